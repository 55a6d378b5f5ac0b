"""Play a policy on given tasks and write labelled frames: one run, or several side by side.

Seeding follows `acl3d.training.evaluation.evaluate` on one worker: the first episode resets with
`seed`, later ones continue the env's random stream, and tasks are float32 vectors, so a video
shows the very episodes an evaluation with the same seed scored.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Sequence

import numpy as np
from tqdm import tqdm

from acl3d import validation
from acl3d.overlay import draw_label, episode_lines
from acl3d.video import open_sink, tile

Policy = Callable[[np.ndarray], np.ndarray]


class EpisodePlayer:
    """One rgb_array env and one policy, stepped one control step at a time."""

    def __init__(self, env, policy: Policy, title: str = "", overlay: bool = True):
        self.env, self.policy, self.title, self.overlay = env, policy, title, overlay
        self.obs = None
        self.steps, self.episode_return, self.success, self.done = 0, 0.0, False, True
        self.outcome = ""  # see acl3d.overlay.OUTCOMES
        self.task: dict = {}

    def reset(self, task, seed: int | None) -> None:
        vector = np.asarray(task, dtype=np.float32)  # as the evaluation workers receive it
        self.obs, info = self.env.reset(seed=seed, options={"task": vector})
        self.task = self.env.unwrapped.get_task()
        self.steps, self.episode_return, self.done, self.outcome = 0, 0.0, False, ""
        self.success = bool(info.get("success", False))

    def step(self, max_steps: int) -> None:
        """One step of the policy (no-op once the episode is over or `max_steps` long)."""
        if self.done:
            return
        self.obs, reward, terminated, truncated, info = self.env.step(self.policy(self.obs))
        self.steps += 1
        self.episode_return += float(reward)
        self.success = bool(info.get("success", False))
        self.done = bool(terminated or truncated) or self.steps >= max_steps
        if self.success:
            self.outcome = "success"
        elif terminated:
            self.outcome = "failed"
        elif self.done:
            self.outcome = "time limit"

    def frame(self) -> np.ndarray:
        frame = self.env.render()
        if self.overlay:
            lines = episode_lines(
                self.title, self.task, self.steps, self.episode_return, self.outcome
            )
            draw_label(frame, lines)
        return frame

    def summary(self) -> dict:
        return {
            "task": self.task,
            "return": self.episode_return,
            "length": self.steps,
            "success": self.success,
        }


def task_vectors(env, tasks: Sequence) -> list[np.ndarray]:
    """Tasks (dicts in task-space units or flat vectors) as validated float32 vectors."""
    space = env.unwrapped.task_space
    out = []
    for task in tasks:
        vector = space.to_vector(task) if isinstance(task, dict) else space.validate_vector(task)
        out.append(np.asarray(vector, dtype=np.float32))
    if not out:
        raise ValueError("tasks: at least one task is needed")
    return out


def _check_playback(max_steps: int, every: int, seed) -> None:
    validation.count("max_steps", max_steps)
    validation.count("every", every)
    validation.seed(seed)


def record_rollouts(
    env,
    policy: Policy,
    out,
    tasks: Sequence,
    seed: int | None = 0,
    max_steps: int = 2000,
    every: int = 1,
    fps: int | None = None,
    progress: bool = True,
    title: str = "",
    overlay: bool = True,
    fmt: str | None = None,
    strip_frames: int = 6,
) -> list[dict]:
    """Play one episode per task and write every `every`-th frame to `out` (mp4, gif or png).

    Returns one summary per episode (task, return, length, success).
    """
    player = EpisodePlayer(env, policy, title, overlay)
    return record_grid(
        [player], out, tasks, seed, max_steps, every, fps, progress, 1, fmt, strip_frames
    )[0]


def record_grid(
    players: Sequence[EpisodePlayer],
    out,
    tasks: Sequence,
    seed: int | None = 0,
    max_steps: int = 2000,
    every: int = 1,
    fps: int | None = None,
    progress: bool = True,
    cols: int | None = None,
    fmt: str | None = None,
    strip_frames: int = 6,
) -> list[list[dict]]:
    """Every player plays the same tasks in lockstep; one grid frame holds one cell per player.

    A cell whose episode is over holds its last frame until every cell has finished. Returns
    one list of episode summaries per player.
    """
    _check_playback(max_steps, every, seed)
    if not players:
        raise ValueError("record_grid: at least one player is needed")
    cols = cols or math.ceil(math.sqrt(len(players)))
    vectors = [task_vectors(p.env, tasks) for p in players]
    fps = fps or max(1, round(players[0].env.metadata.get("render_fps", 50) / every))
    sink = open_sink(out, fps, fmt, strip_frames)
    summaries: list[list[dict]] = [[] for _ in players]
    try:
        with tqdm(disable=not progress, unit="step", desc="render") as bar:
            for ep in range(len(vectors[0])):
                bar.set_description_str(f"episode {ep + 1}/{len(vectors[0])}")
                for p, v in zip(players, vectors):
                    p.reset(v[ep], seed if ep == 0 else None)
                cells = [p.frame() for p in players]
                sink.append(tile(cells, cols))
                t = 0
                while not all(p.done for p in players):
                    t += 1
                    for i, p in enumerate(players):
                        if p.done:
                            continue  # its cell keeps the frame of its last step
                        p.step(max_steps)
                        if p.done or t % every == 0:
                            cells[i] = p.frame()
                    bar.update(1)
                    if t % every == 0 or all(p.done for p in players):
                        sink.append(tile(cells, cols))
                sink.end_episode()
                for p, s in zip(players, summaries):
                    s.append(p.summary())
    except BaseException:
        with contextlib.suppress(Exception):  # keep the original error, not the sink's
            sink.close()
        raise
    sink.close()
    return summaries
