"""3D Terrain's rules: forward progress, heading and lateral drift, crossing the finish line.

The tracks' rules, widened to a body that can turn and drift:

* shaping = 15 * x - 5 * |yaw| - 5 * |y| (- 5 * |pitch| for bodies with the head-angle term);
  the step reward is the shaping difference minus the torque cost, so the shaping terms only
  move the return by what the body ends up at (crossing from the spawn point: ~330);
* a critical contact, going behind the start (x < 0) or leaving the field (|y| > its half
  width) replaces the step reward by -100 and ends the episode;
* crossing the finish line ends the episode: `crossed` is the success flag.

The observation is the tracks' head and motor state, then the terrain sensor (the height scan by
default, or the sagittal lidar cast by MuJoCo), then the lateral position y / half width.
The arithmetic is written on arrays so that it applies to one env or N envs alike.
"""

from __future__ import annotations

import numpy as np

from acl3d.bodies.base import BoundBody
from acl3d.envs.height_scan import HeightScan
from acl3d.envs.lidar import Lidar
from acl3d.envs.track_rules import (
    ANGLE_PENALTY,
    FAIL_REWARD,
    EpisodeRows,
    TrackRules,
    torque_use,
)

PROGRESS_GAIN = 15.0  # reward per metre along x (the course is ~22 m from spawn to finish)
HEADING_PENALTY = 5.0  # per radian of yaw away from +x
DRIFT_PENALTY = 5.0  # per metre of |y| away from the field's centre line


def shaping(x, y, pitch, yaw, head_angle_reward: bool):
    """The potential whose differences reward a step (arrays or floats)."""
    s = PROGRESS_GAIN * x - HEADING_PENALTY * abs(yaw) - DRIFT_PENALTY * abs(y)
    if head_angle_reward:
        s = s - ANGLE_PENALTY * abs(pitch)
    return s


def outcome(x, y, critical, end_x: float, half_width: float):
    """(failed, crossed) flags: failure wins over crossing (arrays or floats)."""
    failed = critical | (x < 0.0) | (abs(y) > half_width)
    return failed, (x > end_x) & np.logical_not(failed)


class Terrain3DRules(TrackRules):
    """Observation, reward and termination of N envs of one body on the 3D field.

    Its rows add `crossed`, the flag of the last step (the success of an episode that ended
    there), which the env reports as `info["success"]`.
    """

    def __init__(self, bound: BoundBody, sensor, half_width: float, end_x: float):
        self.half_width = half_width
        super().__init__(bound, sensor, end_x)

    def extra_obs_size(self) -> int:
        return 1  # y / half width

    def new_rows(self, n: int) -> EpisodeRows:
        rows = super().new_rows(n)
        rows.crossed = np.zeros(n, dtype=bool)
        return rows

    def _pose(self, physics, obs) -> tuple:
        """(y, pitch, yaw) of the root, (N,) each; a planar body stays at y = 0 facing +x."""
        if self.body.planar:
            return 0.0, obs[:, 0], 0.0
        return physics.field("xpos")[:, self.bound.root_id, 1], obs[:, 0], obs[:, 5]

    def observe(self, physics, rows) -> tuple[np.ndarray, np.ndarray]:
        x, obs = super().observe(physics, rows)
        obs[:, -1] = physics.field("xpos")[:, self.bound.root_id, 1] / self.half_width
        return x, obs

    def potential(self, physics, x, obs) -> np.ndarray:
        y, pitch, yaw = self._pose(physics, obs)
        return shaping(x, y, pitch, yaw, self.body.head_angle_reward)

    def reset_rows(self, physics, rows) -> np.ndarray:
        rows.crossed[:] = False
        return super().reset_rows(physics, rows)

    def outcome(self, physics, actions: np.ndarray, rows):
        x, obs = self.observe(physics, rows)
        s = self.potential(physics, x, obs)
        reward = s - rows.prev_shaping
        rows.prev_shaping[:] = s
        reward -= self.body.torque_cost_per_unit * torque_use(actions)
        critical = self.touched(physics, self._critical_sensors).any(axis=1)
        rows.critical_contact[:] = critical
        y = self._pose(physics, obs)[0]
        failed, rows.crossed[:] = outcome(x, y, critical, self.end_x, self.half_width)
        return obs, np.where(failed, FAIL_REWARD, reward), failed | rows.crossed


def make_sensor(observation: str, arena) -> HeightScan | Lidar:
    """The terrain sensor an observation name selects ("height_scan" or "lidar")."""
    return HeightScan(arena) if observation == "height_scan" else Lidar("down")
