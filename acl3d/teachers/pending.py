"""Proposed tasks awaiting their episode's outcome, for teachers that match an outcome back to
its proposal (Robust PLR's level, the terrain curriculum's robot, a goal's outcomes).

Every running world holds one proposal, and a many-world run draws some ahead, so tens of
thousands may wait at once while a step reports dozens of outcomes. A reported task is matched
through a hash of its value, not by comparing it with every proposal: exact matching keys the
whole task; matching within a tolerance keys the first dimension's bucket of one tolerance's
width and compares only the proposals of the neighbouring buckets. Either way the matches are
those of comparing every dimension of every proposal.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

# proposals kept before the oldest are forgotten: more than the most worlds a run steps
# (1 << 20) with the tasks drawn ahead for them
MAX_PENDING = 1 << 21
# buckets on each side of a task's own that may hold a match (one is enough in exact
# arithmetic; the second covers the rounding of task / width)
_NEIGHBOURS = 2


class PendingTasks:
    """Proposals (task, payload), oldest first: the task as the env will report it, and what
    the teacher needs back with the outcome (a level's index and kind, a robot, a goal's
    outcomes so far).

    A proposal matches a reported task when every |proposal - task| / span <= tolerance
    (per dimension, or one value for all); tolerance 0: when they are equal. Proposals are
    named by handles, integers that grow with age."""

    def __init__(self, dim: int, span=1.0, tolerance=0.0):
        self.dim = int(dim)
        self._span = np.broadcast_to(np.asarray(span, dtype=np.float64), (self.dim,)).copy()
        self._tolerance = np.broadcast_to(np.asarray(tolerance, np.float64), (self.dim,)).copy()
        if np.any(self._span <= 0):
            raise ValueError(f"span={span!r}; valid: values > 0")
        if np.any(self._tolerance < 0):
            raise ValueError(f"tolerance={tolerance!r}; valid: values >= 0")
        self._rule = list(zip(self._span.tolist(), self._tolerance.tolist()))  # as floats
        self._exact = not self._tolerance.any()
        self._width = float(self._tolerance[0] * self._span[0])  # a bucket, on dimension 0
        self._entries: dict[int, tuple[np.ndarray, object]] = {}  # handle -> (task, payload)
        self._buckets: dict[object, list[int]] = {}  # key -> handles, oldest first
        self._handles = itertools.count()

    def __len__(self) -> int:
        return len(self._entries)

    def _key(self, task: np.ndarray):
        if self._exact:
            return tuple(task.tolist())
        first = float(task[0])
        return math.floor(first / self._width) if self._width > 0 else first

    def _candidate_keys(self, task: np.ndarray) -> list:
        key = self._key(task)
        if self._exact or self._width == 0:
            return [key]
        return [key + k for k in range(-_NEIGHBOURS, _NEIGHBOURS + 1)]

    def add(self, task: np.ndarray, payload) -> None:
        task = np.array(task, dtype=np.float64).reshape(self.dim)
        handle = next(self._handles)
        self._entries[handle] = (task, payload)
        self._buckets.setdefault(self._key(task), []).append(handle)
        if len(self._entries) > MAX_PENDING:
            self.pop(next(iter(self._entries)))

    def oldest(self, task: np.ndarray) -> int | None:
        """The handle of the oldest proposal that `task` matches; None if none does."""
        return next(self._matching(task, newest_first=False), None)

    def newest(self, task: np.ndarray) -> int | None:
        """The handle of the newest proposal that `task` matches; None if none does."""
        return next(self._matching(task, newest_first=True), None)

    def _matching(self, task: np.ndarray, newest_first: bool):
        """The handles `task` matches, lazily, in order of age (replayed levels put many equal
        proposals in one bucket: the first match ends the search)."""
        task = np.asarray(task, dtype=np.float64).reshape(self.dim)
        handles = [h for key in self._candidate_keys(task) for h in self._buckets.get(key, ())]
        handles.sort(reverse=newest_first)
        values, rule = task.tolist(), self._rule
        for h in handles:
            proposed = self._entries[h][0].tolist()
            if all(abs(p - t) / s <= tol for p, t, (s, tol) in zip(proposed, values, rule)):
                yield h

    def payload(self, handle: int):
        return self._entries[handle][1]

    def pop(self, handle: int) -> tuple[np.ndarray, object]:
        """Forget proposal `handle`; returns its (task, payload)."""
        task, payload = self._entries.pop(handle)
        key = self._key(task)
        bucket = self._buckets[key]
        bucket.remove(handle)
        if not bucket:
            del self._buckets[key]
        return task.copy(), payload

    def items(self) -> list:
        """[(task, payload)], oldest first (for checkpoints)."""
        return [(task.copy(), payload) for task, payload in self._entries.values()]

    def columns(self, names: tuple[str, ...]) -> dict[str, np.ndarray]:
        """The proposals as arrays, oldest first (a checkpoint writes a few arrays, not one a
        proposal): `tasks` (M, dim), then one column per name of the payloads' integer fields
        (a payload is a tuple of them, or one integer when there is one name)."""
        items = list(self._entries.values())
        tasks = np.array([t for t, _ in items], dtype=np.float64).reshape(len(items), self.dim)
        fields = np.array([p for _, p in items], dtype=np.int64).reshape(len(items), len(names))
        return {"tasks": tasks, **{name: fields[:, k] for k, name in enumerate(names)}}

    def load_columns(self, columns: dict, names: tuple[str, ...]) -> None:
        """Replace the proposals with `columns(names)`'s."""
        fields = [np.asarray(columns[name], dtype=np.int64).tolist() for name in names]
        payloads = zip(*fields) if len(names) > 1 else fields[0]
        self.load(zip(np.asarray(columns["tasks"]).reshape(-1, self.dim), payloads))

    def load(self, items) -> None:
        """Replace the proposals with [(task, payload)], oldest first."""
        self._entries.clear()
        self._buckets.clear()
        for task, payload in items:
            self.add(task, payload)
