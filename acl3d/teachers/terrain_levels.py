"""Terrain levels (legged_gym / Isaac Lab / mjlab's terrain curriculum) over a parametric task space.

`nb_workers` virtual robots each hold a difficulty level in [0, nb_levels). A level is a band of
the chosen task dimensions, moved together from their easy end to their hard end: level l plays
difficulty u ~ U(l, l + 1) / nb_levels, i.e. value = easy + u * (hard - easy) on every chosen
dimension; the other dimensions are drawn uniformly. Tasks go to the robots in turn. When a
robot's episode is reported, its level goes up if the episode went far enough (return >=
`promote_return`), down if it fell short (return < `demote_return`, never below 0), and a robot
promoted past the top level is sent to a random level (the rule that keeps the top levels from
being over-trained). Levels start uniformly in [0, max_init_level]. A dimension's hard end is
`hard_end`, by default the bound away from the environment's easy side
(`CurriculumProfile.easy_at_high`): on Stump Tracks obstacle_spacing gets harder downwards, so
level 9 is tall, dense stumps (with "max" everywhere, levels raised the stumps while widening
their spacing, and every level had the same overall difficulty).

"How far the episode went" is the episodic return as the teacher receives it (raw, or in [0, 1]
with reward scaling): on acl3d's tracks the return is dominated by forward progress (130 per 30 m
of head travel), so the defaults 180 / 90 promote above about half the track and demote below a
quarter; other environments pass their own thresholds. Several workers may have episodes in
flight: outcomes are matched to robots by task value, as GoalGAN's goals are.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from acl3d.curriculum_profile import CurriculumProfile, easy_directions
from acl3d.teachers.base import RunFacts, Teacher
from acl3d.teachers.pending import PendingTasks
from acl3d.validation import count, fail, integer, real


class TerrainLevels(Teacher):
    """Per-robot difficulty levels promoted and demoted by how far each episode went."""

    name = "terrain-levels"

    @classmethod
    def run_params(cls, facts: RunFacts) -> dict[str, Any]:
        """The environment's easy side: levels walk each dimension away from it."""
        return {"easy_at_high": sorted(facts.profile.easy_at_high), **super().run_params(facts)}

    @classmethod
    def toy_params(cls, facts: RunFacts) -> dict[str, Any]:
        """Start at the origin, promote on a mastered cube (the toy's success return), demote on
        a locked one (return 0)."""
        return {
            "promote_return": facts.profile.success_return,
            "demote_return": 0.005,
            "max_init_level": 0,
        }

    def __init__(
        self,
        task_space,
        seed: int | None = None,
        *,
        dimensions=None,
        hard_end=None,
        nb_levels: int = 10,
        max_init_level: int = 5,
        nb_workers: int = 16,
        promote_return: float = 180.0,
        demote_return: float = 90.0,
        easy_at_high=CurriculumProfile.easy_at_high,
    ):
        super().__init__(task_space, seed)
        names = list(self.task_space.names)
        varying = [i for i in range(self.dim) if self.maxs[i] > self.mins[i]]
        if dimensions is None:
            self.level_dims = np.asarray(varying, dtype=np.intp)
        else:
            if isinstance(dimensions, (str, bytes)) or not isinstance(dimensions, (list, tuple)):
                raise fail("dimensions", dimensions, f"a list of task dimensions among {names}")
            idx = []
            for d in dimensions:
                if isinstance(d, str) and d in names:
                    idx.append(names.index(d))
                elif (
                    isinstance(d, (int, np.integer))
                    and not isinstance(d, bool)
                    and 0 <= d < self.dim
                ):
                    idx.append(int(d))
                else:
                    raise fail(
                        "dimensions", dimensions, f"names among {names} or indices < {self.dim}"
                    )
            if not idx or len(set(idx)) != len(idx):
                raise fail("dimensions", dimensions, "a non-empty list without repeats")
            self.level_dims = np.asarray(idx, dtype=np.intp)
        if hard_end is None:  # hard away from the environment's easy side
            up = easy_directions(self.task_space, easy_at_high)[self.level_dims] > 0
            ends = ["max" if u else "min" for u in up]
        else:
            ends = hard_end
        if (
            not isinstance(ends, (list, tuple))
            or len(ends) != len(self.level_dims)
            or any(e not in ("min", "max") for e in ends)
        ):
            raise fail("hard_end", hard_end, f"{len(self.level_dims)} entries, each 'min' or 'max'")
        self.hard_end = [str(e) for e in ends]
        lo, hi = self.mins[self.level_dims], self.maxs[self.level_dims]
        hard_at_max = np.array([e == "max" for e in self.hard_end], dtype=bool)
        self.easy = np.where(hard_at_max, lo, hi)
        self.hard = np.where(hard_at_max, hi, lo)
        self.nb_levels = count("nb_levels", nb_levels)
        self.max_init_level = integer("max_init_level", max_init_level, 0, self.nb_levels - 1)
        self.nb_workers = count("nb_workers", nb_workers)
        self.promote_return = real("promote_return", promote_return)
        self.demote_return = real("demote_return", demote_return)
        if not self.demote_return <= self.promote_return:
            raise fail(
                "demote_return", demote_return, f"<= promote_return = {self.promote_return:g}"
            )
        self.levels = self.rng.integers(0, self.max_init_level + 1, size=self.nb_workers)
        self._turn = 0
        self._pending = PendingTasks(self.dim)  # task as played -> robot

    def task_at(self, difficulty: float) -> np.ndarray:
        """A task whose chosen dimensions sit at `difficulty` in [0, 1] (others uniform)."""
        task = self.uniform_task()
        task[self.level_dims] = self.easy + difficulty * (self.hard - self.easy)
        return task

    def _sample(self) -> np.ndarray:
        robot = self._turn % self.nb_workers
        self._turn += 1
        u = (self.levels[robot] + self.rng.random()) / self.nb_levels
        task = np.asarray(self.clip(self.task_at(u)), dtype=np.float32).astype(np.float64)
        self._pending.add(task, robot)
        return task

    def _non_exploratory_sample(self) -> np.ndarray:
        level = self.levels[self.rng.integers(self.nb_workers)]
        return self.clip(self.task_at((level + self.rng.random()) / self.nb_levels))

    def _episodic_update(self, task: np.ndarray, reward: float, is_success: bool) -> None:
        proposal = self._pending.oldest(task)
        if proposal is not None:
            _, r = self._pending.pop(proposal)
            level = int(self.levels[r])
            if reward >= self.promote_return:
                level += 1
                if level >= self.nb_levels:
                    level = int(self.rng.integers(self.nb_levels))
            elif reward < self.demote_return:
                level = max(level - 1, 0)
            self.levels[r] = level
        self.bk["episodes"].append(self.nb_episodes + 1)
        self.bk["mean_level"].append(float(self.levels.mean()))

    def plot_state(self) -> dict[str, Any]:
        """One box per level (its band of the chosen dimensions), valued by its robot count."""
        boxes = []
        for level in range(self.nb_levels):
            low, high = self.mins.copy(), self.maxs.copy()
            a = self.easy + level / self.nb_levels * (self.hard - self.easy)
            b = self.easy + (level + 1) / self.nb_levels * (self.hard - self.easy)
            low[self.level_dims], high[self.level_dims] = np.minimum(a, b), np.maximum(a, b)
            boxes.append((low, high, float((self.levels == level).sum())))
        return {"kind": "boxes", "boxes": boxes, "label": "robots at this level"}

    def _extra_state(self) -> dict[str, Any]:
        return {
            "levels": self.levels.copy(),
            "turn": self._turn,
            "proposals": self._pending.columns(("robots",)),
        }

    def _load_extra_state(self, extra: dict[str, Any]) -> None:
        self.levels = np.asarray(extra["levels"], dtype=np.int64).reshape(self.nb_workers)
        self._turn = int(extra["turn"])
        proposals = extra.get("proposals")
        if proposals is None:  # a checkpoint written before proposals were kept as columns
            self._pending.load((t, int(r)) for t, r in extra["pending"])
        else:
            self._pending.load_columns(proposals, ("robots",))
