"""Parkour's typed lidar: the original's rays cast analytically on its surfaces, with flags.

Same rays as the track lidar (`acl3d.envs.lidar`: angles a*i/10 + b per type, 5.33 m). Ground
and ceiling are piecewise-linear height lines along x (exactly what the heightfields hold),
creepers are boxes (static, or swinging segments on the CPU), the water is a horizontal plane
seen from above only (the original does not see its surface from inside). Casting on these
shapes gives the distances `mj_multiRay` gives (tested) several times faster on the two
240-column heightfields, for N envs at once.

Written once over `ArrayOps` (`cast`): the CPU envs read their rows' lines and their creepers'
poses from the physics (`read_rows`), the many-world simulation its worlds' records
(`acl3d.envs.tensor_parkour_rules`), with `on(ops)`. Element by element the arithmetic does not
depend on N (only exact reductions: min and max), so each row is bit-identical to the env cast
alone.
"""

from __future__ import annotations

import copy
from typing import NamedTuple

import numpy as np

from acl3d.envs.array_ops import NUMPY, ArrayOps
from acl3d.envs.lidar import LIDAR_RANGE, LIDAR_TYPES, NB_RAYS, TerrainSensor

WATER_FLAG, CREEPER_FLAG = -1.0, 1.0
_MIN_DIRECTION = 1e-12  # a ray component below this (parallel to a box face) counts as this


class CreeperBoxes(NamedTuple):
    """N envs' creeper boxes, (N, P, ...) arrays: centres (3), rotations (3, 3: the box axes as
    columns; None: axis-aligned), half sizes (3), bounding radii and which are in use (bool)."""

    centres: object
    rotations: object
    half: object
    rbound: object
    used: object


def creeper_boxes(xpos, xmat, pool, size, rbound, count) -> CreeperBoxes:
    """The CPU envs' creeper boxes: the poses of the pool's geoms (N, ngeom, 3) and (N, ngeom,
    9), their half sizes (N, P, 3) and bounding radii (N, P), the first `count` (N,) in use
    (the pool cut after the last box any env uses)."""
    n, used = len(xpos), int(count.max())
    pool = pool[:used]
    return CreeperBoxes(
        xpos[:, pool], xmat[:, pool].reshape(n, -1, 3, 3), size[:, :used], rbound[:, :used],
        np.arange(used) < count[:, None],
    )  # fmt: skip


class ParkourLidar(TerrainSensor):
    """The typed lidar of Parkour's rules (see the module docstring): `nb_rays` fractions in
    [0, 1] (1: nothing within range) and as many surface flags (water -1, creeper +1, else 0)."""

    reads_height_rows = False  # it reads the ground, ceiling and water rows of `ParkourRules`
    ops: ArrayOps = NUMPY

    def __init__(self, kind: str, arena, nb_rays: int = NB_RAYS, ray_range: float = LIDAR_RANGE):
        if kind not in LIDAR_TYPES:
            raise ValueError(f"lidar type {kind!r}; valid: {list(LIDAR_TYPES)}")
        a, b = LIDAR_TYPES[kind]
        angles = a * np.arange(nb_rays) / nb_rays + b
        self.kind, self.nb_rays, self.range = kind, nb_rays, ray_range
        self.directions = np.stack([np.sin(angles), np.zeros(nb_rays), -np.cos(angles)], axis=1)
        self._dx = self.directions[:, 0].copy()[None, :, None]  # (1, rays, 1): rows x segments
        self._dz = self.directions[:, 2].copy()[None, :, None]
        self._directions = self.directions
        self._box_d = np.where(
            np.abs(self.directions) < _MIN_DIRECTION, _MIN_DIRECTION, self.directions
        )
        # how far back and ahead along x the rays reach
        self._reach_back = self.range * min(0.0, self.directions[:, 0].min())
        self._reach_ahead = self.range * max(0.0, self.directions[:, 0].max())
        self.arena = arena
        self._pool = arena.creeper_geoms  # the same geom ids in every env's model
        grid = self._grid = arena.grid
        self._x = grid.x
        # columns a window of reach can span (the int() truncations add up to 2)
        width = int((self._reach_ahead - self._reach_back) / grid.cell) + 3
        self._window = np.arange(min(width, grid.ncol))
        with np.errstate(divide="ignore"):  # distance per metre of height to the water plane
            self._inv_down = np.where(
                self.directions[:, 2] < 0.0, -1.0 / self.directions[:, 2], np.inf
            )

    def on(self, ops: ArrayOps) -> ParkourLidar:
        """This lidar casting on arrays of `ops` (the many worlds' records' lines and boxes)."""
        out = copy.copy(self)
        out.ops = ops
        for name in ("_dx", "_dz", "_directions", "_box_d", "_x", "_inv_down"):
            setattr(out, name, ops.asarray(getattr(self, name)))
        out._window = ops.index(self._window)
        return out

    # ------------------------------------------------------------------ the CPU envs
    def read(self, model, data, origin) -> np.ndarray:
        """Fractions in [0, 1] (1 = nothing within range) for this env's arena alone."""
        arena = self.arena
        creepers = creeper_boxes(
            data.geom_xpos[None], data.geom_xmat[None], self._pool, arena.creeper_size[None],
            arena.creeper_rbound[None], np.array([arena.nb_creeper_geoms]),
        )  # fmt: skip
        fractions, _ = self.cast(
            arena.heights[None],
            arena.ceiling_heights[None],
            np.array([arena.water.level]),
            np.asarray(origin, dtype=np.float64)[None],
            creepers,
        )
        return fractions[0]

    def read_rows(self, physics, rows, origins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(fractions (N, rays) in [0, 1], surface flags (N, rays)) for the N envs of `rows`,
        rays from `origins` (N, 3)."""
        creepers = creeper_boxes(
            physics.field("geom_xpos"), physics.field("geom_xmat"), self._pool,
            rows.creeper_size, rows.creeper_rbound, rows.creeper_count,
        )  # fmt: skip
        return self.cast(rows.ground, rows.ceiling, rows.water_level, origins, creepers)

    # ------------------------------------------------------------------ casting
    def cast(self, ground, ceiling, water_level, origins, creepers: CreeperBoxes):
        """(fractions (N, rays), flags (N, rays)) of rays from `origins` (N, 3) on N envs'
        ground and ceiling lines (N, ncol), water levels (N,) and creeper boxes."""
        xp = self.ops.xp
        x0, z0 = origins[:, 0], origins[:, 2]
        best = self.ops.clip(self._surface_hits(ground, ceiling, x0, z0), high=self.range)
        creeper = self._creeper_hits(origins, creepers)
        on_creeper = creeper < best
        best = xp.where(on_creeper, creeper, best)
        flags = xp.where(on_creeper, CREEPER_FLAG, 0.0)
        height = (z0 - water_level)[:, None]
        above = height > 0.0  # rays from under water do not see its surface
        if self.ops.needed(above):
            with self.ops.quiet():  # 0 * inf where a ray does not go down
                water = xp.where(above, height * self._inv_down, np.inf)
            on_water = water < best
            best = xp.where(on_water, water, best)
            flags = xp.where(on_water, WATER_FLAG, flags)
        miss = best >= self.range
        return xp.where(miss, 1.0, best / self.range), xp.where(miss, 0.0, flags)

    def _surface_hits(self, ground, ceiling, x0, z0):
        """(N, rays) distance to the first crossing of each env's ground or ceiling polyline
        within the columns its rays can reach (inf: none); a surface wholly out of reach is
        skipped, as for one env."""
        ops, xp, grid = self.ops, self.ops.xp, self._grid
        i0 = ops.clip(ops.to_int((x0 + self._reach_back - grid.x_min) / grid.cell), low=0)
        i1 = ops.clip(
            ops.to_int((x0 + self._reach_ahead - grid.x_min) / grid.cell) + 1, high=grid.ncol - 1
        )
        cols = i0[:, None] + self._window
        inside = cols <= i1[:, None]  # (N, W): the window's columns
        cols = ops.clip(cols, high=grid.ncol - 1)
        xs = self._x[cols]
        zg, zc = ops.gather(ground, cols), ops.gather(ceiling, cols)
        ground_near = xp.amax(xp.where(inside, zg, -np.inf), axis=1) >= z0 - self.range
        ceiling_near = xp.amin(xp.where(inside, zc, np.inf), axis=1) <= z0 + self.range
        segments = inside[:, 1:]
        hits = ops.full((len(x0), self.nb_rays), np.inf)
        for zs, near in ((zg, ground_near), (zc, ceiling_near)):
            if ops.needed(near):
                found = self._polyline_hits(xs, zs, x0, z0, segments)
                hits = xp.minimum(hits, xp.where(near[:, None], found, np.inf))
        return hits

    def _polyline_hits(self, xs, zs, x0, z0, segments):
        """(N, rays) distance along each ray to the first crossing of the polylines (xs, zs)
        (N, W) on their valid `segments` (N, W - 1); inf if none."""
        xp = self.ops.xp
        ex, ez = self._grid.cell, (zs[:, 1:] - zs[:, :-1])[:, None, :]
        rx, rz = (xs[:, :-1] - x0[:, None])[:, None, :], (zs[:, :-1] - z0[:, None])[:, None, :]
        dx, dz = self._dx, self._dz
        denom = dx * ez - dz * ex  # d x e
        safe = xp.where(denom == 0.0, 1.0, denom)
        t = (rx * ez - rz * ex) / safe  # (r x e) / (d x e)
        u = (rx * dz - rz * dx) / safe  # (r x d) / (d x e)
        valid = (denom != 0.0) & (u >= 0.0) & (u <= 1.0) & (t >= 0.0) & segments[:, None, :]
        return xp.amin(xp.where(valid, t, np.inf), axis=2)

    def _creeper_hits(self, origins, boxes: CreeperBoxes):
        """(N, rays) distance along each ray to the nearest box in use within reach, entered from
        outside (slab test in the box's frame; inf: none)."""
        ops, xp = self.ops, self.ops.xp
        n = origins.shape[0]
        offsets = origins[:, None, :] - boxes.centres  # (N, P, 3): the origin from the centre
        reach = self.range + boxes.rbound
        near = ((offsets * offsets).sum(axis=-1) <= reach * reach) & boxes.used
        if not ops.needed(near):
            return ops.full((n, self.nb_rays), np.inf)
        env, box = ops.pairs(near)  # (M,) boxes to test
        rel, half = offsets[env, box], boxes.half[env, box]  # (M, 3)
        d = self._box_d[:, None, :]  # (rays, 1, 3)
        if boxes.rotations is not None:  # into the box frame: R^T (o - c), R^T d
            rotations = boxes.rotations[env, box]
            rel = xp.einsum("mkj,mk->mj", rotations, rel)
            d = xp.einsum("mkj,rk->rmj", rotations, self._directions)
            d = xp.where(xp.abs(d) < _MIN_DIRECTION, _MIN_DIRECTION, d)
        t1, t2 = (-half - rel) / d, (half - rel) / d  # (rays, M, 3)
        t_in = xp.amax(xp.minimum(t1, t2), axis=-1)  # (rays, M)
        t_out = xp.amin(xp.maximum(t1, t2), axis=-1)
        hit = (t_in <= t_out) & (t_in > 0.0) & near[env, box]
        return ops.scatter_min(xp.where(hit, t_in, np.inf), env, n)
