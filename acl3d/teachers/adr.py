"""Automatic Domain Randomization (OpenAI et al. 2019): grow a box of tasks while the student copes.

Tasks are drawn uniformly in the current box [cur_low, cur_high], which starts as a single task.
With probability `boundary_sampling_p`, one dimension of the task is instead set to one of its
current bounds; the returns of those boundary episodes fill a queue per bound, and every
`queue_len` of them the bound moves outwards by `step_size` (task units) when their mean is
>= `max_reward_thr`, or inwards when it is <= `min_reward_thr`.

Where the box starts: the mean of `initial_dist` when given (expert knowledge "high"), else the
environment's easiest task (`start="easy"`, every dimension at the easy bound its
`CurriculumProfile` declares), as in OpenAI's ADR, which grows from the nominal environment;
`start="random"` is TeachMyAgent's start under expert knowledge "low" (a uniform task). A random
start is why stump-v1's ADR runs of seeds 0-2 never moved: their start was too hard for a mean
return >= `max_reward_thr`, and a collapsed box cannot shrink, so each trained on one task.

What stays inherent: the box grows only where the boundary episodes average
>= `max_reward_thr` (180 on the tracks), so a student that never reaches that on its start
keeps a single task; a bound at its global limit is never tested again.

Deliberate differences from TeachMyAgent's ADR:
- a queue is fed only by the episodes whose task was boundary-sampled on that bound (remembered
  per sampled task, so several tasks may be in flight); TMA fed every queue whose bound happened to
  equal the task value, so all queues of a collapsed box got every episode;
- the boundary draw picks among bounds that can still grow (TMA could pick a bound already at its
  global limit, wasting the episode); a bound at its limit is therefore never tested again, as in
  TMA when both bounds of a dimension are at their limits;
- no re-seeding when the box changes: all draws come from the teacher's generator;
- seed 0 is a valid seed (base class).
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Any

import numpy as np

from acl3d import validation
from acl3d.curriculum_profile import CurriculumProfile, easy_task
from acl3d.teachers import histories
from acl3d.teachers.base import RunFacts, Teacher
from acl3d.teachers.pending import MAX_PENDING  # boundary-sampled tasks awaiting their return

STARTS = ("easy", "random")
LOW, HIGH = 0, 1


class ADR(Teacher):
    """Automatic Domain Randomization (defaults: TeachMyAgent benchmark, returns in raw units)."""

    name = "adr"
    uses_initial_dist = True
    return_params = ("min_reward_thr", "max_reward_thr")

    @classmethod
    def plot_history(cls, bk, low, high, steps):
        """The box after each change."""
        return histories.boxes(bk)

    @classmethod
    def toy_params(cls, facts: RunFacts) -> dict[str, Any]:
        """A box grown from a random toy task may never see a return: start at the toy's prior
        (its origin corner, the one cube learnable from the start)."""
        return {"initial_dist": facts.initial_dist}

    @classmethod
    def run_params(cls, facts: RunFacts) -> dict[str, Any]:
        """The environment's reward thresholds and easy side, and its easy-task prior when
        known."""
        low, high = facts.profile.adr_reward_thresholds
        return {
            "min_reward_thr": low,
            "max_reward_thr": high,
            "easy_at_high": sorted(facts.profile.easy_at_high),
            **super().run_params(facts),
        }

    def __init__(
        self,
        task_space,
        seed: int | None = None,
        *,
        step_size: float = 0.1,
        boundary_sampling_p: float = 0.7,
        queue_len: int = 10,
        min_reward_thr: float = CurriculumProfile.adr_reward_thresholds[0],
        max_reward_thr: float = CurriculumProfile.adr_reward_thresholds[1],
        initial_dist: dict | None = None,
        start: str = "easy",
        easy_at_high=CurriculumProfile.easy_at_high,
    ):
        super().__init__(task_space, seed)
        validation.choice("start", start, STARTS)
        validation.positive("step_size", step_size)
        validation.real("boundary_sampling_p", boundary_sampling_p, 0.0, 1.0)
        validation.count("queue_len", queue_len)
        validation.real("min_reward_thr", min_reward_thr)
        validation.real("max_reward_thr", max_reward_thr)
        if not min_reward_thr < max_reward_thr:
            raise ValueError(
                f"need finite min_reward_thr < max_reward_thr, got {min_reward_thr!r} and {max_reward_thr!r}"
            )
        self.step_size = float(step_size)
        self.boundary_sampling_p = float(boundary_sampling_p)
        self.queue_len = int(queue_len)
        self.min_reward_thr, self.max_reward_thr = float(min_reward_thr), float(max_reward_thr)
        if initial_dist is not None:
            try:
                mean = np.asarray(initial_dist["mean"], dtype=np.float64).reshape(self.dim)
            except (KeyError, TypeError, ValueError):
                raise ValueError(
                    f"initial_dist must be a dict with a 'mean' of length {self.dim}, got {initial_dist!r}"
                ) from None
            if not np.all(np.isfinite(mean)):
                raise ValueError(f"initial_dist mean must be finite, got {mean}")
            first = self.clip(mean)
        elif start == "easy":
            first = easy_task(self.task_space, easy_at_high)
        else:
            first = self.uniform_task()
        self.cur_low, self.cur_high = first.copy(), first.copy()
        self.queues: list[list[list[float]]] = [[[] for _ in range(self.dim)] for _ in (LOW, HIGH)]
        self.pending: OrderedDict[bytes, tuple[int, int, float]] = OrderedDict()
        self.bk["task_space"].append((self.cur_low.copy(), self.cur_high.copy()))
        self.bk["episodes"].append(0)

    def _sample(self) -> np.ndarray:
        task = self.rng.uniform(self.cur_low, self.cur_high)
        if self.rng.random() < self.boundary_sampling_p:
            growable = np.stack(
                [self.cur_low > self.mins, self.cur_high < self.maxs]
            )  # (side, dim)
            dims = np.flatnonzero(growable.any(axis=0))
            if len(dims):
                dim = int(dims[self.rng.integers(len(dims))])
                sides = np.flatnonzero(growable[:, dim])
                side = int(sides[self.rng.integers(len(sides))])
                value = float(np.float32(self.cur_low[dim] if side == LOW else self.cur_high[dim]))
                task[dim] = value
                self.pending[np.asarray(task, dtype=np.float32).tobytes()] = (dim, side, value)
                while len(self.pending) > MAX_PENDING:
                    self.pending.popitem(last=False)
        return task

    def _non_exploratory_sample(self) -> np.ndarray:
        return self.rng.uniform(self.cur_low, self.cur_high)

    def _episodic_update(self, task: np.ndarray, reward: float, is_success: bool) -> None:
        entry = self.pending.pop(np.asarray(task, dtype=np.float32).tobytes(), None)
        if entry is None:
            return
        dim, side, value = entry
        bound = self.cur_low if side == LOW else self.cur_high
        if float(np.float32(bound[dim])) != value:  # the bound moved since this task was sampled
            return
        queue = self.queues[side][dim]
        queue.append(reward)
        if len(queue) < self.queue_len:
            return
        mean = sum(queue) / len(queue)
        queue.clear()
        outwards = -1.0 if side == LOW else 1.0
        if mean >= self.max_reward_thr:
            new = bound[dim] + outwards * self.step_size
        elif mean <= self.min_reward_thr:
            new = bound[dim] - outwards * self.step_size
        else:
            return
        if side == LOW:
            self.cur_low[dim] = min(max(new, self.mins[dim]), self.cur_high[dim])
        else:
            self.cur_high[dim] = max(min(new, self.maxs[dim]), self.cur_low[dim])
        self.bk["task_space"].append((self.cur_low.copy(), self.cur_high.copy()))
        self.bk["episodes"].append(self.nb_episodes + 1)

    def plot_state(self) -> dict[str, Any]:
        return {"kind": "box", "low": self.cur_low.copy(), "high": self.cur_high.copy()}

    def _extra_state(self) -> dict[str, Any]:
        return {
            "cur_low": self.cur_low.copy(),
            "cur_high": self.cur_high.copy(),
            "queues": [[list(q) for q in side] for side in self.queues],
            "pending": [
                [np.frombuffer(k, dtype=np.float32).tolist(), d, s, v]
                for k, (d, s, v) in self.pending.items()
            ],
        }

    def _load_extra_state(self, extra: dict[str, Any]) -> None:
        self.cur_low = np.asarray(extra["cur_low"], dtype=np.float64).copy()
        self.cur_high = np.asarray(extra["cur_high"], dtype=np.float64).copy()
        self.queues = [[[float(r) for r in q] for q in side] for side in extra["queues"]]
        self.pending = OrderedDict(
            (np.asarray(t, dtype=np.float32).tobytes(), (int(d), int(s), float(v)))
            for t, d, s, v in extra["pending"]
        )
