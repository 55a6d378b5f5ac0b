"""3D Terrain's task: forward progress, heading and lateral drift, crossing the finish line.

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
from acl3d.envs import env_state
from acl3d.envs.height_scan import HeightScan
from acl3d.envs.lidar import Lidar
from acl3d.envs.track_task import ANGLE_PENALTY, FAIL_REWARD, TrackTask

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


class Terrain3DTask(TrackTask):
    """Per-step observation, reward and termination of one body on the 3D field."""

    def __init__(self, bound: BoundBody, sensor, half_width: float, end_x: float):
        self.half_width = half_width
        self.crossed = False
        super().__init__(bound, sensor, end_x)

    def extra_obs_size(self) -> int:
        return 1  # y / half width

    def _pose(self, data, head) -> tuple[float, float, float]:
        """(y, pitch, yaw) of the root; a planar body stays at y = 0 facing +x."""
        if self.body.planar:
            return 0.0, float(head[0]), 0.0
        return float(data.xpos[self.bound.root_id, 1]), float(head[0]), float(head[5])

    def observe(self, model, data, head, touched) -> np.ndarray:
        root = data.xpos[self.bound.root_id]
        terrain = self.lidar.read(model, data, root)
        lateral = (root[1] / self.half_width,)
        return np.concatenate(
            (head, self.motor_state(data, touched), self.grasp_state(data), terrain, lateral)
        ).astype(np.float32)

    def begin_episode(self) -> None:
        self.crossed = False

    def reset(self, model, data) -> np.ndarray:
        touched = self.update_contacts(data)
        x, head = self.head_state(data)
        y, pitch, yaw = self._pose(data, head)
        self.prev_shaping = shaping(x, y, pitch, yaw, self.body.head_angle_reward)
        return self.observe(model, data, head, touched)

    def step(self, model, data, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool]:
        """After physics: (observation, reward, terminated, crossed the finish line)."""
        touched = self.update_contacts(data)
        x, head = self.head_state(data)
        y, pitch, yaw = self._pose(data, head)
        s = shaping(x, y, pitch, yaw, self.body.head_angle_reward)
        reward = s - self.prev_shaping
        self.prev_shaping = s
        reward -= self.body.torque_cost_per_unit * float(np.minimum(np.abs(action), 1.0).sum())
        obs = self.observe(model, data, head, touched)
        critical = self.bound.critical_geom_ids
        self.critical_contact = bool(len(critical) and touched[critical].any())
        failed, crossed = outcome(x, y, self.critical_contact, self.end_x, self.half_width)
        self.crossed = bool(crossed)
        if failed:
            return obs, FAIL_REWARD, True, False
        return obs, reward, self.crossed, self.crossed

    # ------------------------------------------------------------------ exact snapshots
    def episode_state(self) -> dict:
        return {"task/crossed": self.crossed}

    def check_episode_state(self, state) -> dict:
        env_state.check_keys(state, ("task/crossed",))
        return {"crossed": env_state.scalar(state, "task/crossed", "flag")}

    def set_episode_state(self, checked: dict) -> None:
        self.crossed = checked["crossed"]


def make_sensor(observation: str, arena) -> HeightScan | Lidar:
    """The terrain sensor an observation name selects ("height_scan" or "lidar")."""
    return HeightScan(arena) if observation == "height_scan" else Lidar("down")
