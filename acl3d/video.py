"""Rollout videos: run a policy in an rgb_array env and stream frames to an mp4 or gif."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
from tqdm import tqdm

Policy = Callable[[np.ndarray], np.ndarray]
VIDEO_FORMATS = (".mp4", ".gif")


def video_writer(path: str | Path, fps: int):
    """An imageio writer for .mp4 (ffmpeg, H.264) or .gif (looping)."""
    path = Path(path)
    if path.suffix.lower() not in VIDEO_FORMATS:
        raise ValueError(f"video path {str(path)!r}: the extension must be one of {VIDEO_FORMATS}")
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".mp4":
        return imageio.get_writer(path, fps=fps, codec="libx264", quality=7, macro_block_size=8)
    return imageio.get_writer(path, mode="I", duration=1000.0 / fps, loop=0)


def record_rollouts(
    env,
    policy: Policy,
    out: str | Path,
    tasks: Sequence | None = None,
    episodes: int = 1,
    seed: int | None = 0,
    max_steps: int = 2000,
    every: int = 1,
    fps: int | None = None,
    progress: bool = True,
) -> list[dict]:
    """Play `episodes` episodes (one per task if `tasks` is given) and write every `every`-th frame.

    Returns one summary per episode (task, return, length, success).
    """
    if every < 1:
        raise ValueError(f"every={every}: must be >= 1")
    fps = fps or max(1, round(env.metadata.get("render_fps", 50) / every))
    episodes = len(tasks) if tasks is not None else episodes
    summaries = []
    with (
        video_writer(out, fps) as writer,
        tqdm(total=episodes * max_steps, disable=not progress, unit="step", desc="render") as bar,
    ):
        for ep in range(episodes):
            options = {"task": tasks[ep]} if tasks is not None else None
            obs, info = env.reset(seed=None if seed is None else seed + ep, options=options)
            writer.append_data(env.render())
            ret, length, done = 0.0, 0, False
            while not done and length < max_steps:
                obs, reward, terminated, truncated, info = env.step(policy(obs))
                ret += float(reward)
                length += 1
                done = terminated or truncated
                if length % every == 0:
                    writer.append_data(env.render())
                bar.update(1)
            bar.update(max_steps - length)
            summaries.append(
                {
                    "task": env.unwrapped.get_task(),
                    "return": ret,
                    "length": length,
                    "success": bool(info.get("success", False)),
                }
            )
    return summaries
