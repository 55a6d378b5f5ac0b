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
Written once over `ArrayOps`, as the tracks' rules: numpy for one env or N, torch for the many
worlds (`on(ops)`).
"""

from __future__ import annotations

from acl3d.bodies.base import BoundBody
from acl3d.envs.array_ops import ArrayOps
from acl3d.envs.height_scan import HeightScan
from acl3d.envs.lidar import Lidar
from acl3d.envs.track_rules import ANGLE_PENALTY, TrackRules, sensor_on

PROGRESS_GAIN = 15.0  # reward per metre along x (the course is ~22 m from spawn to finish)
HEADING_PENALTY = 5.0  # per radian of yaw away from +x
DRIFT_PENALTY = 5.0  # per metre of |y| away from the field's centre line


class Terrain3DRules(TrackRules):
    """Observation, reward, termination and success of N envs of one body on the 3D field:
    success is crossing the finish line (`Outcome.crossed`)."""

    def __init__(self, bound: BoundBody, sensor, half_width: float, end_x: float):
        self.half_width = half_width
        super().__init__(bound, sensor, end_x)

    def on(self, ops: ArrayOps) -> Terrain3DRules:
        sensor = sensor_on(self.lidar, ops)
        return Terrain3DRules(self.bound, sensor, self.half_width, self.end_x)

    def extra_obs_size(self) -> int:
        return 1  # y / half width

    def _pose(self, physics, obs) -> tuple:
        """(y, pitch, yaw) of the root, (N,) each; a planar body stays at y = 0 facing +x."""
        if self.body.planar:
            zero = self.ops.xp.zeros_like(obs[:, 0])
            return zero, obs[:, 0], zero
        return physics.field("xpos")[:, self.bound.root_id, 1], obs[:, 0], obs[:, 5]

    def observe(self, physics, heights):
        x, obs = super().observe(physics, heights)
        obs[:, -1] = physics.field("xpos")[:, self.bound.root_id, 1] / self.half_width
        return x, obs

    def potential(self, physics, x, obs):
        """15 x - 5 |yaw| - 5 |y| (- 5 |pitch| for bodies with the head-angle term)."""
        xp = self.ops.xp
        y, pitch, yaw = self._pose(physics, obs)
        s = PROGRESS_GAIN * x - HEADING_PENALTY * xp.abs(yaw) - DRIFT_PENALTY * xp.abs(y)
        if self.body.head_angle_reward:
            s = s - ANGLE_PENALTY * xp.abs(pitch)
        return s

    def ending(self, physics, x, obs, critical) -> tuple:
        """Failure (critical contact, x < 0, |y| past the half width) wins over crossing."""
        y = self._pose(physics, obs)[0]
        failed = critical | (x < 0.0) | (self.ops.xp.abs(y) > self.half_width)
        crossed = (x > self.end_x) & ~failed
        return failed, failed | crossed, crossed


def make_sensor(observation: str, arena) -> HeightScan | Lidar:
    """The terrain sensor an observation name selects ("height_scan" or "lidar")."""
    return HeightScan(arena) if observation == "height_scan" else Lidar("down")
