"""Parkour's rules: water and death flags, grasp state, surface-typed lidars, survival.

Extends the tracks' rules (§2.4.4-2.4.7 of the reference). Observation, in order:
[head (4, or 9 for free 3D bodies), under_water, dead] + motor state + [climbers: per hand
touching, holding] + 10 lidar fractions + 10 surface flags (water -1, creeper +1, else 0).
Unlike the original, a flag is reset to 0 when its ray hits nothing (the original keeps it stale).

Survival: each step while alive, the head above/below the water surface counts consecutive
steps; walkers and climbers die after more than 600 under water, swimmers after more than 600 out
of it, amphibians never. Death zeroes the actions from the next step on (and so their torque
cost) and raises the dead flag; with `end_on_death` it ends the episode instead (no penalty).

Critical contacts: in Parkour a walker's hull is not critical (only bodies listed in
`PARKOUR_CRITICAL_WALKERS` keep theirs); climbers die when a critical part touches anything but
the ceiling (creepers never collide).
"""

from __future__ import annotations

import numpy as np

from acl3d.bodies.base import BoundBody
from acl3d.envs import env_state
from acl3d.envs.array_ops import NUMPY, ArrayOps
from acl3d.envs.climbing import after_steps, before_steps
from acl3d.envs.lidar import LIDAR_RANGE, LIDAR_TYPES, NB_RAYS, TerrainSensor
from acl3d.envs.track_rules import FAIL_REWARD, EpisodeRows, Outcome, TrackRules, torque_use

SURVIVAL_STEPS = 600
SURVIVAL_KEYS = ("steps_under_water", "steps_out_of_water", "dead", "under_water")
WATER_FLAG, CREEPER_FLAG = -1.0, 1.0
PARKOUR_CRITICAL_WALKERS = ("profile_chimpanzee",)  # the chimpanzee's head is always critical
DEFAULT_LIDARS = {"walker": "down", "amphibian": "down", "climber": "up", "swimmer": "full"}


class ParkourLidar(TerrainSensor):
    """The original's 10 rays cast analytically on Parkour's surfaces, with surface-type flags.

    Same rays as the track lidar (`acl3d.envs.lidar`: angles a*i/10 + b per type, 5.33 m).
    Ground and ceiling are piecewise-linear height lines along x (exactly what the heightfields
    hold), creepers are boxes (static or swinging segments), the water is a horizontal plane seen
    from above only (the original does not see its surface from inside). Casting on these
    shapes in numpy gives the distances `mj_multiRay` gives (tested) several times faster on
    the two 240-column heightfields, and for N envs at once (`read_rows`): element by element
    the same arithmetic whatever N (only exact reductions: min and max), so each row is
    bit-identical to the env cast alone.
    """

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
        # how far back and ahead along x the rays reach
        self._reach_back = self.range * min(0.0, self.directions[:, 0].min())
        self._reach_ahead = self.range * max(0.0, self.directions[:, 0].max())
        self.arena = arena
        self._pool = arena.creeper_geoms  # the same geom ids in every env's model
        grid = self._grid = arena.grid
        # columns a window of reach can span (the int() truncations add up to 2)
        width = int((self._reach_ahead - self._reach_back) / grid.cell) + 3
        self._window = np.arange(min(width, grid.ncol))
        with np.errstate(divide="ignore"):  # distance per metre of height to the water plane
            self._inv_down = np.where(
                self.directions[:, 2] < 0.0, -1.0 / self.directions[:, 2], np.inf
            )

    def read(self, model, data, origin) -> np.ndarray:
        """Fractions in [0, 1] (1 = nothing within range) for this env's arena alone."""
        arena = self.arena
        count, size, rbound = arena.nb_creeper_geoms, arena.creeper_size, arena.creeper_rbound
        fractions, _ = self._cast(
            arena.heights[None],
            arena.ceiling_heights[None],
            np.array([arena.water.level]),
            np.asarray(origin, dtype=np.float64)[None],
            (
                data.geom_xpos[None],
                data.geom_xmat[None],
                np.array([count]),
                size[None],
                rbound[None],
            ),
        )
        return fractions[0]

    def read_rows(self, physics, rows, origins: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(fractions (N, rays) in [0, 1], surface flags (N, rays)) for the N envs of `rows`,
        rays from `origins` (N, 3)."""
        creepers = (
            physics.field("geom_xpos"),
            physics.field("geom_xmat"),
            rows.creeper_count,
            rows.creeper_size,
            rows.creeper_rbound,
        )
        return self._cast(rows.ground, rows.ceiling, rows.water_level, origins, creepers)

    def _cast(self, ground, ceiling, water_level, origins, creepers):
        x0, z0 = origins[:, 0], origins[:, 2]
        best = np.minimum(self.range, self._surface_hits(ground, ceiling, x0, z0))
        flags = np.zeros_like(best)
        hits = self._creeper_hits(origins, *creepers)
        if hits is not None:
            on_creeper = hits < best
            best[on_creeper] = hits[on_creeper]
            flags[on_creeper] = CREEPER_FLAG
        height = z0 - water_level
        above = height > 0.0  # rays from under water do not see its surface
        if above.any():
            with np.errstate(invalid="ignore"):  # 0 * inf where a ray does not go down
                water = np.where(above[:, None], height[:, None] * self._inv_down, np.inf)
            on_water = water < best
            best[on_water] = water[on_water]
            flags[on_water] = WATER_FLAG
        miss = best >= self.range
        flags[miss] = 0.0
        return np.where(miss, 1.0, best / self.range), flags

    def _surface_hits(self, ground, ceiling, x0, z0) -> np.ndarray:
        """(N, rays) distance to the first crossing of each env's ground or ceiling polyline
        within the columns its rays can reach (inf: none); a surface wholly out of reach is
        skipped, as for one env."""
        grid, n = self._grid, len(x0)
        i0 = np.maximum(0, ((x0 + self._reach_back - grid.x_min) / grid.cell).astype(np.int64))
        i1 = ((x0 + self._reach_ahead - grid.x_min) / grid.cell).astype(np.int64) + 1
        np.minimum(i1, grid.ncol - 1, out=i1)
        cols = i0[:, None] + self._window
        inside = cols <= i1[:, None]  # (N, W): the window's columns
        np.minimum(cols, grid.ncol - 1, out=cols)
        xs = grid.x[cols]
        env = np.arange(n)[:, None]
        zg, zc = ground[env, cols], ceiling[env, cols]
        ground_near = np.where(inside, zg, -np.inf).max(axis=1) >= z0 - self.range
        ceiling_near = np.where(inside, zc, np.inf).min(axis=1) <= z0 + self.range
        segments = inside[:, 1:]
        hits = np.full((n, self.nb_rays), np.inf)
        for zs, near in ((zg, ground_near), (zc, ceiling_near)):
            if near.any():
                found = self._polyline_hits(xs, zs, x0, z0, segments)
                np.minimum(hits, np.where(near[:, None], found, np.inf), out=hits)
        return hits

    def _polyline_hits(self, xs, zs, x0, z0, segments) -> np.ndarray:
        """(N, rays) distance along each ray to the first crossing of the polylines (xs, zs)
        (N, W) on their valid `segments` (N, W - 1); inf if none."""
        ex, ez = self._grid.cell, (zs[:, 1:] - zs[:, :-1])[:, None, :]
        rx, rz = (xs[:, :-1] - x0[:, None])[:, None, :], (zs[:, :-1] - z0[:, None])[:, None, :]
        dx, dz = self._dx, self._dz
        denom = dx * ez - dz * ex  # d x e
        safe = np.where(denom == 0.0, 1.0, denom)
        t = (rx * ez - rz * ex) / safe  # (r x e) / (d x e)
        u = (rx * dz - rz * dx) / safe  # (r x d) / (d x e)
        valid = (denom != 0.0) & (u >= 0.0) & (u <= 1.0) & (t >= 0.0) & segments[:, None, :]
        return np.where(valid, t, np.inf).min(axis=2)

    def _creeper_hits(self, origins, xpos, xmat, count, size, rbound) -> np.ndarray | None:
        """(N, rays) distance along each ray to the nearest creeper box of its env entered from
        outside (inf: none); None when no env has a creeper within reach. xpos, xmat: the
        envs' (N, ngeom, ...) geom poses; count, size, rbound: their creeper boxes in use
        (the arenas' `nb_creeper_geoms`, `creeper_size`, `creeper_rbound`)."""
        if not count.any():
            return None
        used = int(count.max())
        pool = self._pool[:used]
        offsets = xpos[:, pool] - origins[:, None]  # (N, P, 3)
        reach = self.range + rbound[:, :used]
        near = np.einsum("npj,npj->np", offsets, offsets) <= reach * reach
        near &= np.arange(used) < count[:, None]
        if not near.any():
            return None
        env, box = np.nonzero(near)
        offsets = offsets[env, box]
        rot = xmat[env, pool[box]].reshape(-1, 3, 3)
        size = size[env, box]
        o_local = -np.einsum("nkj,nk->nj", rot, offsets)  # R^T (o - c)
        d_local = np.einsum("nkj,rk->rnj", rot, self.directions)
        d_local[np.abs(d_local) < 1e-12] = 1e-12
        t1 = (-size - o_local) / d_local
        t2 = (size - o_local) / d_local
        t_in = np.minimum(t1, t2).max(axis=-1)
        t_out = np.maximum(t1, t2).min(axis=-1)
        hit = (t_in <= t_out) & (t_in > 0.0)
        out = np.full((self.nb_rays, len(origins)), np.inf)
        np.minimum.at(out, (slice(None), env), np.where(hit, t_in, np.inf))
        return out.T


class ParkourRules(TrackRules):
    """The tracks' rules + water, survival counters, grasping and the Parkour observation layout,
    for N envs at once like the tracks': each env's survival counters, terrain (ground, ceiling,
    water level) and arena (its water forces, grasps and creepers) are its row of the
    `EpisodeRows`; a batch of Parkour envs steps as one."""

    # what the water forces, the grasps and the creeper rays read or write, too
    physics_fields = (
        *TrackRules.physics_fields,
        *("geom_xpos", "geom_xmat", "subtree_com", "xipos", "xaxis", "xanchor", "xquat"),
        *("qfrc_actuator", "xfrc_applied", "eq_active"),
    )
    steps_in_batch = True

    def __init__(
        self,
        bound: BoundBody,
        lidar: ParkourLidar,
        arena,
        end_x: float,
        success_return: float,
        end_on_death: bool = False,
        survival_steps: int = SURVIVAL_STEPS,
    ):
        self.arena = arena  # this env's: its terrain goes to its row at each reset
        self.climber = arena.climbing is not None
        self._nb_grasp = len(bound.body.grasp_sensors)
        super().__init__(bound, lidar, end_x, success_return)
        body = bound.body
        self.kind = body.kind
        critical = bound.critical_geom_ids
        if self.kind == "walker" and body.name not in PARKOUR_CRITICAL_WALKERS:
            critical = np.zeros(0, dtype=int)
        self._critical_any = self._sensor_adr(bound.model, critical)
        self._critical_ceiling = self._sensor_adr(bound.model, critical, against="ceiling")
        self.end_on_death = end_on_death
        self.survival_steps = survival_steps
        self._water_geoms = arena.water.geoms  # the same body geoms in every env's model
        self._water_reach = bound.model.geom_rbound[self._water_geoms]

    def extra_obs_size(self) -> int:
        return 2 + self.lidar.nb_rays  # under_water and dead flags, surface flags

    def new_rows(self, n: int) -> EpisodeRows:
        rows = super().new_rows(n)
        ncol = self.arena.grid.ncol
        rows.ground, rows.ceiling = np.zeros((n, ncol)), np.zeros((n, ncol))
        rows.water_level = np.full(n, -np.inf)
        rows.arenas = np.empty(n, dtype=object)
        pool = len(self.arena.creeper_geoms)
        rows.creeper_count = np.zeros(n, dtype=np.int64)
        rows.creeper_size, rows.creeper_rbound = np.zeros((n, pool, 3)), np.zeros((n, pool))
        rows.steps_under_water = np.zeros(n, dtype=np.int64)
        rows.steps_out_of_water = np.zeros(n, dtype=np.int64)
        rows.dead = np.zeros(n, dtype=bool)
        rows.under_water = np.zeros(n, dtype=bool)
        return rows

    def take_terrain(self, rows: EpisodeRows, i: int = 0) -> None:
        arena = self.arena
        rows.ground[i], rows.ceiling[i] = arena.heights, arena.ceiling_heights
        rows.water_level[i] = arena.water.level
        rows.arenas[i] = arena
        rows.creeper_count[i] = arena.nb_creeper_geoms
        rows.creeper_size[i], rows.creeper_rbound[i] = arena.creeper_size, arena.creeper_rbound

    # ------------------------------------------------------------------ survival
    def begin_episode(self, rows: EpisodeRows) -> None:
        rows.steps_under_water[:] = rows.steps_out_of_water[:] = 0
        rows.dead[:] = False

    def before_physics(self, physics, actions: np.ndarray, rows: EpisodeRows) -> np.ndarray:
        """Dead bodies play zeros; climbers release the grasps their actions let go (all envs at
        once); then the water forces of the envs whose body reaches the water (or just left it:
        their forces are cleared), each on its row."""
        if rows.dead.any():
            actions = np.where(rows.dead[:, None], 0.0, actions)
        if self.climber:
            climbings = [arena.climbing for arena in rows.arenas]
            before_steps(climbings, physics.field("eq_active"), actions[:, -self._nb_grasp :])
        bottoms = physics.field("geom_xpos")[:, self._water_geoms, 2] - self._water_reach
        wet = [arena.water.wet for arena in rows.arenas]
        # per wet env, in plain floats: the same forces on (N, geoms, edges) numpy arrays took
        # 300 us per call for one env against 32 us (docs/benchmarks.md)
        for i in np.flatnonzero((bottoms.min(axis=1) < rows.water_level) | wet):
            rows.arenas[i].water.apply(physics.row_data(i))
        return actions

    def episode_state(self, rows: EpisodeRows) -> dict:
        return {f"survival/{key}": getattr(rows, key)[0].item() for key in SURVIVAL_KEYS}

    def check_episode_state(self, state) -> dict:
        env_state.check_keys(state, [f"survival/{key}" for key in SURVIVAL_KEYS])
        return {
            key: env_state.scalar(
                state, f"survival/{key}", "integer" if key.startswith("steps") else "flag", 0
            )
            for key in SURVIVAL_KEYS
        }

    def set_episode_state(self, checked: dict, rows: EpisodeRows) -> None:
        for key in SURVIVAL_KEYS:
            getattr(rows, key)[0] = checked[key]

    def _update_survival(self, physics, rows: EpisodeRows) -> np.ndarray:
        """Count consecutive steps in/out of water; (N,) flags: the body died this step."""
        under = physics.field("xpos")[:, self.bound.root_id, 2] <= rows.water_level
        rows.under_water[:] = under
        alive = ~rows.dead
        below, above = rows.steps_under_water, rows.steps_out_of_water
        below[:] = np.where(alive, np.where(under, below + 1, 0), below)
        above[:] = np.where(alive, np.where(under, 0, above + 1), above)
        if self.kind in ("walker", "climber"):
            died = alive & (below > self.survival_steps)
        elif self.kind == "swimmer":
            died = alive & (above > self.survival_steps)
        else:
            died = np.zeros_like(alive)
        rows.dead |= died
        return died

    # ------------------------------------------------------------------ observation
    def observe_rows(self, physics, rows) -> tuple[np.ndarray, np.ndarray]:
        obs = np.zeros((len(rows.dead), self.obs_size))
        col = self.head_size
        x = self.head(physics, obs[:, :col])
        obs[:, col] = rows.under_water
        obs[:, col + 1] = rows.dead
        col += 2
        self.motor_state(physics, obs[:, col : col + self._motor_size])
        col += self._motor_size
        if self.climber:
            for i, arena in enumerate(rows.arenas):
                obs[i, col : col + self.grasp_size] = arena.climbing.state()
        col += self.grasp_size
        origins = physics.field("xpos")[:, self.bound.root_id]
        fractions, flags = self.lidar.read_rows(physics, rows, origins)
        obs[:, col : col + self.lidar.nb_rays] = fractions
        obs[:, col + self.lidar.nb_rays :] = flags
        return x, obs

    def reset_rows(self, physics, rows) -> np.ndarray:
        self.begin_episode(rows)
        root_z = physics.field("xpos")[:, self.bound.root_id, 2]
        rows.under_water[:] = root_z <= rows.water_level
        return super().reset_rows(physics, rows)

    def critical_touch(self, physics) -> np.ndarray:
        """(N,) flags: a critical part touches something other than the ceiling (it has more
        contacts than those with the ceiling)."""
        touching = physics.field("sensordata")
        more = touching[:, self._critical_any] > touching[:, self._critical_ceiling]
        return np.logical_or.reduce(more, axis=1)

    def outcome_rows(self, physics, actions: np.ndarray, rows) -> Outcome:
        if self.climber:
            climbings = [arena.climbing for arena in rows.arenas]
            xpos, xmat = physics.field("geom_xpos"), physics.field("geom_xmat")
            after_steps(climbings, physics.row_data, xpos, xmat)
        alive = ~rows.dead  # a dead body plays zero actions, which cost nothing
        died = self._update_survival(physics, rows)
        x, obs = self.observe_rows(physics, rows)
        shaping = self.shaping(x, obs[:, 0])
        reward = shaping - rows.prev_shaping
        cost = self.body.torque_cost_per_unit * torque_use(self.ops, actions)
        reward[alive] -= cost[alive]
        critical = self.critical_touch(physics)
        fail = critical | (x < 0.0)
        terminated = fail | (x > self.end_x)
        if self.end_on_death:
            terminated |= died
        return Outcome(obs, np.where(fail, FAIL_REWARD, reward), terminated, shaping, critical)
