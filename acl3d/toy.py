"""teachDeepRL's toy curriculum problem, generalised: competence that spreads from a corner.

The task space [0, 1]^(nb_dims + nb_irrelevant_dims) is cut into `nb_cubes` bins along each of the
first `nb_dims` dimensions. Playing a task in a cube raises its competence (0..100) by one if it is
the origin cube or if one of its "previous" neighbours (each index unchanged or minus one) is at
competence >= 75; the reward is the cube's competence / 100. So progress only exists on a moving
frontier, and sampling locked cubes teaches nothing: a curriculum must find and follow the frontier.
The score is the percentage of cubes with competence > 75. Extra dimensions are ignored by the
environment (distractors a teacher has to learn to disregard); `noise` adds Gaussian noise to the
reward (not to the competence).
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, field

import numpy as np

from acl3d.task_space import TaskSpace

MASTERED = 75  # competence above which a cube counts as mastered (and unlocks its successors)
SUCCESS_REWARD = MASTERED / 100  # reward above which an episode counts as a success for teachers


class ToyEnv:
    """The toy environment: `episode(task) -> reward`, `score() -> % mastered cubes`."""

    def __init__(
        self,
        nb_dims: int = 2,
        nb_cubes: int = 10,
        nb_irrelevant_dims: int = 0,
        noise: float = 0.0,
        seed: int | None = None,
    ):
        for what, value, lo in (
            ("nb_dims", nb_dims, 1),
            ("nb_cubes", nb_cubes, 1),
            ("nb_irrelevant_dims", nb_irrelevant_dims, 0),
        ):
            if not isinstance(value, (int, np.integer)) or value < lo:
                raise ValueError(f"{what} must be an integer >= {lo}, got {value!r}")
        if nb_dims > 16:  # the unlock rule looks at 2**nb_dims - 1 neighbours
            raise ValueError(f"nb_dims must be <= 16, got {nb_dims}")
        if nb_cubes**nb_dims > 10_000_000:
            raise ValueError(
                f"nb_cubes**nb_dims = {nb_cubes}**{nb_dims} cubes is too many (max 1e7)"
            )
        if not (np.isfinite(noise) and noise >= 0):
            raise ValueError(f"noise must be a finite standard deviation >= 0, got {noise!r}")
        self.nb_dims, self.nb_cubes = int(nb_dims), int(nb_cubes)
        self.nb_irrelevant_dims, self.noise = int(nb_irrelevant_dims), float(noise)
        self.rng = np.random.default_rng(seed)
        self.competence = np.zeros((self.nb_cubes,) * self.nb_dims, dtype=np.int16)
        offsets = np.array(list(itertools.product((0, 1), repeat=self.nb_dims))[1:], dtype=np.intp)
        self._offsets = offsets  # every non-empty subset of dimensions to step back along

    @property
    def task_dim(self) -> int:
        return self.nb_dims + self.nb_irrelevant_dims

    def task_space(self) -> TaskSpace:
        return TaskSpace.from_bounds(
            {"position": [0.0, 1.0, self.nb_dims]}
            | (
                {"distractor": [0.0, 1.0, self.nb_irrelevant_dims]}
                if self.nb_irrelevant_dims
                else {}
            )
        )

    def cube_of(self, task) -> tuple[int, ...]:
        p = np.asarray(task, dtype=np.float64)
        if p.shape != (self.task_dim,) or not np.all(np.isfinite(p)):
            raise ValueError(
                f"task must be a finite vector of length {self.task_dim}, got {task!r}"
            )
        return tuple(
            np.clip((p[: self.nb_dims] * self.nb_cubes).astype(np.intp), 0, self.nb_cubes - 1)
        )

    def episode(self, task) -> float:
        """Play one episode on `task`; returns the (noisy) competence of its cube in [0, 1]."""
        cube = self.cube_of(task)
        c = self.competence
        if c[cube] < 100:
            if not any(cube):
                c[cube] += 1
            else:
                prev = np.maximum(np.asarray(cube) - self._offsets, 0)
                prev = prev[(prev != cube).any(axis=1)]
                if (c[tuple(prev.T)] >= MASTERED).any():
                    c[cube] += 1
        reward = c[cube] / 100.0
        if self.noise > 0:
            reward += self.noise * self.rng.standard_normal()
        return float(reward)

    def competence_map(self) -> np.ndarray:
        """Competence over the first two dimensions (mean over the others), for plots."""
        c = self.competence.astype(np.float64)
        if self.nb_dims == 1:
            return c[:, None]
        return c.mean(axis=tuple(range(2, self.nb_dims))) if self.nb_dims > 2 else c

    def score(self) -> float:
        """Percentage of cubes with competence > 75."""
        return float(100.0 * (self.competence > MASTERED).mean())


def toy_teacher_params(name: str, env: ToyEnv) -> dict:
    """What reward-threshold teachers need on the toy, whose returns are competences in [0, 1].

    ADR expands a bound whose boundary episodes average >= 0.75 (mastered) and shrinks it when
    they all return 0 (a locked cube); it starts at the origin corner, the toy's expert knowledge
    (ADR needs a feasible start). The oracle moves its window once the window averages > 0.75.
    Self-paced schedules count environment steps; a toy episode is one step, so they are rescaled
    to update every 250 episodes after the first 1000.
    """
    if name == "adr":
        d = env.task_dim
        return {
            "min_reward_thr": 0.0,
            "max_reward_thr": SUCCESS_REWARD,
            "initial_dist": {"mean": np.zeros(d), "variance": np.eye(d) * 1e-4},
        }
    if name == "oracle":
        return {"reward_thr": SUCCESS_REWARD}
    if name == "self-paced":
        return {"update_frequency": 250, "update_offset": 1000}
    return {}


@dataclass
class ToyRun:
    """Outcome of `run_teacher`: score history and the CPU time spent inside the teacher."""

    episodes: list[int] = field(default_factory=list)
    scores: list[float] = field(default_factory=list)
    teacher_cpu_s: float = 0.0
    nb_episodes: int = 0

    @property
    def cpu_per_1000(self) -> float:
        return 1000.0 * self.teacher_cpu_s / max(1, self.nb_episodes)


def run_teacher(
    teacher, env: ToyEnv, episodes: int, score_every: int = 1000, observer=None, on_score=None
) -> ToyRun:
    """Let `teacher` pick `episodes` tasks on `env`; scores every `score_every` episodes.

    Teachers that need more than returns get what the toy can give: success = reward > 0.75,
    the task itself as initial state, and a one-step episode (state = next_state = task, empty
    action, done) for per-step updates. `observer(i, task, reward)` runs after each episode
    (GIF recording); `on_score(episode, score)` after each score.
    """
    if not isinstance(episodes, (int, np.integer)) or episodes < 0:
        raise ValueError(f"episodes must be a non-negative integer, got {episodes!r}")
    if score_every < 1:
        raise ValueError(f"score_every must be >= 1, got {score_every!r}")
    if teacher.dim != env.task_dim:
        raise ValueError(
            f"teacher task dimension {teacher.dim} != toy task dimension {env.task_dim}"
        )
    needs = teacher.needs
    clock = time.process_time
    run = ToyRun()
    no_action = np.zeros(0, dtype=np.float32)
    for i in range(episodes):
        t0 = clock()
        task = teacher.sample_task()
        if "initial_states" in needs:
            teacher.record_initial_state(task, task)
        run.teacher_cpu_s += clock() - t0
        reward = env.episode(task)
        t0 = clock()
        if "step_rewards" in needs:
            teacher.step_update(task, no_action, reward, task, True)
        teacher.episodic_update(task, reward, reward > SUCCESS_REWARD)
        run.teacher_cpu_s += clock() - t0
        run.nb_episodes += 1
        if observer is not None:
            observer(i, task, reward)
        if (i + 1) % score_every == 0:
            run.episodes.append(i + 1)
            run.scores.append(env.score())
            if on_score is not None:
                on_score(i + 1, run.scores[-1])
    return run
