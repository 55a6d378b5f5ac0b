"""Dimension shuffling: a seeded bijection of the task box that hides its structure from a teacher.

TeachMyAgent's "rugged difficulty" challenge cuts each dimension into 4 intervals and permutes
them, so tasks that are close for the teacher can differ widely in difficulty. The teacher samples
in its own space, the environment plays the shuffled task, and the controller inverts the map on
every played task to credit the teacher's own task.
"""

from __future__ import annotations

import numpy as np

_SNAP = 1e-6  # in interval widths: values this close to an interval's end belong to the next one


class DimensionsShuffler:
    """A per-dimension piecewise-translation bijection of the task box.

    Each dimension is cut into `cuttings` equal intervals, which are permuted (one seeded
    permutation per dimension); a value keeps its offset inside its interval. Intervals are
    half-open [a, b) and the upper bound maps to itself, which makes the map a bijection of the
    closed box. Values within 1e-6 interval widths of an interval's end are snapped to the next
    interval's start, so float32 round trips never jump a whole interval. Inputs outside the
    bounds are clipped; constant dimensions are left unchanged.
    """

    def __init__(self, low, high, cuttings: int = 4, seed: int | None = None):
        self.low = np.asarray(low, dtype=np.float64).reshape(-1)
        self.high = np.asarray(high, dtype=np.float64).reshape(-1)
        if self.low.shape != self.high.shape or np.any(self.low > self.high):
            raise ValueError(
                f"DimensionsShuffler: low {self.low} and high {self.high} must have the same shape and low <= high"
            )
        if not isinstance(cuttings, (int, np.integer)) or cuttings < 1:
            raise ValueError(f"cuttings must be an integer >= 1, got {cuttings!r}")
        self.cuttings = int(cuttings)
        rng = np.random.default_rng(seed)
        self.perms = (
            np.stack([rng.permutation(self.cuttings) for _ in range(len(self.low))])
            if len(self.low)
            else np.zeros((0, self.cuttings), dtype=np.int64)
        )
        self.inverse_perms = np.argsort(self.perms, axis=1)
        self.width = (self.high - self.low) / self.cuttings

    def _apply(self, x, table: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if x.shape[-1:] != self.low.shape:
            raise ValueError(
                f"DimensionsShuffler: expected vectors of {len(self.low)} values, got shape {x.shape}"
            )
        active = self.width > 0
        u = np.clip(
            np.divide(x - self.low, self.width, out=np.zeros_like(x), where=active),
            0,
            self.cuttings,
        )
        i = np.floor(u)
        frac = u - i
        snap = frac > 1 - _SNAP
        i, frac = np.where(snap, i + 1, i), np.where(snap, 0.0, frac)
        top = i >= self.cuttings
        idx = np.minimum(i, self.cuttings - 1).astype(np.int64)
        mapped = np.take_along_axis(
            np.broadcast_to(table, idx.shape[:-1] + table.shape), idx[..., None], -1
        )[..., 0]
        out_u = np.where(top, self.cuttings, mapped + frac)
        return np.where(active, self.low + out_u * self.width, x)

    def forward(self, x) -> np.ndarray:
        """Teacher space -> environment space."""
        return self._apply(x, self.perms)

    def inverse(self, y) -> np.ndarray:
        """Environment space -> teacher space."""
        return self._apply(y, self.inverse_perms)
