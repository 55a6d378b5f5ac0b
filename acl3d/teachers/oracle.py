"""Oracle (teachDeepRL): a hand-designed curriculum, a window that walks from easy to hard tasks.

Tasks are drawn uniformly in a window of width `window_ratio` x range per dimension. Every
`step_rate` episodes, if the mean return of those episodes exceeds `reward_thr`, the window moves
by `window_step_vector` (task units, clamped so it stays inside the bounds). A positive step
starts the window at the lower bound, a negative one at the upper bound. The expert knowledge is
in the step vector: its signs say where the easy tasks are. Without an explicit vector the step
is range/30 per dimension (teachDeepRL's 0.1 and 0.2 on Stump Tracks' [0, 3] x [0, 6]) pointing
away from the easy side the environment declares (`CurriculumProfile.easy_at_high`): on Stump
Tracks [+0.1, -0.2] from height 0 and spacing 6, as teachDeepRL's oracle. In a training run
`reward_thr` is the environment's success return unless the run sets it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from acl3d import validation
from acl3d.curriculum_profile import CurriculumProfile, easy_directions
from acl3d.teachers.base import RunFacts, Teacher


class Oracle(Teacher):
    """teachDeepRL's sliding-window oracle; default step: range/30 from the easy side."""

    name = "oracle"
    return_params = ("reward_thr",)

    @classmethod
    def run_params(cls, facts: RunFacts) -> dict[str, Any]:
        """The window starts at the environment's easy side and moves on when its episodes
        succeed on average (the environment's success return)."""
        return {
            "reward_thr": facts.profile.success_return,
            "easy_at_high": sorted(facts.profile.easy_at_high),
            **super().run_params(facts),
        }

    def __init__(
        self,
        task_space,
        seed: int | None = None,
        *,
        window_step_vector=None,
        step_rate: int = 50,
        reward_thr: float = CurriculumProfile.success_return,
        window_ratio: float = 1 / 6,
        easy_at_high=CurriculumProfile.easy_at_high,
    ):
        super().__init__(task_space, seed)
        span = self.maxs - self.mins
        if window_step_vector is None:
            step = easy_directions(self.task_space, easy_at_high) * span / 30.0
        else:
            step = np.asarray(window_step_vector, dtype=np.float64).reshape(-1)
            if step.shape != (self.dim,) or not np.all(np.isfinite(step)):
                raise ValueError(
                    f"window_step_vector must hold {self.dim} finite values, got {window_step_vector!r}"
                )
        validation.count("step_rate", step_rate)
        validation.real("reward_thr", reward_thr)
        validation.real("window_ratio", window_ratio, 0.0, 1.0, exclusive_low=True)
        self.step = step
        self.step_rate = int(step_rate)
        self.reward_thr = float(reward_thr)
        self.width = span * float(window_ratio)
        self.window_low = np.where(step < 0, self.maxs - self.width, self.mins)
        self.rewards: list[float] = []

    def _sample(self) -> np.ndarray:
        return self.clip(self.rng.uniform(self.window_low, self.window_low + self.width))

    def _episodic_update(self, task: np.ndarray, reward: float, is_success: bool) -> None:
        self.rewards.append(reward)
        if len(self.rewards) < self.step_rate:
            return
        mean = sum(self.rewards) / len(self.rewards)
        self.rewards.clear()
        if mean > self.reward_thr:
            self.window_low = np.clip(
                self.window_low + self.step, self.mins, self.maxs - self.width
            )
            self.bk["window_low"].append(self.window_low.copy())
            self.bk["episodes"].append(self.nb_episodes + 1)

    def plot_state(self) -> dict[str, Any]:
        return {"kind": "box", "low": self.window_low.copy(), "high": self.window_low + self.width}

    def _extra_state(self) -> dict[str, Any]:
        return {"window_low": self.window_low.copy(), "rewards": list(self.rewards)}

    def _load_extra_state(self, extra: dict[str, Any]) -> None:
        self.window_low = np.asarray(extra["window_low"], dtype=np.float64).copy()
        self.rewards = [float(r) for r in extra["rewards"]]
