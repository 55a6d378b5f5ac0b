"""Lidars: 10 rays cast from the body's head in the sagittal plane, as in TeachMyAgent.

Ray i points along (sin t_i, 0, -cos t_i) in the world frame with t_i = a*i/10 + b; the reading is
the hit distance as a fraction of the range (1 = nothing within range). Only geoms in group 0
(the terrain and, in Parkour, water and creepers) are seen: never the body itself.
"""

from __future__ import annotations

from typing import ClassVar, Protocol

import mujoco
import numpy as np

LIDAR_RANGE = 160 / 30  # 5.33 m
LIDAR_TYPES = {"down": (1.5, 0.0), "up": (2.3, 1.5), "full": (np.pi, 0.0)}
NB_RAYS = 10


class TerrainSensor(Protocol):
    """What the rules know of their terrain sensor (a lidar or a height scan): `nb_rays`
    readings per env, and which of two ways it reads them.

    A sensor that `reads_height_rows` reads N envs at once from rows of heights the rules keep
    (`batch_heights(n)`, each row filled from its env's `arena.heights`; `read_batch(heights,
    origins, rotations)`), so the batched env steps all its envs as one batch. Any other
    sensor reads one env's own scene (`read(model, data, origin)`), unless its rules keep rows
    of their own for it (Parkour's surfaces, `ParkourLidar.read_rows`).
    """

    nb_rays: int
    reads_height_rows: ClassVar[bool]


class Lidar(TerrainSensor):
    """The rays cast by MuJoCo on one env's scene (whatever geoms it holds)."""

    reads_height_rows = False

    def __init__(self, kind: str = "down", nb_rays: int = NB_RAYS, ray_range: float = LIDAR_RANGE):
        if kind not in LIDAR_TYPES:
            raise ValueError(f"lidar type {kind!r}; valid: {list(LIDAR_TYPES)}")
        a, b = LIDAR_TYPES[kind]
        angles = a * np.arange(nb_rays) / nb_rays + b
        self.kind = kind
        self.range = ray_range
        self._inv_range = 1.0 / ray_range
        self.nb_rays = nb_rays
        self._vec = np.stack([np.sin(angles), np.zeros(nb_rays), -np.cos(angles)], axis=1).ravel()
        self._groups = np.array([1, 0, 0, 0, 0, 0], dtype=np.uint8)
        self.geom_ids = np.zeros(nb_rays, dtype=np.int32)
        self._dist = np.zeros(nb_rays)

    def read(self, model: mujoco.MjModel, data: mujoco.MjData, origin: np.ndarray) -> np.ndarray:
        """Fractions in [0, 1] (1 = no hit); `self.geom_ids` holds the hit geoms (-1 = none).

        `data` is an MjData, or one simulation of a batch (`acl3d.envs.physics.RowData`), whose
        rays MuJoCo's batch casts (the same hits on the static terrain these rays see)."""
        if not isinstance(data, mujoco.MjData):
            self._dist[:], self.geom_ids[:] = data.ray(
                origin, self._vec.reshape(-1, 3), self._groups
            )
        else:
            self._cast(model, data, origin)
        fraction = self._dist * self._inv_range
        miss = (self.geom_ids < 0) | (fraction > 1.0)
        fraction[miss] = 1.0
        self.geom_ids[miss] = -1
        return fraction

    def _cast(self, model: mujoco.MjModel, data: mujoco.MjData, origin: np.ndarray) -> None:
        mujoco.mj_multiRay(
            model,
            data,
            origin,
            self._vec,
            self._groups,
            1,
            -1,
            self.geom_ids,
            self._dist,
            None,
            self.nb_rays,
            self.range,
        )


class HeightLineLidar(Lidar):
    """The same rays, cast analytically on a track's height line (4x fewer microseconds).

    A track is a height line extruded across it, so a sagittal ray meets the terrain where the
    heightfield's centre line does: the piecewise-linear chain through the columns. From the
    origin, the first terrain point above ray i is the first column whose elevation slope
    (h - z0) / (x - x0) reaches the ray's slope; with a running maximum of those slopes, one
    `searchsorted` finds it for all rays, and the crossing is solved on the segment before it.
    `mj_multiRay` instead visits every heightfield column. Forward/downward rays only ("down").
    """

    reads_height_rows = True

    def __init__(
        self, arena, kind: str = "down", nb_rays: int = NB_RAYS, ray_range: float = LIDAR_RANGE
    ):
        super().__init__(kind, nb_rays, ray_range)
        sin, cos = self._vec[0::3], -self._vec[2::3]
        if np.any(sin < -1e-12):
            raise ValueError(
                f"HeightLineLidar casts forward/downward rays only; lidar type {kind!r} looks back"
            )
        self.arena = arena
        self._x_min, self._cell, self._ncol = arena.grid.x_min, arena.grid.cell, arena.grid.ncol
        self._x = arena.grid.x
        vertical = sin <= 1e-12
        self._vertical = np.flatnonzero(vertical)
        self._slanted = np.flatnonzero(~vertical)
        sin_s = sin[self._slanted]
        self._slope = -cos[self._slanted] / sin_s  # dz/dx of each slanted ray, increasing
        self._inv_sin = 1.0 / sin_s
        self._reach = int(np.ceil(ray_range * sin.max() / self._cell)) + 2
        self._terrain_geom = arena.model.geom("terrain").id
        self._no_hit = np.full(nb_rays, np.inf)
        self._batch_n = 0

    def read(self, model, data, origin) -> np.ndarray:
        out = self.read_heights(self.arena.heights, origin)
        self.geom_ids[:] = np.where(out < 1.0, self._terrain_geom, -1)
        return out

    def read_heights(self, heights: np.ndarray, origin: np.ndarray) -> np.ndarray:
        """The rays from `origin` on the height line `heights` (the grid's columns, or more).

        The step's hot path at N = 1: few numpy calls (hits are a prefix of the rays, because
        both the running maximum and the rays' slopes increase, so they are sliced, not masked).
        """
        x0, z0 = float(origin[0]), float(origin[2])
        j = min(max(int((x0 - self._x_min) / self._cell), 0), self._ncol - 2)
        frac = (x0 - self._x[j]) / self._cell
        h0 = heights[j] + frac * (heights[j + 1] - heights[j])  # terrain right under the origin
        if z0 <= h0:  # origin inside the terrain: every ray hits at once
            return np.zeros(self.nb_rays)
        stop = min(j + 1 + self._reach, self._ncol)
        xs = np.concatenate(((x0,), self._x[j + 1 : stop]))
        hs = np.concatenate(((h0,), heights[j + 1 : stop]))
        rise = (hs[1:] - z0) / (xs[1:] - x0)
        np.maximum.accumulate(rise, out=rise)
        k = rise.searchsorted(self._slope)  # segment (k, k+1) holds the crossing
        hits = int(k.searchsorted(len(rise)))  # k never decreases: the first `hits` rays hit
        dist = self._no_hit.copy()
        if hits:
            k = k[:hits]
            after = k + 1
            xa, ha = xs[k], hs[k]
            m = (hs[after] - ha) / (xs[after] - xa)
            s = self._slope[:hits]
            x_hit = (z0 - ha + m * xa - s * x0) / (m - s)
            dist[self._slanted[:hits]] = (x_hit - x0) * self._inv_sin[:hits]
        dist[self._vertical] = z0 - h0
        return np.where(dist <= self.range, dist * self._inv_range, 1.0)

    def batch_heights(self, n: int) -> np.ndarray:
        """Buffer for `read_batch`: N height lines of the grid's columns, then a -inf margin (the
        columns past the track end, which no ray crosses)."""
        out = np.full((n, self._ncol + self._reach + 1), -np.inf)
        out[:, : self._ncol] = 0.0
        return out

    def read_batch(
        self, heights: np.ndarray, origins: np.ndarray, rotations: np.ndarray | None = None
    ) -> np.ndarray:
        """`read` for N envs at once: heights from `batch_heights`, origins (N, 3); the roots'
        orientations (`rotations`, the height scan's) are not used: the rays stay sagittal.

        Element by element the same arithmetic as `read` (no reductions that sum), so each row
        is bit-identical to `read` on that env alone, whatever N.
        """
        n, width = heights.shape
        if n == 1:  # one searchsorted beats the counting below (same results, tested)
            return self.read_heights(heights[0], origins[0])[None]
        if self._batch_n != n:
            self._batch_setup(n, width)
        flat, base, reach = heights.reshape(-1), self._base, self._reach
        x0, z0 = origins[:, 0], origins[:, 2]
        j = ((x0 - self._x_min) / self._cell).astype(np.int64)
        np.minimum(np.maximum(j, 0, out=j), self._ncol - 2, out=j)  # np.clip costs 6x more
        hj, hj1 = flat[base + j], flat[base + j + 1]
        frac = (x0 - self._x[j]) / self._cell
        h0 = hj + frac * (hj1 - hj)
        cols = j[:, None] + self._window
        x0c, z0c = x0[:, None], z0[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            rise = (flat[base[:, None] + cols] - z0c) / (self._x_padded[cols] - x0c)
        np.maximum.accumulate(rise, axis=1, out=rise)
        # k = first column whose running max reaches the ray's slope (segment (k, k + 1)), i.e.
        # how many columns stay below it: count the columns by how many slopes they reach
        reached = np.searchsorted(self._slope, rise, side="right") + self._count_rows
        k = np.bincount(reached.ravel(), minlength=self._count_size).reshape(n, -1)
        k = k.cumsum(axis=1)[:, :-1]
        hit = k < reach
        b = j[:, None] + 1 + k  # the column ending the crossed segment
        first = k == 0
        xa = np.where(first, x0c, self._x_padded[b - 1])
        ha = np.where(first, h0[:, None], flat[base[:, None] + b - 1])
        xb, hb = self._x_padded[b], flat[base[:, None] + b]
        s = self._slope
        with np.errstate(divide="ignore", invalid="ignore"):
            m = (hb - ha) / (xb - xa)
            x_hit = (z0c - ha + m * xa - s * x0c) / (m - s)
        dist = self._dist_buffer
        dist[:, self._slanted] = np.where(hit, (x_hit - x0c) * self._inv_sin, np.inf)
        dist[:, self._vertical] = (z0 - h0)[:, None]
        out = np.where(dist <= self.range, dist * self._inv_range, 1.0)
        out[z0 <= h0] = 0.0  # origin inside the terrain: every ray hits at once
        return out

    def _batch_setup(self, n: int, width: int) -> None:
        self._batch_n = n
        self._base = np.arange(n) * width
        self._window = 1 + np.arange(self._reach)
        pad = self._x[-1] + self._cell * np.arange(1, width - self._ncol + 1)
        self._x_padded = np.concatenate((self._x, pad))
        nb = len(self._slope)
        self._count_rows = np.arange(n)[:, None] * (nb + 1)
        self._count_size = n * (nb + 1)
        self._dist_buffer = np.empty((n, self.nb_rays))
