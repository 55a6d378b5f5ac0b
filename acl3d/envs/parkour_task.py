"""The Parkour task: water and death flags, grasp state, surface-typed lidars, survival rules.

Extends the track task (§2.4.4-2.4.7 of the reference). Observation, in order:
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

import mujoco
import numpy as np

from acl3d.bodies.base import BoundBody
from acl3d.envs import env_state
from acl3d.envs.climbing import Climbing
from acl3d.envs.lidar import LIDAR_RANGE, LIDAR_TYPES, NB_RAYS
from acl3d.envs.track_task import FAIL_REWARD, TrackTask, torque_use
from acl3d.envs.water import Water

SURVIVAL_STEPS = 600
SURVIVAL_KEYS = ("steps_under_water", "steps_out_of_water", "dead", "under_water")
WATER_FLAG, CREEPER_FLAG = -1.0, 1.0
PARKOUR_CRITICAL_WALKERS = ("profile_chimpanzee",)  # the chimpanzee's head is always critical
DEFAULT_LIDARS = {"walker": "down", "amphibian": "down", "climber": "up", "swimmer": "full"}


class ParkourLidar:
    """The original's 10 rays cast analytically on Parkour's surfaces, with surface-type flags.

    Same rays as the track lidar (`acl3d.envs.lidar`: angles a*i/10 + b per type, 5.33 m).
    Ground and ceiling are piecewise-linear profiles along x (exactly what the heightfields
    hold), creepers are boxes (static or swinging segments), the water is a horizontal plane seen
    from above only (the original does not see its surface from inside). Casting on these
    shapes in numpy gives the distances `mj_multiRay` gives (tested) several times faster on
    the two 240-column heightfields.
    """

    def __init__(self, kind: str, arena, nb_rays: int = NB_RAYS, ray_range: float = LIDAR_RANGE):
        if kind not in LIDAR_TYPES:
            raise ValueError(f"lidar type {kind!r}; valid: {list(LIDAR_TYPES)}")
        a, b = LIDAR_TYPES[kind]
        angles = a * np.arange(nb_rays) / nb_rays + b
        self.kind, self.nb_rays, self.range = kind, nb_rays, ray_range
        self.directions = np.stack([np.sin(angles), np.zeros(nb_rays), -np.cos(angles)], axis=1)
        self._dx, self._dz = self.directions[:, 0].copy(), self.directions[:, 2].copy()
        # how far back and ahead along x the rays reach
        self._reach_back = self.range * min(0.0, self._dx.min())
        self._reach_ahead = self.range * max(0.0, self._dx.max())
        self.arena = arena
        self._grid_x = arena.grid.x
        with np.errstate(divide="ignore"):  # distance per metre of height to the water plane
            self._inv_down = np.where(self._dz < 0.0, -1.0 / self._dz, np.inf)
        self.flags = np.zeros(self.nb_rays)

    def read(self, model, data, origin) -> np.ndarray:
        """Fractions in [0, 1] (1 = nothing within range); `self.flags` holds the surface types."""
        x0, z0 = float(origin[0]), float(origin[2])
        best = np.full(self.nb_rays, self.range)
        arena = self.arena
        grid = arena.grid
        i0 = max(0, int((x0 + self._reach_back - grid.x_min) / grid.cell))
        i1 = min(grid.ncol - 1, int((x0 + self._reach_ahead - grid.x_min) / grid.cell) + 1)
        xs = self._grid_x[i0 : i1 + 1]
        ground, ceiling = arena.heights[i0 : i1 + 1], arena.ceiling_heights[i0 : i1 + 1]
        if ground.max() >= z0 - self.range:  # skip profiles out of reach
            np.minimum(best, self._profile_hits(xs, ground, x0, z0), out=best)
        if ceiling.min() <= z0 + self.range:
            np.minimum(best, self._profile_hits(xs, ceiling, x0, z0), out=best)
        flags = self.flags
        flags[:] = 0.0
        creepers = self._creeper_hits(model, data, origin)
        if creepers is not None:
            on_creeper = creepers < best
            best[on_creeper] = creepers[on_creeper]
            flags[on_creeper] = CREEPER_FLAG
        height = z0 - arena.water.level
        if height > 0.0:  # rays from under water do not see its surface
            water = height * self._inv_down  # inf for rays that do not go down
            on_water = water < best
            best[on_water] = water[on_water]
            flags[on_water] = WATER_FLAG
        miss = best >= self.range
        flags[miss] = 0.0
        return np.where(miss, 1.0, best / self.range)

    def _profile_hits(self, xs, zs, x0, z0) -> np.ndarray:
        """Distance along each ray to the first crossing of the polyline (xs, zs); inf if none."""
        ex, ez = self.arena.grid.cell, np.diff(zs)
        rx, rz = xs[:-1] - x0, zs[:-1] - z0
        dx, dz = self._dx[:, None], self._dz[:, None]
        denom = dx * ez - dz * ex  # d x e
        safe = np.where(denom == 0.0, 1.0, denom)
        t = (rx * ez - rz * ex) / safe  # (r x e) / (d x e)
        u = (rx * dz - rz * dx) / safe  # (r x d) / (d x e)
        valid = (denom != 0.0) & (u >= 0.0) & (u <= 1.0) & (t >= 0.0)
        return np.where(valid, t, np.inf).min(axis=1)

    def _creeper_hits(self, model, data, origin) -> np.ndarray | None:
        """Distance along each ray to the nearest creeper box entered from outside (inf: none);
        None when no creeper is within reach."""
        geoms = self.arena.creeper_geoms[: self.arena.nb_creeper_geoms]
        if not len(geoms):
            return None
        offsets = data.geom_xpos[geoms] - origin
        reach = self.range + model.geom_rbound[geoms]
        near = np.einsum("ij,ij->i", offsets, offsets) <= reach * reach
        if not near.any():
            return None
        geoms, offsets = geoms[near], offsets[near]
        rot = data.geom_xmat[geoms].reshape(-1, 3, 3)
        size = model.geom_size[geoms]
        o_local = -np.einsum("nkj,nk->nj", rot, offsets)  # R^T (o - c)
        d_local = np.einsum("nkj,rk->rnj", rot, self.directions)
        d_local[np.abs(d_local) < 1e-12] = 1e-12
        t1 = (-size - o_local) / d_local
        t2 = (size - o_local) / d_local
        t_in = np.minimum(t1, t2).max(axis=-1)
        t_out = np.maximum(t1, t2).min(axis=-1)
        hit = (t_in <= t_out) & (t_in > 0.0)
        return np.where(hit, t_in, np.inf).min(axis=1)


class ParkourTask(TrackTask):
    """Track task + water, survival counters, grasping and the Parkour observation layout."""

    # what the water forces, the grasps and the creeper rays read or write, too
    physics_fields = (
        *TrackTask.physics_fields,
        *("geom_xpos", "geom_xmat", "subtree_com", "xipos", "xaxis", "xanchor", "xquat"),
        *("qfrc_actuator", "xfrc_applied", "eq_active"),
    )

    def __init__(
        self,
        bound: BoundBody,
        lidar: ParkourLidar,
        water: Water,
        climbing: Climbing | None,
        end_x: float,
        end_on_death: bool = False,
        survival_steps: int = SURVIVAL_STEPS,
    ):
        self.water = water
        self.climbing = climbing
        super().__init__(bound, lidar, end_x)
        body = bound.body
        self.kind = body.kind
        critical = bound.critical_geom_ids
        if self.kind == "walker" and body.name not in PARKOUR_CRITICAL_WALKERS:
            critical = np.zeros(0, dtype=int)
        self._critical_any = self._sensor_adr(bound.model, critical)
        self._critical_ceiling = self._sensor_adr(bound.model, critical, against="ceiling")
        self.end_on_death = end_on_death
        self.survival_steps = survival_steps
        self.steps_under_water = 0
        self.steps_out_of_water = 0
        self.dead = False
        self.under_water = False
        self._zero_action = np.zeros(body.action_size)

    def extra_obs_size(self) -> int:
        return 2 + self.lidar.nb_rays  # under_water and dead flags, surface flags

    def grasp_state(self) -> np.ndarray:
        """Climbers' [touching, holding] per hand (`Climbing.state`); empty for other bodies."""
        return self.climbing.state() if self.climbing else np.zeros(0)

    # ------------------------------------------------------------------ survival
    def begin_episode(self) -> None:
        self.steps_under_water = self.steps_out_of_water = 0
        self.dead = False

    def played(self, action: np.ndarray) -> np.ndarray:
        """Dead bodies play zeros."""
        return self._zero_action if self.dead else action

    def episode_state(self) -> dict:
        return {f"survival/{key}": getattr(self, key) for key in SURVIVAL_KEYS}

    def check_episode_state(self, state) -> dict:
        env_state.check_keys(state, [f"survival/{key}" for key in SURVIVAL_KEYS])
        return {
            key: env_state.scalar(
                state, f"survival/{key}", "integer" if key.startswith("steps") else "flag", 0
            )
            for key in SURVIVAL_KEYS
        }

    def set_episode_state(self, checked: dict) -> None:
        for key in SURVIVAL_KEYS:
            setattr(self, key, checked[key])

    def _update_survival(self, data: mujoco.MjData) -> bool:
        """Count consecutive steps in/out of water; return True if the body died this step."""
        self.under_water = bool(data.xpos[self.bound.root_id, 2] <= self.water.level)
        if self.dead:
            return False
        if self.under_water:
            self.steps_under_water += 1
            self.steps_out_of_water = 0
        else:
            self.steps_out_of_water += 1
            self.steps_under_water = 0
        if self.kind in ("walker", "climber"):
            self.dead = self.steps_under_water > self.survival_steps
        elif self.kind == "swimmer":
            self.dead = self.steps_out_of_water > self.survival_steps
        return self.dead

    # ------------------------------------------------------------------ observation
    # Parkour's rules run per env (N = 1): water, creepers and grasps read the env's MjData.
    def observe(self, physics, rows) -> tuple[np.ndarray, np.ndarray]:
        data = physics.data
        obs = np.zeros((1, self.obs_size))
        col = self.head_size
        x = self.head(physics, obs[:, :col])
        obs[0, col : col + 2] = (float(self.under_water), float(self.dead))
        col += 2
        self.motor_state(physics, obs[:, col : col + self._motor_size])
        col += self._motor_size
        grasp = self.grasp_state()
        obs[0, col : col + len(grasp)] = grasp
        col += len(grasp)
        obs[0, col : col + self.lidar.nb_rays] = self.lidar.read(
            physics.model, data, data.xpos[self.bound.root_id]
        )
        obs[0, col + self.lidar.nb_rays :] = self.lidar.flags
        return x, obs

    def reset_rows(self, physics, rows) -> np.ndarray:
        self.begin_episode()
        root_z = physics.data.xpos[self.bound.root_id, 2]
        self.under_water = bool(root_z <= self.water.level)
        return super().reset_rows(physics, rows)

    def critical_touch(self, physics) -> np.ndarray:
        """(N,) flags: a critical part touches something other than the ceiling (it has more
        contacts than those with the ceiling)."""
        touching = physics.field("sensordata")
        more = touching[:, self._critical_any] > touching[:, self._critical_ceiling]
        return np.logical_or.reduce(more, axis=1)

    def outcome(self, physics, actions: np.ndarray, rows):
        data = physics.data
        if self.climbing:
            self.climbing.after_step(data)
        alive = not self.dead  # a dead body plays zero actions, which cost nothing
        died = self._update_survival(data)
        x, obs = self.observe(physics, rows)
        shaping = self.shaping(x, obs[:, 0])
        reward = shaping - rows.prev_shaping
        rows.prev_shaping[:] = shaping
        if alive:
            reward -= self.body.torque_cost_per_unit * torque_use(actions)
        rows.critical_contact[:] = self.critical_touch(physics)
        fail = rows.critical_contact | (x < 0.0)
        terminated = fail | (x > self.end_x) | (died and self.end_on_death)
        return obs, np.where(fail, FAIL_REWARD, reward), terminated
