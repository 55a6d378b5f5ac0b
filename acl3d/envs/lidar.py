"""Lidars: 10 rays cast from the body's head in the sagittal plane, as in TeachMyAgent.

Ray i points along (sin t_i, 0, -cos t_i) in the world frame with t_i = a*i/10 + b; the reading is
the hit distance as a fraction of the range (1 = nothing within range). Only geoms in group 0
(the terrain and, in Parkour, water and creepers) are seen: never the body itself.
"""

from __future__ import annotations

import copy
from typing import ClassVar, Protocol

import mujoco
import numpy as np

from acl3d.envs.array_ops import NUMPY, ArrayOps, index_ids

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
    ops: ArrayOps  # the array library it reads (numpy, or torch after a sensor's `on(ops)`)


class Lidar(TerrainSensor):
    """The rays cast by MuJoCo on one env's scene (whatever geoms it holds)."""

    reads_height_rows = False
    ops: ArrayOps = NUMPY

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
    (h - z0) / (x - x0) reaches the ray's slope; with a running maximum of those slopes, a count
    finds it for all rays, and the crossing is solved on the segment before it. `mj_multiRay`
    instead visits every heightfield column. Forward/downward rays only ("down"). Written once
    over `ArrayOps`: numpy for the CPU envs, torch for the many worlds (`on(ops)`).
    """

    reads_height_rows = True
    _constants = ("_x_padded", "_slope", "_inv_sin", "_x_min", "_cell", "_inv_range")
    _constants += ("_zero", "_one", "_inf")  # (0-d arrays, see the constructor)
    _indices = ("_slanted", "_vertical", "_first_col", "_last_col", "_next")

    def __init__(
        self, arena, kind: str = "down", nb_rays: int = NB_RAYS, ray_range: float = LIDAR_RANGE
    ):
        super().__init__(kind, nb_rays, ray_range)
        sin, cos = self._vec[0::3], -self._vec[2::3]
        if np.any(sin < -1e-12):
            raise ValueError(
                f"HeightLineLidar casts forward/downward rays only; lidar type {kind!r} looks back"
            )
        # a distance d reads min(d * inv_range, 1) (nan: 1), which is 1 exactly beyond the range
        # when the rounded products order as the distances do at the range (as at 160/30)
        inv, above = self._inv_range, np.nextafter(ray_range, np.inf)
        if not ray_range * inv <= 1.0 <= above * inv:
            raise ValueError(f"ray_range {ray_range!r}: d * (1 / range) crosses 1 off the range")
        self.arena = arena
        self._x_min, self._cell, self._ncol = arena.grid.x_min, arena.grid.cell, arena.grid.ncol
        vertical = sin <= 1e-12
        self._vertical = NUMPY.index(np.flatnonzero(vertical))  # slices where contiguous
        self._slanted = NUMPY.index(np.flatnonzero(~vertical))
        sin_s = sin[~vertical]
        # (1, rays): numpy's ufuncs take arrays of one shape, as one env's are, faster
        self._slope = (-cos[self._slanted] / sin_s)[None]  # dz/dx of each slanted ray, increasing
        self._inv_sin = (1.0 / sin_s)[None]
        self._reach = int(np.ceil(ray_range * sin.max() / self._cell)) + 2
        self._width = self._ncol + self._reach + 1
        x = arena.grid.x
        self._x_padded = np.concatenate(
            (x, x[-1] + self._cell * np.arange(1, self._width - self._ncol + 1))
        )
        self._terrain_geom = arena.model.geom("terrain").id
        # the step's scalars as 0-d arrays: numpy's ufuncs take them faster than Python floats
        scalars = (self._x_min, self._cell, self._inv_range, 0.0, 1.0, np.inf)
        self._x_min, self._cell, self._inv_range, self._zero, self._one, self._inf = (
            np.asarray(v, dtype=np.float64) for v in scalars
        )
        self._first_col, self._last_col, self._next = (
            np.asarray(v, dtype=np.int64) for v in (0, self._ncol - 2, 1)
        )

    def on(self, ops: ArrayOps) -> HeightLineLidar:
        """This lidar reading arrays of `ops` (the many-world simulation's tensors)."""
        out = copy.copy(self)
        out.ops = ops
        for name in self._constants:
            setattr(out, name, ops.asarray(getattr(self, name)))
        for name in self._indices:
            setattr(out, name, ops.index(index_ids(getattr(self, name))))
        return out

    def read(self, model, data, origin) -> np.ndarray:
        heights = self.batch_heights(1)
        heights[0, : self._ncol] = self.arena.heights
        out = self.read_batch(heights, np.asarray(origin, dtype=float)[None])[0]
        self.geom_ids[:] = np.where(out < 1.0, self._terrain_geom, -1)
        return out

    def batch_heights(self, n: int):
        """Buffer for `read_batch`: N height lines of the grid's columns, then a -inf margin (the
        columns past the track end, which no ray crosses)."""
        out = self.ops.full((n, self._width), -np.inf)
        out[:, : self._ncol] = 0.0
        return out

    def read_batch(self, heights, origins, rotations=None):
        """The rays of N envs: heights from `batch_heights`, origins (N, 3) -> (N, nb_rays)
        fractions of the range (1: no hit); the roots' orientations (`rotations`, the height
        scan's) are not used: the rays stay sagittal.

        For each ray, the crossed segment ends at the first column whose running maximum
        elevation slope reaches the ray's slope: as both increase, that is how many columns stay
        below it. Element by element the arithmetic does not depend on N (no sums across
        envs), so each row is bit-identical to the same env read alone.
        """
        ops, xp = self.ops, self.ops.xp
        x0, z0 = origins[:, 0:1], origins[:, 2:3]  # (N, 1)
        j = ops.clip(ops.to_int((x0 - self._x_min) / self._cell), self._first_col, self._last_col)
        # the origin's column, then those a ray may cross (copies: rewritten below)
        width = self._reach + 2
        hs, xs = ops.window(heights, j, width), ops.window(self._x_padded, j, width)
        frac = (x0 - xs[:, 0:1]) / self._cell
        h0 = hs[:, 0:1] + frac * (hs[:, 1:2] - hs[:, 0:1])  # the terrain right under the origin
        # the chain from the origin's foot (x0, h0) through the columns past it, ending in a
        # point infinitely high: a ray that crosses no segment within reach meets the last one,
        # of slope inf, at nan, so its distance is nan and it reads 1 (no hit)
        xs[:, 0:1], hs[:, 0:1], hs[:, -1:] = x0, h0, self._inf
        x0, z0 = ops.per_row(x0), ops.per_row(z0)  # operands against (N, columns or rays)
        with ops.quiet():  # a column at x0 itself, or a segment parallel to a ray: no hit there
            rise = (hs[:, 1:-1] - z0) / (xs[:, 1:-1] - x0)
            k = ops.count_below(ops.running_max(rise), self._slope[0])
            k1 = k + self._next  # the crossed segment: points k and k + 1
            xa, xb, ha, hb = (
                ops.gather(xs, k),
                ops.gather(xs, k1),
                ops.gather(hs, k),
                ops.gather(hs, k1),
            )
            s = self._slope
            m = (hb - ha) / (xb - xa)
            x_hit = (z0 - ha + m * xa - s * x0) / (m - s)
            dist = ops.full((len(heights), self.nb_rays), 0.0)
            dist[:, self._slanted] = (x_hit - x0) * self._inv_sin
        dist[:, self._vertical] = z0 - h0
        out = xp.fmin(dist * self._inv_range, self._one)  # nan (no hit) and out of range: 1
        return xp.where(z0 <= h0, self._zero, out)  # the origin is inside the terrain
