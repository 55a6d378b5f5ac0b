"""The track task: observation assembly, reward, termination and success (body-agnostic).

Follows TeachMyAgent §2.1: shaping = 130/30 * x_head - 5 * |angle| (angle term dropped for bodies
without it), step reward = shaping difference - torque cost; a critical contact or going behind
the track start replaces the step reward by -100 and terminates; crossing the end line
terminates (success is judged by the return: > 230, reported at every step).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from acl3d.bodies.base import BoundBody
from acl3d.envs.lidar import Lidar
from acl3d.terrain.tracks import END_X

SUCCESS_RETURN = 230.0
FAIL_REWARD = -100.0
PROGRESS_GAIN = 130.0 / 30.0  # reward per metre of forward progress
ANGLE_PENALTY = 5.0


class TrackTask:
    """Per-step observation, reward and termination for one bound body."""

    def __init__(self, bound: BoundBody, lidar: Lidar, end_x: float = END_X):
        self.bound = bound
        self.body = bound.body
        self.lidar = lidar
        self.end_x = end_x
        self.head_size = 4 if self.body.planar else 9
        # climbers: [contact, grasping] per hand sensor, between the motor state and the lidars
        self._grasp = np.zeros(2 * len(self.body.grasp_sensors))
        self.obs_size = (
            self.head_size
            + bound.motor_state_size
            + len(self._grasp)
            + lidar.nb_rays
            + self.extra_obs_size()
        )
        self._touched = np.zeros(bound.model.ngeom, dtype=bool)
        # where each motor's entries sit in the motor state (a contact flag follows some angles/speeds)
        width = 2 + bound.has_contact_flag.astype(int)
        starts = np.concatenate(([0], np.cumsum(width)[:-1]))
        self._angle_pos, self._speed_pos = starts, starts + 1
        self._contact_pos = (starts + 2)[bound.has_contact_flag]
        self._inv_speeds = 1.0 / bound.speeds
        self._motor_buffer = np.zeros(int(width.sum()))
        self.prev_shaping = 0.0
        self.critical_contact = False

    def grasp_state(self, data: mujoco.MjData) -> np.ndarray:
        """Climbers' sensor state, 2 entries per `Body.grasp_sensors` item: [has_contact, has_grasp].

        Always 0 on tracks without graspable surfaces; tasks with a ceiling or creepers (Parkour)
        override this to report their grasp logic. Empty for every other body.
        """
        return self._grasp

    def extra_obs_size(self) -> int:
        """Hook for tasks that add observation entries after the lidars (Parkour's surface flags)."""
        return 0

    # ------------------------------------------------------------------ physics readings
    def update_contacts(self, data: mujoco.MjData) -> np.ndarray:
        """Flags of geoms touching anything this step (bodies never collide with themselves)."""
        touched = self._touched
        touched[:] = False
        if data.ncon:
            touched[data.contact.geom[: data.ncon].ravel()] = True
        return touched

    def head_state(self, data: mujoco.MjData) -> tuple[float, np.ndarray]:
        """(x of the head, head observation): angle, 2*omega/50, 0.12*vx, 0.08*vz (+ 3D extras)."""
        b = self.bound
        r = data.xmat[b.root_id]  # row-major 3x3: columns are the body axes in the world
        pitch = math.atan2(r[6], r[0])  # nose-up positive (rotation about -y)
        omega = data.cvel[b.root_id, :3]  # world angular velocity
        v = b.root_dof
        if self.body.planar:
            vx, vz = data.qvel[v], data.qvel[v + 1]
            head = np.array([pitch, 2.0 * data.qvel[v + 2] / 50.0, 0.12 * vx, 0.08 * vz])
        else:
            vx, vy, vz = data.qvel[v : v + 3]
            roll = math.atan2(r[7], r[8])
            yaw = math.atan2(r[3], r[0])
            head = np.array(
                [
                    pitch,
                    -2.0 * omega[1] / 50.0,
                    0.12 * vx,
                    0.08 * vz,
                    roll,
                    yaw,
                    0.12 * vy,
                    2.0 * omega[0] / 50.0,
                    2.0 * omega[2] / 50.0,
                ]
            )
        return float(data.xpos[b.root_id, 0]), head

    def motor_state(self, data: mujoco.MjData, touched: np.ndarray) -> np.ndarray:
        """Per motor [angle + correction, speed / servo speed, (contact flag)], as the original."""
        b = self.bound
        out = self._motor_buffer
        out[self._angle_pos] = data.qpos[b.qpos_adr] + b.angle_correction
        out[self._speed_pos] = data.qvel[b.dof_adr] * self._inv_speeds
        out[self._contact_pos] = touched[b.contact_geom_ids]
        return out

    # ------------------------------------------------------------------ episode logic
    def shaping(self, x: float, angle: float) -> float:
        s = PROGRESS_GAIN * x
        if self.body.head_angle_reward:
            s -= ANGLE_PENALTY * abs(angle)
        return s

    def begin_episode(self) -> None:
        """Clear per-episode rules before the body is placed (a track task has none)."""

    def played(self, action: np.ndarray) -> np.ndarray:
        """The action the body plays (on a track: the one given)."""
        return action

    def episode_state(self) -> dict:
        """Per-episode rule state beyond the shaping and contact flag (none on a track)."""
        return {}

    def check_episode_state(self, state) -> dict:
        return {}

    def set_episode_state(self, checked: dict) -> None:
        """Restore what `check_episode_state` returned."""

    def reset(self, model, data) -> np.ndarray:
        touched = self.update_contacts(data)
        x, head = self.head_state(data)
        self.prev_shaping = self.shaping(x, head[0])
        return self.observe(model, data, head, touched)

    def observe(self, model, data, head, touched) -> np.ndarray:
        lidar = self.lidar.read(model, data, data.xpos[self.bound.root_id])
        return np.concatenate(
            (head, self.motor_state(data, touched), self.grasp_state(data), lidar)
        ).astype(np.float32)

    def step(self, model, data, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool]:
        """After physics: (observation, reward, terminated, crossed_the_end)."""
        touched = self.update_contacts(data)
        x, head = self.head_state(data)
        shaping = self.shaping(x, head[0])
        reward = shaping - self.prev_shaping
        self.prev_shaping = shaping
        reward -= self.body.torque_cost_per_unit * float(np.minimum(np.abs(action), 1.0).sum())
        obs = self.observe(model, data, head, touched)
        critical = self.bound.critical_geom_ids
        self.critical_contact = bool(len(critical) and touched[critical].any())
        if self.critical_contact or x < 0.0:
            return obs, FAIL_REWARD, True, False
        if x > self.end_x:
            return obs, reward, True, True
        return obs, reward, False, False
