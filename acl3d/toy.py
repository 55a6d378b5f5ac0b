"""teachDeepRL's toy curriculum problem, generalised: competence that spreads from a corner.

The task space [0, 1]^(nb_dims + nb_irrelevant_dims) is cut into `nb_cubes` bins along each of the
first `nb_dims` dimensions. Playing a task in a cube raises its competence (0..100) by one if it is
the origin cube or if one of its "previous" neighbours (each index unchanged or minus one) is at
competence >= 75; the reward is the cube's competence / 100. So progress only exists on a moving
frontier, and sampling locked cubes teaches nothing: a curriculum must find and follow the frontier.
The score is the percentage of cubes with competence > 75. Extra dimensions are ignored by the
environment (distractors a teacher has to learn to disregard); `noise` adds Gaussian noise to the
reward (not to the competence). `space_ratio` > 1 makes the task space mostly unfeasible
(TeachMyAgent's first skill criterion in miniature): each relevant dimension spans
[0, space_ratio] while the cubes cover [0, 1] only, and tasks outside the learnable box return 0
and teach nothing (ratio 3 in 2-D: 1/9 of the space can be learned).
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, field

import numpy as np

from acl3d.curriculum_profile import CurriculumProfile
from acl3d.task_space import TaskSpace
from acl3d.validation import fail, real_array

MASTERED = 75  # competence above which a cube counts as mastered (and unlocks its successors)
SUCCESS_REWARD = MASTERED / 100  # reward above which an episode counts as a success for teachers


def _origin_prior(space: TaskSpace) -> dict[str, np.ndarray]:
    """A narrow Gaussian at the origin corner, where the first cube is learnable."""
    return {"mean": np.zeros(space.dim), "variance": np.eye(space.dim) * 1e-4}


class ToyEnv:
    """The toy environment: `episode(task) -> reward`, `score() -> % mastered cubes`."""

    def __init__(
        self,
        nb_dims: int = 2,
        nb_cubes: int = 10,
        nb_irrelevant_dims: int = 0,
        noise: float = 0.0,
        seed: int | None = None,
        space_ratio=1.0,
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
        ratio = real_array("space_ratio", space_ratio).reshape(-1)
        if ratio.size not in (1, nb_dims) or np.any(ratio < 1):
            raise fail("space_ratio", space_ratio, f"a number >= 1, or {nb_dims} of them")
        self.space_ratio = np.broadcast_to(ratio, (nb_dims,)).copy()
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
        position = [[0.0, float(r)] for r in self.space_ratio]
        return TaskSpace.from_bounds(
            {"position": position}
            | (
                {"distractor": [0.0, 1.0, self.nb_irrelevant_dims]}
                if self.nb_irrelevant_dims
                else {}
            )
        )

    @property
    def curriculum_profile(self) -> CurriculumProfile:
        """The toy's curriculum facts: returns are competences in [0, 1], an episode succeeds
        on a mastered cube (ADR expands on those and shrinks on locked cubes, return 0), and the
        easy tasks are at the origin corner (ADR's start, the prior at expert knowledge high)."""
        return CurriculumProfile(
            name="toy",
            reward_bounds=(0.0, 1.0),
            success_return=SUCCESS_REWARD,
            adr_reward_thresholds=(0.0, SUCCESS_REWARD),
            initial_dist=_origin_prior,
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

    def learnable(self, task) -> bool:
        """Whether `task` lies in the learnable box [0, 1]^nb_dims (always, when space_ratio = 1)."""
        p = np.asarray(task, dtype=np.float64)[: self.nb_dims]
        return bool(np.all((p >= 0.0) & (p <= 1.0)))

    def episode(self, task) -> float:
        """Play one episode on `task`; returns the (noisy) competence of its cube in [0, 1]
        (0 outside the learnable box)."""
        cube = self.cube_of(task)
        c = self.competence
        if not self.learnable(task):
            reward = 0.0
        else:
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


class ToyValueProxy:
    """A stand-in for the student's value function on the toy: V(task) per cube.

    The toy's "student" is its competence table; a real student's critic lags behind its
    returns, so this critic moves each played cube's value towards the return by `lr`. Its value
    error is then large exactly where competence is changing (the frontier) and ~0 on locked and
    mastered cubes, which is what value-loss teachers (Robust PLR, ACCEL, SPDL) feed on.
    """

    def __init__(self, env: ToyEnv, lr: float = 0.1):
        self.env, self.lr = env, float(lr)
        self.values = np.zeros(env.competence.shape)

    def __call__(self, states) -> np.ndarray:
        states = np.atleast_2d(np.asarray(states, dtype=np.float64))
        return np.array(
            [self.values[self.env.cube_of(s)] if self.env.learnable(s) else 0.0 for s in states]
        )

    def update(self, task, reward: float) -> None:
        if self.env.learnable(task):
            cube = self.env.cube_of(task)
            self.values[cube] += self.lr * (reward - self.values[cube])


def run_teacher(
    teacher,
    env: ToyEnv,
    episodes: int,
    score_every: int = 1000,
    observer=None,
    on_score=None,
    to_env=None,
) -> ToyRun:
    """Let `teacher` pick `episodes` tasks on `env`; scores every `score_every` episodes.

    Teachers that need more than returns get what the toy can give: success = reward > 0.75,
    the task itself as initial state, a one-step episode (state = next_state = task, empty
    action, done) for per-step updates, and a `ToyValueProxy` as value estimator.
    `to_env(task)` maps the teacher's task to the one the toy plays (e.g. a `DimensionsShuffler`'s
    forward map for rugged difficulty). `observer(i, task, reward)` runs after each episode
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
    critic = None
    if "value_estimator" in needs:
        critic = ToyValueProxy(env)
        teacher.set_value_estimator(critic)
    clock = time.process_time
    run = ToyRun()
    no_action = np.zeros(0, dtype=np.float32)
    for i in range(episodes):
        t0 = clock()
        task = teacher.sample_task()
        env_task = task if to_env is None else np.asarray(to_env(task), dtype=np.float32)
        if "initial_states" in needs:
            teacher.record_initial_state(task, env_task)
        run.teacher_cpu_s += clock() - t0
        reward = env.episode(env_task)
        t0 = clock()
        if "step_rewards" in needs:
            teacher.step_update(env_task, no_action, reward, env_task, True)
        teacher.episodic_update(task, reward, reward > SUCCESS_REWARD)
        run.teacher_cpu_s += clock() - t0
        if critic is not None:
            critic.update(env_task, reward)
        run.nb_episodes += 1
        if observer is not None:
            observer(i, task, reward)
        if (i + 1) % score_every == 0:
            run.episodes.append(i + 1)
            run.scores.append(env.score())
            if on_score is not None:
                on_score(i + 1, run.scores[-1])
    return run
