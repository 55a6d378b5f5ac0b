"""One control step of N Stump/Hexagon Tracks envs of one body, computed together.

`TrackBatch` is the array form of `TrackEnv.step` (servo action, physics, then
`TrackTask.step` and the instability check): the per-env part is what must touch each env's
own MuJoCo model and data (write the servo caps and targets, `mj_step`, copy the few state
rows the task reads), and runs on the caller's worker threads; observation, reward,
termination and the lidars are then computed for all envs at once. Every operation is the
single env's, element by element, in the same order (reductions only along rows, `math.atan2`
for the angles as the single env), so each row is bit-identical to a single env.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from acl3d.envs.track_task import ANGLE_PENALTY, FAIL_REWARD, PROGRESS_GAIN

_BADQACC = int(mujoco.mjtWarning.mjWARN_BADQACC)


class TrackBatch:
    """Array state and buffers of N track envs (`TrackEnv` instances of one body and track)."""

    def __init__(self, envs):
        e = envs[0]
        self.envs = envs
        self.n = n = len(envs)
        self.datas = [env.data for env in envs]
        self.physics_states = [env.physics for env in envs]  # mj_step x frame_skip, snapshots
        b, task, body = e.bound, e.task, e.body
        self.planar = body.planar
        self.root_dof = b.root_dof
        self.nb_motors = len(b.speeds)
        self.speeds, self.torque = b.speeds, body.torque
        self.cost_per_unit = body.torque_cost_per_unit
        self.head_angle_reward = body.head_angle_reward
        self.lidar = task.lidar
        self.end_x = task.end_x
        self.critical = b.critical_geom_ids
        self._qpos_adr, self._dof_adr = b.qpos_adr, b.dof_adr
        self._angle_correction, self._inv_speeds = b.angle_correction, task._inv_speeds
        self._contact_geoms = b.contact_geom_ids
        head, motors = task.head_size, b.motor_state_size
        self._motor_cols = head + np.concatenate((task._angle_pos, task._speed_pos))
        self._contact_cols = head + task._contact_pos
        self._lidar_col = head + motors + len(task._grasp)
        self.obs_size = task.obs_size
        # live views into each env's model and data (MuJoCo never moves these arrays)
        ids, root = b.actuator_ids, b.root_id
        whole = np.array_equal(ids, np.arange(e.model.nu))
        self._caps = [env.model.actuator_forcerange[slice(None) if whole else ids] for env in envs]
        self._ctrl = [env.data.ctrl for env in envs]
        self._ctrl_index = slice(None) if whole else ids
        # (rows of the gathered state, per env the live view copied into it after its step)
        views = {
            "qpos": [env.data.qpos for env in envs],
            "qvel": [env.data.qvel for env in envs],
            "root_xpos": [env.data.xpos[root] for env in envs],
            "root_xmat": [env.data.xmat[root] for env in envs],
            "warning_counts": [env.data.warning.number for env in envs],
        }
        if not self.planar:
            views["root_cvel"] = [env.data.cvel[root] for env in envs]
        self._copies = []
        for name, per_env in views.items():
            rows = np.zeros((n, *per_env[0].shape), dtype=per_env[0].dtype)
            setattr(self, name, rows)
            self._copies.append((rows, per_env))
        self._geom1 = [np.zeros(0, dtype=int)] * n
        self._geom2 = [np.zeros(0, dtype=int)] * n
        self._row_offsets = np.arange(n) * e.model.ngeom
        self._per_env = list(
            zip(range(n), self._caps, self._ctrl, self.physics_states, self.datas, strict=True)
        )
        self.touched = np.zeros((n, e.model.ngeom), dtype=bool)
        self._servo = np.zeros((n, self.nb_motors, 2))
        self._targets = np.zeros((n, self.nb_motors))
        # per-env episode state (also kept by each TrackEnv: see `pull` and `push`)
        self.heights = self.lidar.batch_heights(n)
        self.prev_shaping = np.zeros(n)
        self.episode_return = np.zeros(n)
        self.warnings_seen = np.zeros(n, dtype=np.int64)
        self.critical_contact = np.zeros(n, dtype=bool)

    # ------------------------------------------------------------------ per-env state sync
    def pull(self, i: int) -> None:
        """Take env i's episode state after it was reset (or restored) on its own."""
        env = self.envs[i]
        self.heights[i, : len(env.arena.heights)] = env.arena.heights
        self.prev_shaping[i] = env.task.prev_shaping
        self.episode_return[i] = env._episode_return
        self.warnings_seen[i] = env._warnings
        self.critical_contact[i] = env.task.critical_contact

    def push(self, i: int) -> None:
        """Write env i's episode state back into its TrackEnv (before reading or saving it)."""
        env = self.envs[i]
        env.task.prev_shaping = float(self.prev_shaping[i])
        env._episode_return = float(self.episode_return[i])
        env._warnings = int(self.warnings_seen[i])
        env.task.critical_contact = bool(self.critical_contact[i])

    # ------------------------------------------------------------------ the step
    def prepare(self, actions: np.ndarray) -> None:
        """Servo caps and targets of every env (`TrackEnv._apply_action`, vectorised)."""
        motors = actions[:, : self.nb_motors]
        magnitude = np.minimum(np.abs(motors), 1.0) * self.torque
        self._servo[:, :, 0] = -magnitude
        self._servo[:, :, 1] = magnitude
        self._targets[:] = self.speeds * np.sign(motors)

    def physics(self, lo: int, hi: int) -> None:
        """Envs lo..hi-1: set the servos, step (GIL released), note the contacting geoms."""
        index, copies, servo, targets = self._ctrl_index, self._copies, self._servo, self._targets
        g1, g2 = self._geom1, self._geom2
        for i, cap, ctrl, physics, d in self._per_env[lo:hi]:
            cap[:] = servo[i]
            ctrl[index] = targets[i]
            physics.step()
            for rows, views in copies:
                rows[i] = views[i]
            n = d.ncon
            contact = d.contact
            g1[i], g2[i] = contact.geom1[:n], contact.geom2[:n]

    def _gather_contacts(self) -> None:
        """Flag the geoms each env's contacts touch (after all physics ran)."""
        touched = self.touched
        touched[:] = False
        counts = [len(g) for g in self._geom1]
        if sum(counts):
            rows = np.repeat(self._row_offsets, counts)
            flat = touched.reshape(-1)
            flat[rows + np.concatenate(self._geom1)] = True
            flat[rows + np.concatenate(self._geom2)] = True

    def finish(self, actions: np.ndarray):
        """(obs float32 (N, obs), rewards, terminated, unstable) after `physics` ran for all."""
        self._gather_contacts()
        head = self._head()
        x = self.root_xpos[:, 0]
        shaping = PROGRESS_GAIN * x
        if self.head_angle_reward:
            shaping = shaping - ANGLE_PENALTY * np.abs(head[:, 0])
        reward = shaping - self.prev_shaping
        self.prev_shaping = shaping
        reward -= self.cost_per_unit * np.minimum(np.abs(actions), 1.0).sum(axis=1)
        obs = np.zeros((self.n, self.obs_size))
        obs[:, : head.shape[1]] = head
        obs[:, self._motor_cols] = np.concatenate(
            (
                self.qpos[:, self._qpos_adr] + self._angle_correction,
                self.qvel[:, self._dof_adr] * self._inv_speeds,
            ),
            axis=1,
        )
        obs[:, self._contact_cols] = self.touched[:, self._contact_geoms]
        lidar = self.lidar.read_batch(self.heights, self.root_xpos)
        obs[:, self._lidar_col : self._lidar_col + lidar.shape[1]] = lidar
        if len(self.critical):
            self.critical_contact = self.touched[:, self.critical].any(axis=1)
        fail = self.critical_contact | (x < 0.0)
        reward = np.where(fail, FAIL_REWARD, reward)
        warnings = self.warning_counts[:, _BADQACC]
        unstable = warnings > self.warnings_seen
        self.warnings_seen[:] = warnings
        terminated = fail | (x > self.end_x) | unstable
        self.episode_return += reward
        return obs.astype(np.float32), reward, terminated, unstable

    def _head(self) -> np.ndarray:
        """`TrackTask.head_state` for every env: (N, 4) planar, (N, 9) free 3D."""
        r = self.root_xmat
        pitch = np.array([math.atan2(a, b) for a, b in zip(r[:, 6].tolist(), r[:, 0].tolist())])
        v = self.root_dof
        qv = self.qvel
        if self.planar:
            return np.column_stack(
                (pitch, 2.0 * qv[:, v + 2] / 50.0, 0.12 * qv[:, v], 0.08 * qv[:, v + 1])
            )
        roll = [math.atan2(a, b) for a, b in zip(r[:, 7].tolist(), r[:, 8].tolist())]
        yaw = [math.atan2(a, b) for a, b in zip(r[:, 3].tolist(), r[:, 0].tolist())]
        omega = self.root_cvel
        return np.column_stack(
            (
                pitch,
                -2.0 * omega[:, 1] / 50.0,
                0.12 * qv[:, v],
                0.08 * qv[:, v + 2],
                roll,
                yaw,
                0.12 * qv[:, v + 1],
                2.0 * omega[:, 0] / 50.0,
                2.0 * omega[:, 2] / 50.0,
            )
        )
