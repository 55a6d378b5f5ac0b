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
from acl3d.envs.climbing import after_steps, before_steps
from acl3d.envs.parkour_lidar import ParkourLidar, creeper_boxes
from acl3d.envs.track_rules import FAIL_REWARD, EpisodeRows, Outcome, TrackRules, torque_use

SURVIVAL_STEPS = 600
SURVIVAL_KEYS = ("steps_under_water", "steps_out_of_water", "dead", "under_water")
PARKOUR_CRITICAL_WALKERS = ("profile_chimpanzee",)  # the chimpanzee's head is always critical
DEFAULT_LIDARS = {"walker": "down", "amphibian": "down", "climber": "up", "swimmer": "full"}


def count_survival(xp, kind: str, limit: int, under, below, above, alive):
    """One step of the survival counters of N bodies (`xp`: numpy or torch): consecutive steps
    `below` and `above` the water surface, counted while alive; returns (below, above, died):
    walkers and climbers die after more than `limit` steps under water, swimmers after more
    than `limit` out of it, amphibians never."""
    below = xp.where(alive, xp.where(under, below + 1, 0), below)
    above = xp.where(alive, xp.where(under, 0, above + 1), above)
    if kind in ("walker", "climber"):
        died = alive & (below > limit)
    elif kind == "swimmer":
        died = alive & (above > limit)
    else:
        died = xp.zeros_like(alive)
    return below, above, died


def critical_touch(sensordata, any_contact, ceiling_contact):
    """(N,) flags: a critical part touches something other than the ceiling (its touch sensor
    counts more contacts than its ceiling-only one)."""
    return (sensordata[:, any_contact] > sensordata[:, ceiling_contact]).any(axis=1)


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
        once); then the water forces of all envs at once, if a body reaches the water (or just
        left it: its forces are cleared)."""
        if rows.dead.any():
            actions = np.where(rows.dead[:, None], 0.0, actions)
        if self.climber:
            climbings = [arena.climbing for arena in rows.arenas]
            before_steps(climbings, physics.field("eq_active"), actions[:, -self._nb_grasp :])
        water = self.arena.water  # its tables: the same body geoms in every env's model
        bottoms = physics.field("geom_xpos")[:, water.geoms, 2] - water.reach
        reached = bottoms.min(axis=1) < rows.water_level
        wet = np.fromiter((arena.water.wet for arena in rows.arenas), bool, len(reached))
        if (reached | wet).any():  # all envs at once; a dry one gets zero forces
            forces, _ = water.forces(physics, rows.water_level)
            physics.field("xfrc_applied")[:, water.body_ids, 0::2] = forces
            for arena, flag in zip(rows.arenas, reached.tolist()):
                arena.water.wet = flag
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
        below, above, died = count_survival(
            np, self.kind, self.survival_steps, under, rows.steps_under_water,
            rows.steps_out_of_water, ~rows.dead,
        )  # fmt: skip
        rows.steps_under_water[:], rows.steps_out_of_water[:] = below, above
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

    def outcome_rows(self, physics, actions: np.ndarray, rows) -> Outcome:
        if self.climber:
            climbings = [arena.climbing for arena in rows.arenas]
            xpos, xmat = physics.field("geom_xpos"), physics.field("geom_xmat")
            boxes = creeper_boxes(
                xpos, xmat, self.arena.creeper_geoms, rows.creeper_size, rows.creeper_rbound,
                rows.creeper_count,
            )  # fmt: skip
            grid = self.arena.grid
            after_steps(climbings, physics.row_data, xpos, xmat, rows.ceiling, grid, boxes)
        alive = ~rows.dead  # a dead body plays zero actions, which cost nothing
        died = self._update_survival(physics, rows)
        x, obs = self.observe_rows(physics, rows)
        shaping = self.shaping(x, obs[:, 0])
        reward = shaping - rows.prev_shaping
        cost = self.body.torque_cost_per_unit * torque_use(self.ops, actions)
        reward[alive] -= cost[alive]
        critical = critical_touch(
            physics.field("sensordata"), self._critical_any, self._critical_ceiling
        )
        fail = critical | (x < 0.0)
        terminated = fail | (x > self.end_x)
        if self.end_on_death:
            terminated |= died
        return Outcome(obs, np.where(fail, FAIL_REWARD, reward), terminated, shaping, critical)
