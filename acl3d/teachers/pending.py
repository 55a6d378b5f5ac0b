"""Proposed tasks awaiting their episode's outcome, for teachers that match an outcome back to
its proposal (Robust PLR's level, the terrain curriculum's robot).

Every running world holds one proposal, and a many-world run draws some ahead, so tens of
thousands may wait at once: they sit in one array, matched against a reported task in one
vectorised comparison, not a Python loop over the proposals.
"""

from __future__ import annotations

import numpy as np

# proposals kept before the oldest are forgotten: more than the most worlds a run steps
# (1 << 20) with the tasks drawn ahead for them
MAX_PENDING = 1 << 21


class PendingTasks:
    """Proposals (task, payload), oldest first: the task as the env will report it, and what
    the teacher needs back with the outcome (a level's index and kind, a robot, a goal's
    outcomes so far)."""

    def __init__(self, dim: int):
        self._tasks = np.zeros((16, dim), dtype=np.float64)
        self._payloads: list = []

    def __len__(self) -> int:
        return len(self._payloads)

    def add(self, task: np.ndarray, payload) -> None:
        n = len(self._payloads)
        if n == len(self._tasks):
            self._tasks = np.concatenate((self._tasks, np.zeros_like(self._tasks)))
        self._tasks[n] = task
        self._payloads.append(payload)
        if n + 1 > MAX_PENDING:
            self.pop(0)

    def matches(self, task: np.ndarray, span=None, tolerance=0.0) -> np.ndarray:
        """Indices (oldest first) of the proposals equal to `task`, or with every
        |proposal - task| / span within `tolerance` (per dimension, or one for all)."""
        proposed = self._tasks[: len(self._payloads)]
        # the first dimension alone picks the few candidates; the whole check runs on them
        if span is None:
            rows = np.flatnonzero(proposed[:, 0] == task[0])
            return rows[(proposed[rows] == task).all(axis=1)]
        span, tolerance = np.broadcast_to(span, task.shape), np.broadcast_to(tolerance, task.shape)
        rows = np.flatnonzero(np.abs(proposed[:, 0] - task[0]) / span[0] <= tolerance[0])
        return rows[(np.abs(proposed[rows] - task) / span <= tolerance).all(axis=1)]

    def payload(self, index: int):
        return self._payloads[index]

    def pop(self, index: int) -> tuple[np.ndarray, object]:
        """Forget proposal `index`; returns its (task, payload)."""
        n, task = len(self._payloads), self._tasks[index].copy()
        self._tasks[index : n - 1] = self._tasks[index + 1 : n]
        return task, self._payloads.pop(index)

    def items(self) -> list:
        """[(task, payload)], oldest first (for checkpoints)."""
        return [(t.copy(), p) for t, p in zip(self._tasks, self._payloads)]

    def load(self, items) -> None:
        """Replace the proposals with [(task, payload)], oldest first."""
        self.__init__(self._tasks.shape[1])
        for task, payload in items:
            self.add(np.asarray(task, dtype=np.float64).reshape(-1), payload)
