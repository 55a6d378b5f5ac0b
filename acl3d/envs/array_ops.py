"""The array library the rules and terrain sensors run on: numpy for the CPU envs, torch for the
many-world simulation.

Both are written once against an `ArrayOps`: `ops.xp` is the library itself (numpy or torch) for
the functions both spell and compute alike (`where`, `abs`, `sign`, `floor`, `sqrt`, `hypot`,
`minimum` / `maximum` of two arrays, `amin` / `amax`, `einsum`, `zeros_like`,
`concatenate(..., axis=)`, and array methods such as `.sum(axis=)`, `.any(axis=)`, `.all(axis=)`,
`.reshape`), and `ArrayOps` methods cover the rest:

* `atan2`: numpy's vector `arctan2` differs from the C library's `atan2` by one ulp on about 7%
  of inputs on a CPU with AVX-512 (2026-11-26, numpy 2.4), so the CPU path computes it per
  element with `math.atan2`: the bits of a run then do not depend on the host's instruction set.
* `clip`, `to_int`, `to_float`: spelled differently (`np.minimum` / `Tensor.clamp`, ...).
* `running_max` (`np.maximum.accumulate` / `torch.cummax`), `count_below` (a row-wise
  `searchsorted`, which numpy has for one row only), `gather` and `window` (consecutive columns
  from a per-row start: a slice for one env).
* sparse work: `needed(mask)` and `pairs(mask)` let numpy skip or compact what no row needs
  (a host check, cheap on the CPU), where torch keeps every row and masks (no host sync on a
  GPU); `scatter_min` reduces per-pair values back to rows.
* where arrays live and in which precision (`asarray`, `index`, `full`).
* `per_row`: (N, 1) values as an operand against (N, M) arrays. numpy's ufuncs take operands of
  one shape, or 0-d ones, at about a third of the cost of broadcasting a (1, 1) array or
  converting a Python float, so numpy gives one row's as a 0-d view, and the rules keep their
  constants as (1, ·) rows and 0-d arrays (one env's arrays are (1, ·)).

Why not the Array API standard through `array-api-compat`: its torch namespace wraps `minimum`,
`maximum`, `where` and others to promote Python scalars, which made the tracks' rules on torch
~20% slower per step (2026-11-26, `scripts/bench_rules.py`), and a few of its numpy functions
(`sum`, `any`, `reshape`, `astype`) cost twice numpy's own on the single env's 1-row arrays.
"""

from __future__ import annotations

import contextlib
import math
from abc import ABC, abstractmethod

import numpy as np


class ArrayOps(ABC):
    """One array library, device and float precision (see the module docstring)."""

    xp = None  # the library: numpy or torch

    @abstractmethod
    def asarray(self, values):
        """Floats in this library's precision, on its device."""

    @abstractmethod
    def index(self, ids):
        """Integer indices (or one integer, 0-d) on this library's device (a contiguous run may
        stay a slice)."""

    @abstractmethod
    def full(self, shape, value):
        """A float array of `shape` filled with `value`."""

    @abstractmethod
    def atan2(self, y, x):
        """Element-wise atan2(y, x)."""

    @abstractmethod
    def clip(self, a, low=None, high=None):
        """`a` limited to [low, high] (either bound may be None)."""

    @abstractmethod
    def to_int(self, a):
        """int64 of `a`, truncated toward zero."""

    @abstractmethod
    def to_float(self, a):
        """`a` (flags or numbers) as floats of this precision."""

    @abstractmethod
    def running_max(self, a):
        """Cumulative maximum along the last axis."""

    @abstractmethod
    def count_below(self, rows, values):
        """(N, V) integers: how many entries of each nondecreasing row of `rows` (N, W) are below
        each of the increasing `values` (V,) (a row-wise `searchsorted`)."""

    @abstractmethod
    def gather(self, a, index):
        """a[i, index[i, j]] for 2-D `a` and `index` (a new array)."""

    @abstractmethod
    def window(self, a, start, width: int):
        """(N, width): columns start[i] .. start[i] + width - 1 of row i of `a` (N, W), or of
        the row `a` (W,) that all N share, for integers `start` (N, 1) (a new array)."""

    @abstractmethod
    def per_row(self, a):
        """(N, 1) values, one per row, as an operand against (N, M) arrays (equal results)."""

    @abstractmethod
    def needed(self, mask) -> bool:
        """False only if no entry of `mask` holds and this library can tell cheaply."""

    @abstractmethod
    def pairs(self, mask):
        """(rows, cols) index arrays of the entries of the 2-D `mask` to compute: at least
        those that hold (numpy: exactly those)."""

    @abstractmethod
    def scatter_min(self, values, rows, n: int):
        """(n, R): the minimum per row of `values` (R, M) whose column m belongs to row
        `rows[m]` (inf where none)."""

    def quiet(self):
        """A context in which divisions by zero give inf or nan silently (torch's default)."""
        return contextlib.nullcontext()


class NumpyOps(ArrayOps):
    """float64 numpy arrays: the CPU envs (bit-identical whatever the batch size)."""

    xp = np

    def __init__(self):
        self._row_start: dict[tuple[int, int], np.ndarray] = {}
        self._cols: dict[int, np.ndarray] = {}

    def _row_starts(self, n: int, width: int) -> np.ndarray:
        """(n, 1): where each row of an (n, width) array starts in the flat array."""
        if (n, width) not in self._row_start:
            self._row_start[n, width] = np.arange(n)[:, None] * width
        return self._row_start[n, width]

    def _columns(self, width: int) -> np.ndarray:
        if width not in self._cols:
            self._cols[width] = np.arange(width)
        return self._cols[width]

    def asarray(self, values):
        return np.asarray(values, dtype=np.float64)

    def index(self, ids):
        """`ids` as a slice where they are a contiguous ascending run (indexing then gives a
        view, not a gathered copy: the same arithmetic, cheaper numpy calls), else as is."""
        ids = np.asarray(ids, dtype=np.int64)
        if ids.ndim == 1 and len(ids) and np.array_equal(ids, np.arange(ids[0], ids[0] + len(ids))):
            return slice(int(ids[0]), int(ids[0]) + len(ids))
        return ids

    def full(self, shape, value):
        """`empty` and `fill`: a third of `np.full`'s time on small arrays."""
        out = np.empty(shape)
        out.fill(value)
        return out

    def atan2(self, y, x):
        return np.array(list(map(math.atan2, y.tolist(), x.tolist())))

    def clip(self, a, low=None, high=None):
        """`np.minimum` / `np.maximum`: `np.clip` costs 5x more on small arrays."""
        if low is not None:
            a = np.maximum(a, low)
        return a if high is None else np.minimum(a, high)

    def to_int(self, a):
        return a.astype(np.int64)

    def to_float(self, a):
        return a.astype(np.float64)

    def running_max(self, a):
        """One row's through its 1-D view (a sixth cheaper)."""
        if len(a) == 1:
            return np.maximum.accumulate(a[0], -1)[None]
        return np.maximum.accumulate(a, -1)

    def count_below(self, rows, values):
        """One `searchsorted` for one row (the array's method: a third of `np.searchsorted`'s
        time); for N rows, each entry's count of values it reaches, tallied per row
        (`bincount`) and summed up: 3x cheaper than comparing all pairs."""
        n, v = len(rows), len(values)
        if n == 1:
            return rows[0].searchsorted(values)[None]
        reached = values.searchsorted(rows, side="right") + self._row_starts(n, v + 1)
        tally = np.bincount(reached.ravel(), minlength=n * (v + 1)).reshape(n, v + 1)
        return tally.cumsum(axis=1)[:, :-1]

    def gather(self, a, index):
        """Indexing the flat array: half the time of `a[rows, index]` on 64 rows, a fifth of it
        on one."""
        n, width = a.shape
        if n == 1:
            return a.reshape(-1)[index]
        return a.reshape(-1)[index + self._row_starts(n, width)]

    def window(self, a, start, width: int):
        """One env: a slice's copy (a third of an index's time); N envs: `gather`."""
        if len(start) == 1:
            first = start.item()
            return (a[None] if a.ndim == 1 else a)[:, first : first + width].copy()
        cols = start + self._columns(width)
        return a[cols] if a.ndim == 1 else self.gather(a, cols)

    def per_row(self, a):
        """One row's as a 0-d view: numpy's ufuncs broadcast it at a third of a (1, 1) array's
        cost."""
        return a[0, 0, ...] if a.shape == (1, 1) else a

    def needed(self, mask) -> bool:
        return bool(mask.any())

    def pairs(self, mask):
        return np.nonzero(mask)

    def scatter_min(self, values, rows, n: int):
        out = np.full((len(values), n), np.inf)
        np.minimum.at(out, (slice(None), rows), values)
        return out.T

    def quiet(self):
        return np.errstate(divide="ignore", invalid="ignore")


NUMPY = NumpyOps()


def index_ids(index) -> np.ndarray:
    """The ids of an index `NumpyOps.index` made (a slice, or ids as they were)."""
    if isinstance(index, slice):
        return np.arange(index.start, index.stop)
    return np.asarray(index)


class TorchOps(ArrayOps):
    """torch tensors on `device` in `dtype`: the many-world simulation (imports torch)."""

    def __init__(self, device, dtype):
        import torch

        self.xp = torch
        self.device, self.dtype = torch.device(device), dtype
        self._cols: dict[int, object] = {}  # width -> arange on the device, made once

    def asarray(self, values):
        return self.xp.as_tensor(np.asarray(values, dtype=np.float64)).to(self.device, self.dtype)

    def index(self, ids):
        return self.xp.as_tensor(np.asarray(ids, dtype=np.int64), device=self.device)

    def full(self, shape, value):
        return self.xp.full(shape, value, device=self.device, dtype=self.dtype)

    def atan2(self, y, x):
        return self.xp.atan2(y, x)

    def clip(self, a, low=None, high=None):
        return a.clamp(low, high)

    def to_int(self, a):
        return a.long()

    def to_float(self, a):
        return a.to(self.dtype)

    def running_max(self, a):
        return self.xp.cummax(a, dim=-1).values

    def count_below(self, rows, values):
        return self.xp.searchsorted(rows, values.expand(len(rows), -1).contiguous())

    def gather(self, a, index):
        return a.gather(1, index)

    def window(self, a, start, width: int):
        if width not in self._cols:
            self._cols[width] = self.xp.arange(width, device=self.device)
        cols = start + self._cols[width]
        return a[cols] if a.ndim == 1 else a.gather(1, cols)

    def per_row(self, a):
        return a

    def needed(self, mask) -> bool:
        return True  # asking would wait for the device

    def pairs(self, mask):
        n, m = mask.shape
        rows = self.xp.arange(n, device=self.device)[:, None].expand(n, m).reshape(-1)
        cols = self.xp.arange(m, device=self.device).repeat(n)
        return rows, cols

    def scatter_min(self, values, rows, n: int):
        out = self.full((n, values.shape[0]), float("inf"))
        src = values.T
        return out.scatter_reduce_(0, rows[:, None].expand_as(src), src, "amin")
