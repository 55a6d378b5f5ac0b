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
from acl3d.envs.climbing import Climbing
from acl3d.envs.lidar import Lidar
from acl3d.envs.track_task import FAIL_REWARD, TrackTask
from acl3d.envs.water import Water

SURVIVAL_STEPS = 600
WATER_FLAG, CREEPER_FLAG = -1.0, 1.0
PARKOUR_CRITICAL_WALKERS = ("profile_chimpanzee",)  # the chimpanzee's head is always critical
DEFAULT_LIDARS = {"walker": "down", "amphibian": "down", "climber": "up", "swimmer": "full"}


class ParkourLidar(Lidar):
    """The track lidar plus the water surface (seen from above only) and surface-type flags."""

    def __init__(self, kind: str, creeper_geoms: np.ndarray):
        super().__init__(kind)
        self._dz = self._vec.reshape(-1, 3)[:, 2].copy()
        # geom id -> is a creeper; the extra last entry answers for misses (id -1)
        self._is_creeper = np.zeros(int(creeper_geoms.max()) + 2, dtype=bool)
        self._is_creeper[creeper_geoms] = True
        self.water_level = -np.inf
        self.flags = np.zeros(self.nb_rays)

    def read(self, model, data, origin) -> np.ndarray:
        fraction = super().read(model, data, origin)
        ids = self.geom_ids
        flags = self.flags
        flags[:] = 0.0
        flags[self._is_creeper[np.minimum(ids, len(self._is_creeper) - 1)]] = CREEPER_FLAG
        height = origin[2] - self.water_level
        if height > 0.0:  # rays from under water do not see its surface
            down = self._dz < 0.0
            water = np.full(self.nb_rays, np.inf)
            water[down] = height / -self._dz[down] / self.range
            hit = water < fraction
            fraction[hit] = water[hit]
            flags[hit] = WATER_FLAG
        return fraction


class ParkourTask(TrackTask):
    """Track task + water, survival counters, grasping and the Parkour observation layout."""

    def __init__(
        self,
        bound: BoundBody,
        lidar: ParkourLidar,
        water: Water,
        climbing: Climbing | None,
        ceiling_geom: int,
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
        self.critical_ids = critical
        self.ceiling_geom = ceiling_geom
        self.end_on_death = end_on_death
        self.survival_steps = survival_steps
        self.steps_under_water = 0
        self.steps_out_of_water = 0
        self.dead = False
        self.under_water = False

    def extra_obs_size(self) -> int:
        return 2 + self.lidar.nb_rays  # under_water and dead flags, surface flags

    def grasp_state(self, data: mujoco.MjData) -> np.ndarray:
        return self.climbing.state() if self.climbing else self._grasp

    # ------------------------------------------------------------------ survival
    def reset_survival(self) -> None:
        self.steps_under_water = self.steps_out_of_water = 0
        self.dead = False

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
    def observe(self, model, data, head, touched) -> np.ndarray:
        lidar = self.lidar.read(model, data, data.xpos[self.bound.root_id])
        flags = (float(self.under_water), float(self.dead))
        return np.concatenate(
            (
                head,
                flags,
                self.motor_state(data, touched),
                self.grasp_state(data),
                lidar,
                self.lidar.flags,
            )
        ).astype(np.float32)

    def reset(self, model, data) -> np.ndarray:
        self.reset_survival()
        self.under_water = bool(data.xpos[self.bound.root_id, 2] <= self.water.level)
        return super().reset(model, data)

    def critical_touch(self, data: mujoco.MjData) -> bool:
        """A critical part touches something other than the ceiling."""
        if not len(self.critical_ids) or not data.ncon:
            return False
        pairs = data.contact.geom[: data.ncon]
        critical = np.isin(pairs, self.critical_ids)
        other = pairs[:, ::-1]
        return bool((critical & (other != self.ceiling_geom)).any())

    def step(self, model, data, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool]:
        """After physics: (observation, reward, terminated, crossed_the_end)."""
        touched = self.update_contacts(data)
        if self.climbing:
            self.climbing.after_step(data)
        x, head = self.head_state(data)
        shaping = self.shaping(x, head[0])
        reward = shaping - self.prev_shaping
        self.prev_shaping = shaping
        if not self.dead:  # a dead body plays zero actions, which cost nothing
            reward -= self.body.torque_cost_per_unit * float(np.minimum(np.abs(action), 1.0).sum())
        died = self._update_survival(data)
        obs = self.observe(model, data, head, touched)
        self.critical_contact = self.critical_touch(data)
        if self.critical_contact or x < 0.0:
            return obs, FAIL_REWARD, True, False
        if x > self.end_x:
            return obs, reward, True, True
        return obs, reward, bool(died and self.end_on_death), False
