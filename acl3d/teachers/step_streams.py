"""What teachers that learn from steps keep of the episodes still running, one row per stream.

A stream is an env (a world) index: episodes of many envs interleave, one step per env at a
time. Both records take a batch of steps, one per stream, in one call with no Python per
stream (a many-world run steps thousands of worlds at once), and give back the episodes the
batch ended in the batch's order: what one-stream calls in that order give, bit for bit. The
rows are dense arrays indexed by stream, grown on demand; `state()` / `load_state()` write and
read the {stream: record} form checkpoints hold.
"""

from __future__ import annotations

import numpy as np

from acl3d import validation

MAX_STREAMS = 1 << 20  # as many as the many-world simulation has worlds


def check_streams(streams, n: int) -> np.ndarray:
    """(n,) distinct stream indices in [0, MAX_STREAMS); None: 0 .. n-1."""
    if streams is None:
        return np.arange(n, dtype=np.int64)
    arr = np.asarray(streams)
    if arr.shape != (n,) or arr.dtype.kind not in "iu":
        raise validation.fail("streams", arr.tolist(), f"({n},) integer env indices")
    arr = arr.astype(np.int64)
    if n and (arr.min() < 0 or arr.max() >= MAX_STREAMS or len(np.unique(arr)) != n):
        raise validation.fail("streams", arr.tolist(), f"distinct indices in [0, {MAX_STREAMS})")
    return arr


def check_states(states, n: int) -> np.ndarray:
    """(n, d) finite states: float32 kept as given (observations are), anything else float64."""
    arr = np.asarray(states)
    if arr.dtype != np.float32:
        arr = validation.real_array("states", arr)
    elif not np.all(np.isfinite(arr)):
        raise validation.fail("states", "non-finite values", "finite states")
    if arr.ndim < 1 or arr.shape[0] != n:
        raise validation.fail("states", arr.shape, f"({n}, ...) states, one per step")
    return arr.reshape(n, -1)


def _ranks(counts: np.ndarray) -> np.ndarray:
    """0 .. counts[i] - 1 for each i in turn, concatenated (each item's place in its group)."""
    return np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)


def _grown(array: np.ndarray, rows: int, columns: int | None = None) -> np.ndarray:
    """`array` zero-padded to at least `rows` (and `columns` along axis 1), doubling."""
    shape = list(array.shape)
    if rows > shape[0]:
        shape[0] = max(rows, 2 * shape[0])
    if columns is not None and columns > shape[1]:
        shape[1] = max(columns, 2 * shape[1])
    if tuple(shape) == array.shape:
        return array
    out = np.zeros(shape, dtype=array.dtype)
    out[tuple(slice(0, k) for k in array.shape)] = array
    return out


class StepTraces:
    """Each stream's running episode as (states, rewards), for Robust PLR's scores. States keep
    the dtype they come in (float32 observations take half the memory of float64).

    Steps are stored in pages of `PAGE` steps drawn from one pool and handed back when their
    episode ends, so memory follows the steps of the running episodes, not the number of
    streams times the longest episode (4,096 worlds of 24 float32 observations, episodes of 500
    steps on average: a peak of 0.3 GB, against 1.2 GB for per-stream rows as long as the
    longest episode, grown by copying)."""

    PAGE = 64

    def __init__(self):
        self.lengths = np.zeros(0, dtype=np.int64)
        self.pages = np.zeros((0, 1), dtype=np.int64)  # stream -> its pages in order, -1: none
        self.states = np.zeros((0, self.PAGE, 0), dtype=np.float32)  # the pool
        self.rewards = np.zeros((0, self.PAGE), dtype=np.float64)
        self._free = np.zeros(0, dtype=np.int64)  # pool pages not in use, a stack

    def add(self, streams: np.ndarray, states: np.ndarray, rewards, dones) -> list:
        """One step per stream (checked inputs: `check_streams`, `check_states`); returns
        [(states, rewards)] of the episodes it ended, in the batch's order."""
        if not len(streams):
            return []
        at = self._fit(streams, states, 1)
        self._write(
            self.pages[streams, at // self.PAGE] * self.PAGE + at % self.PAGE, states, rewards
        )
        self.lengths[streams] = at + 1
        ended = streams[np.asarray(dones, dtype=bool)]
        out = [self._episode(s) for s in ended.tolist()]
        self._release(ended)
        return out

    def _write(self, slots: np.ndarray, states: np.ndarray, rewards) -> None:
        """Steps into the pool's slots (page x PAGE + step in the page): one index per row is
        numpy's fast path, ~2.5x faster than a (page, step) pair."""
        self._steps()[slots] = states
        self.rewards.reshape(-1)[slots] = rewards

    def _steps(self) -> np.ndarray:
        """The pool as one row a step (a view; its shape spelt out: a pool of 0-dimensional
        states has no size to infer it from)."""
        return self.states.reshape(len(self.states) * self.PAGE, self.states.shape[2])

    def _episode(self, stream: int) -> tuple[np.ndarray, np.ndarray]:
        n = int(self.lengths[stream])
        pages = self.pages[stream, : -(-n // self.PAGE)]
        rows = len(pages) * self.PAGE
        return (
            self.states[pages].reshape(rows, self.states.shape[2])[:n],
            self.rewards[pages].reshape(rows)[:n],
        )

    def _release(self, streams: np.ndarray) -> None:
        """The streams' episodes forgotten, their pages back in the pool."""
        pages = self.pages[streams]
        self._free = np.concatenate((self._free, pages[pages >= 0]))
        self.pages[streams] = -1
        self.lengths[streams] = 0

    def _fit(self, streams: np.ndarray, states: np.ndarray, steps: int) -> np.ndarray:
        """Pages for `steps` more steps of `streams`; returns their current lengths."""
        d = states.shape[-1]
        if d != self.states.shape[2]:
            if self.lengths.any():
                raise validation.fail("states", states.shape, f"(n, {self.states.shape[2]})")
            self.states = np.zeros((len(self.states), self.PAGE, d), states.dtype)
        dtype = np.promote_types(self.states.dtype, states.dtype)
        if dtype != self.states.dtype:
            self.states = self.states.astype(dtype)
        rows = int(streams.max()) + 1
        if rows > len(self.lengths):
            rows = max(rows, 2 * len(self.lengths))
            self.lengths = np.concatenate((self.lengths, np.zeros(rows - len(self.lengths), int)))
            more = np.full((rows - len(self.pages), self.pages.shape[1]), -1)
            self.pages = np.concatenate((self.pages, more))
        at = self.lengths[streams]
        first, last = at // self.PAGE, (at + steps - 1) // self.PAGE
        if last.max() >= self.pages.shape[1]:
            wider = max(int(last.max()) + 1, 2 * self.pages.shape[1])
            more = np.full((len(self.pages), wider - self.pages.shape[1]), -1)
            self.pages = np.concatenate((self.pages, more), axis=1)
        # each page the steps reach that the stream does not hold yet: the steps' first page
        # unless they start inside it, and every page after
        start = first + (at % self.PAGE != 0)
        counts = np.maximum(last - start + 1, 0)
        if counts.any():
            owners = np.repeat(streams, counts)
            columns = np.repeat(start, counts) + _ranks(counts)
            self.pages[owners, columns] = self._take(int(counts.sum()))
        return at

    def _take(self, k: int) -> np.ndarray:
        """`k` pages from the pool (grown, doubling, when it has too few)."""
        if k > len(self._free):
            have = len(self.states)
            grown = max(have + k - len(self._free), 2 * have, 16)
            self.states = np.concatenate(
                (self.states, np.zeros((grown - have, *self.states.shape[1:]), self.states.dtype))
            )
            self.rewards = np.concatenate((self.rewards, np.zeros((grown - have, self.PAGE))))
            self._free = np.concatenate((self._free, np.arange(grown - 1, have - 1, -1)))
        taken, self._free = (
            self._free[len(self._free) - k :][::-1],
            self._free[: len(self._free) - k],
        )
        return taken

    def _slots(self, streams: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        """The pool slots of every step of `streams`' running episodes (`lengths` steps each),
        stream after stream, each episode's steps in order."""
        owners, steps = np.repeat(streams, lengths), _ranks(lengths)
        return self.pages[owners, steps // self.PAGE] * self.PAGE + steps % self.PAGE

    def state(self) -> dict:
        """The running episodes as four flat arrays (a checkpoint writes four arrays, not one
        per stream): `streams` and their `lengths`, then every step's `states` and `rewards`,
        stream after stream."""
        streams = np.flatnonzero(self.lengths)
        lengths = self.lengths[streams]
        slots = self._slots(streams, lengths)
        return {
            "streams": streams,
            "lengths": lengths,
            "states": self._steps()[slots],
            "rewards": self.rewards.reshape(-1)[slots],
        }

    @staticmethod
    def flat(streams: dict) -> dict:
        """`state()`'s form of the {stream: [states, rewards]} dict that checkpoints written
        before it hold."""
        keys = sorted(streams, key=int)
        rewards = [np.asarray(streams[k][1], dtype=np.float64).reshape(-1) for k in keys]
        states = [np.asarray(streams[k][0]).reshape(len(r), -1) for k, r in zip(keys, rewards)]
        return {
            "streams": np.array([int(k) for k in keys], dtype=np.int64),
            "lengths": np.array([len(r) for r in rewards], dtype=np.int64),
            "states": np.concatenate(states) if states else np.zeros((0, 0), np.float32),
            "rewards": np.concatenate(rewards) if rewards else np.zeros(0),
        }

    def load_state(self, state: dict) -> None:
        """Continue from `state()`: each running episode in pages of its own, the pool exactly
        as large as they need."""
        self.__init__()
        streams = np.asarray(state["streams"], dtype=np.int64).reshape(-1)
        lengths = np.asarray(state["lengths"], dtype=np.int64).reshape(-1)
        if not len(streams):
            return
        states = np.asarray(state["states"])
        states = states.astype(np.float32 if states.dtype == np.float32 else np.float64)
        counts = -(-lengths // self.PAGE)
        total = int(counts.sum())
        self.lengths = np.zeros(int(streams.max()) + 1, dtype=np.int64)
        self.pages = np.full((len(self.lengths), int(counts.max())), -1, dtype=np.int64)
        self.pages[np.repeat(streams, counts), _ranks(counts)] = np.arange(total)
        self.states = np.zeros((total, self.PAGE, states.shape[1]), dtype=states.dtype)
        self.rewards = np.zeros((total, self.PAGE), dtype=np.float64)
        self.lengths[streams] = lengths
        self._write(self._slots(streams, lengths), states, state["rewards"])


class DiscountedReturns:
    """Each stream's running discounted return, for SPDL: sum over k of discount**k x reward."""

    def __init__(self, discount: float):
        self.discount = float(discount)
        self.sums = np.zeros(0, dtype=np.float64)
        self.counts = np.zeros(0, dtype=np.int64)
        self._powers = np.ones(1, dtype=np.float64)  # discount**k, as Python's float power

    def add(self, streams: np.ndarray, rewards, dones) -> np.ndarray:
        """One step per stream; returns the discounted returns of the episodes it ended."""
        if not len(streams):
            return np.zeros(0)
        rows = int(streams.max()) + 1
        self.sums, self.counts = _grown(self.sums, rows), _grown(self.counts, rows)
        at = self.counts[streams]
        if at.max() >= len(self._powers):
            top = max(int(at.max()) + 1, 2 * len(self._powers))
            self._powers = np.array([self.discount**k for k in range(top)])
        self.sums[streams] = self.sums[streams] + self._powers[at] * np.asarray(rewards, float)
        self.counts[streams] = at + 1
        ended = streams[np.asarray(dones, dtype=bool)]
        out = self.sums[ended].copy()
        self.sums[ended], self.counts[ended] = 0.0, 0
        return out

    def state(self) -> dict:
        return {
            str(s): [float(self.sums[s]), int(n)] for s, n in enumerate(self.counts.tolist()) if n
        }

    def load_state(self, streams: dict) -> None:
        self.__init__(self.discount)
        for key, (total, count) in streams.items():
            s = int(key)
            self.sums, self.counts = _grown(self.sums, s + 1), _grown(self.counts, s + 1)
            self.sums[s], self.counts[s] = float(total), int(count)
