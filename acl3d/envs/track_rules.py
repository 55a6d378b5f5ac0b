"""The tracks' rules: observation, reward, termination and success, for N envs at once.

An env's *rules* (dm_control calls this object its task; acl3d keeps "task" for the parameter
vector a teacher picks) turn the physics into what the agent sees and is paid.

Follows TeachMyAgent §2.1: shaping = 130/30 * x_head - 5 * |angle| (angle term dropped for bodies
without it), step reward = shaping difference - torque cost; a critical contact or going behind
the track start replaces the step reward by -100 and terminates; crossing the end line
terminates (success is judged by the return against the curriculum profile's success_return).

One implementation of the step for one env and for many. Every method works on (N, ...) arrays:
it reads the physics through a backend (`acl3d.envs.physics`: a single env's `PhysicsState` is
N = 1, the batched env's `BatchPhysics` is N) and keeps each env's running episode in an
`EpisodeRows` row. A single env is a batch of one; a sub-env of a batched env holds a view of
its row of the batch's rows, so nothing is mirrored. Element by element the arithmetic is the
same whatever N (reductions only along rows, `math.atan2` per element), so every row is
bit-identical to the same env stepped alone.

The interface an env's step uses: `obs_size`, `physics_fields`, `new_rows(n)`,
`servo(actions, caps, controls)`, `reset_rows(physics, rows)` (first observation),
`step(physics, actions, rows)`, `take_terrain(rows, i)`, and the per-env `begin_episode`,
`played`, `episode_state` / `check_episode_state` / `set_episode_state`. New rules override
the hooks they need: `observe` (the observation layout), `sense` (the terrain sensor),
`potential` (the shaping), `outcome` (reward and termination), as Parkour's and 3D Terrain's
rules do.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from acl3d.bodies.base import BoundBody
from acl3d.envs.lidar import TerrainSensor
from acl3d.terrain.tracks import END_X

FAIL_REWARD = -100.0
PROGRESS_GAIN = 130.0 / 30.0  # reward per metre of forward progress
ANGLE_PENALTY = 5.0
TOUCH_SENSOR_PREFIX = "touch_"  # contact sensors on the body's flagged and critical geoms
_BADQACC = int(mujoco.mjtWarning.mjWARN_BADQACC)
_PLANAR_VELOCITY_GAINS = np.array([0.12, 0.08])  # vx, vz in the head observation
_LOW_HIGH = np.array([-1.0, 1.0])  # a force range from a cap (x -1 is exact negation)


def touch_sensor_name(geom: str, against: str | None = None) -> str:
    """The contact sensor that counts the contacts of the (prefixed) geom `geom` (with the geom
    `against` only, if given)."""
    return TOUCH_SENSOR_PREFIX + geom + ("" if against is None else "|" + against)


def gather_index(ids: np.ndarray) -> slice | np.ndarray:
    """`ids` as a slice where they are a contiguous ascending run (indexing then gives a view,
    not a gathered copy: the step's arithmetic is the same, its numpy calls cheaper), else as is."""
    ids = np.asarray(ids)
    if len(ids) and np.array_equal(ids, np.arange(ids[0], ids[0] + len(ids))):
        return slice(int(ids[0]), int(ids[0]) + len(ids))
    return ids


def torque_use(actions: np.ndarray) -> np.ndarray:
    """(N,) sum of |a| clipped at 1 per env: what the torque cost is proportional to."""
    return np.add.reduce(np.minimum(np.abs(actions), 1.0), axis=1)


class EpisodeRows:
    """The running episodes of N envs, one row each (see the module docstring).

    prev_shaping: the last step's shaping; critical_contact: a critical part touched something
    at the last step; episode_return: the running return; warnings: MuJoCo's count of diverged
    steps seen so far; heights: each env's terrain (for the height-line lidar; None if the
    lidar reads the arena itself).
    """

    def __init__(self, n: int, heights: np.ndarray | None = None):
        self.prev_shaping = np.zeros(n)
        self.critical_contact = np.zeros(n, dtype=bool)
        self.episode_return = np.zeros(n)
        self.warnings = np.zeros(n, dtype=np.int64)
        self.heights = heights

    def row(self, i: int) -> EpisodeRows:
        """Env i's row as an `EpisodeRows` of one whose arrays are views of these."""
        out = type(self).__new__(type(self))
        for name, value in vars(self).items():
            setattr(out, name, None if value is None else value[i : i + 1])
        return out


class TrackRules:
    """Observation, reward and termination of envs of one bound body (see the module docstring)."""

    # the MjData fields the step reads through `physics.field`
    physics_fields: tuple[str, ...] = ("qpos", "qvel", "xpos", "xmat", "cvel", "sensordata")

    def __init__(self, bound: BoundBody, lidar: TerrainSensor, end_x: float = END_X):
        self.bound = bound
        self.body = bound.body
        self.lidar = lidar
        self.end_x = end_x
        self.head_size = 4 if self.body.planar else 9
        # climbers: [contact, grasping] per hand sensor, between the motor state and the lidars
        self.grasp_size = 2 * len(self.body.grasp_sensors)
        self.obs_size = (
            self.head_size
            + bound.motor_state_size
            + self.grasp_size
            + lidar.nb_rays
            + self.extra_obs_size()
        )
        model = bound.model
        # where each motor's entries sit in the motor state (a contact flag follows some)
        width = 2 + bound.has_contact_flag.astype(int)
        starts = np.concatenate(([0], np.cumsum(width)[:-1]))
        self._motor_size = int(width.sum())
        # the motor state's columns of [angles, speeds, contact flags]
        contact_cols = (starts + 2)[bound.has_contact_flag]
        self._motor_order = np.concatenate((starts, starts + 1, contact_cols))
        self._inv_speeds = 1.0 / bound.speeds
        self._contact_sensors = gather_index(self._sensor_adr(model, bound.contact_geom_ids))
        self._critical_sensors = gather_index(self._sensor_adr(model, bound.critical_geom_ids))
        self._has_critical = len(bound.critical_geom_ids) > 0
        self._qpos_index = gather_index(bound.qpos_adr)
        self._qvel_index = gather_index(bound.dof_adr)
        self._lidar_col = self.head_size + bound.motor_state_size + self.grasp_size
        self._ctrl_index = gather_index(bound.actuator_ids)
        self._nb_motors = len(bound.speeds)
        self._root = bound.root_id

    @staticmethod
    def _sensor_adr(model: mujoco.MjModel, geom_ids: np.ndarray, against=None) -> np.ndarray:
        """sensordata columns of the touch sensors of these geoms (see `touch_sensor_name`)."""
        names = [touch_sensor_name(model.geom(int(g)).name, against) for g in geom_ids]
        return np.array([model.sensor(n).adr[0] for n in names], dtype=int)

    def grasp_state(self) -> np.ndarray:
        """Climbers' sensor state, 2 entries per `Body.grasp_sensors` item: [has_contact,
        has_grasp]; always 0 on tracks without graspable surfaces (Parkour reports its grasps).
        Empty for every other body."""
        return np.zeros(self.grasp_size)

    def extra_obs_size(self) -> int:
        """Hook for rules that add observation entries after the lidars (Parkour's surface flags)."""
        return 0

    @property
    def steps_in_batch(self) -> bool:
        """N envs under these rules step as one batch when its sensor reads rows of heights (the
        batched env steps a ray-cast lidar's one env at a time); Parkour's always do."""
        return self.lidar.reads_height_rows

    def new_rows(self, n: int) -> EpisodeRows:
        """Running-episode rows for n envs under these rules."""
        heights = self.lidar.batch_heights(n) if self.lidar.reads_height_rows else None
        return EpisodeRows(n, heights)

    def take_terrain(self, rows: EpisodeRows, i: int = 0) -> None:
        """Row i's env wrote a new terrain (reset or restore): the lidar reads it from its row."""
        if rows.heights is not None:
            heights = self.lidar.arena.heights  # a height line (cols,) or a field (rows, cols)
            rows.heights[i, ..., : heights.shape[-1]] = heights

    # ------------------------------------------------------------------ actions
    def servo(self, actions: np.ndarray, caps: list[np.ndarray], controls: np.ndarray) -> None:
        """Velocity servos towards speed*sign(a) with torque capped at torque*|a| (Box2D motor
        semantics): `caps[i]` is env i's `actuator_forcerange` (its model's), `controls` (N, nu)."""
        motors = actions[:, : self._nb_motors]
        magnitude = np.minimum(np.abs(motors), 1.0) * self.body.torque
        ranges = magnitude[:, :, None] * _LOW_HIGH  # (N, motors, 2): [-cap, cap]
        index = self._ctrl_index
        for cap, r in zip(caps, ranges):
            cap[index] = r
        controls[:, index] = self.bound.speeds * np.sign(motors)

    def begin_episode(self, rows: EpisodeRows) -> None:
        """Clear the episode rules of `rows` before the body is placed (the tracks' have none)."""

    def before_physics(self, physics, actions: np.ndarray, rows: EpisodeRows) -> np.ndarray:
        """The arenas' forces for the coming step; returns the (N, action) actions the bodies
        play (on a track: the ones given, and no forces)."""
        return actions

    # ------------------------------------------------------------------ physics readings
    def touched(self, physics, sensors: np.ndarray) -> np.ndarray:
        """(N, len(sensors)) flags: the geoms of these touch sensors touch anything."""
        return physics.field("sensordata")[:, sensors] > 0.0

    def head(self, physics, out: np.ndarray) -> np.ndarray:
        """Write the head observation into out (N, 4 or 9): angle, 2*omega/50, 0.12*vx,
        0.08*vz (+ roll, yaw, 0.12*vy, 2*omega_x/50, 2*omega_z/50 for free 3D bodies); return
        the x of the head (N,)."""
        root = self._root
        r = physics.field("xmat")[:, root]  # row-major 3x3: columns are the body axes
        qv = physics.field("qvel")
        v = self.bound.root_dof
        # nose-up positive (rotation about -y); math.atan2 per element, as a single env
        out[:, 0] = list(map(math.atan2, r[:, 6].tolist(), r[:, 0].tolist()))
        if self.body.planar:  # 2 omega / 50 is omega / 25 to the bit (2 omega is exact)
            np.divide(qv[:, v + 2], 25.0, out=out[:, 1])
            np.multiply(qv[:, v : v + 2], _PLANAR_VELOCITY_GAINS, out=out[:, 2:4])
        else:
            out[:, 2] = 0.12 * qv[:, v]
            omega = physics.field("cvel")[:, root]  # world angular velocity first
            out[:, 1] = -2.0 * omega[:, 1] / 50.0
            out[:, 3] = 0.08 * qv[:, v + 2]
            out[:, 4] = list(map(math.atan2, r[:, 7].tolist(), r[:, 8].tolist()))
            out[:, 5] = list(map(math.atan2, r[:, 3].tolist(), r[:, 0].tolist()))
            out[:, 6] = 0.12 * qv[:, v + 1]
            out[:, 7] = 2.0 * omega[:, 0] / 50.0
            out[:, 8] = 2.0 * omega[:, 2] / 50.0
        return physics.field("xpos")[:, root, 0]

    def motor_state(self, physics, out: np.ndarray) -> None:
        """Write the motor state into out (N, motor state): per motor [angle + correction,
        speed / servo speed, (contact flag)]."""
        b = self.bound
        out[:, self._motor_order] = np.concatenate(
            (
                physics.field("qpos")[:, self._qpos_index] + b.angle_correction,
                physics.field("qvel")[:, self._qvel_index] * self._inv_speeds,
                self.touched(physics, self._contact_sensors),
            ),
            axis=1,
        )

    # ------------------------------------------------------------------ episode logic
    def shaping(self, x: np.ndarray, angle: np.ndarray) -> np.ndarray:
        s = PROGRESS_GAIN * x
        if self.body.head_angle_reward:
            s = s - ANGLE_PENALTY * np.abs(angle)
        return s

    def observe(self, physics, rows: EpisodeRows) -> tuple[np.ndarray, np.ndarray]:
        """(x of the head (N,), observation (N, obs_size) float64): head, motor state, (zero)
        grasp state, lidar fractions; Parkour adds its own."""
        n = physics.controls.shape[0]
        obs = np.zeros((n, self.obs_size))
        x = self.head(physics, obs[:, : self.head_size])
        self.motor_state(physics, obs[:, self.head_size : self.head_size + self._motor_size])
        if self.grasp_size:
            obs[:, self._lidar_col - self.grasp_size : self._lidar_col] = self.grasp_state()
        obs[:, self._lidar_col : self._lidar_col + self.lidar.nb_rays] = self.sense(physics, rows)
        return x, obs

    def sense(self, physics, rows: EpisodeRows) -> np.ndarray:
        """(N, nb_rays) terrain sensor readings: the height-line lidar and the height scan read all
        envs at once from their rows' heights and the roots' positions and orientations; another
        sensor (`read(model, data, origin)`) reads one env."""
        if rows.heights is not None:
            root = self._root
            xpos, xmat = physics.field("xpos")[:, root], physics.field("xmat")[:, root]
            return self.lidar.read_batch(rows.heights, xpos, xmat)
        data = physics.data
        return self.lidar.read(physics.model, data, data.xpos[self._root])[None]

    def potential(self, physics, x: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """(N,) shaping whose differences reward a step, from the head's x and the observation."""
        return self.shaping(x, obs[:, 0])

    def reset_rows(self, physics, rows: EpisodeRows) -> np.ndarray:
        """First observation (N, obs) float32 of episodes whose bodies were just placed."""
        x, obs = self.observe(physics, rows)
        rows.prev_shaping[:] = self.potential(physics, x, obs)
        rows.critical_contact[:] = False
        rows.episode_return[:] = 0.0
        rows.warnings[:] = 0  # MuJoCo's reset cleared its counts: a diverged idle step counts
        return obs.astype(np.float32)

    def outcome(self, physics, actions: np.ndarray, rows: EpisodeRows):
        """The outcome after physics: (obs (N, obs) float64, reward (N,), terminated (N,))."""
        x, obs = self.observe(physics, rows)
        shaping = self.potential(physics, x, obs)
        reward = shaping - rows.prev_shaping
        rows.prev_shaping[:] = shaping
        reward -= self.body.torque_cost_per_unit * torque_use(actions)
        if self._has_critical:
            touched = self.touched(physics, self._critical_sensors)
            np.logical_or.reduce(touched, axis=1, out=rows.critical_contact)
        fail = rows.critical_contact | (x < 0.0)
        reward[fail] = FAIL_REWARD
        return obs, reward, fail | (x > self.end_x)

    def step(self, physics, actions: np.ndarray, rows: EpisodeRows):
        """After physics: (obs (N, obs) float32, reward (N,), terminated (N,), unstable (N,)).

        A simulation MuJoCo had to reset (diverged) ends its episode, flagged `unstable`.
        """
        obs, reward, terminated = self.outcome(physics, actions, rows)
        warnings = physics.warnings[:, _BADQACC]
        unstable = warnings > rows.warnings
        rows.warnings[:] = warnings
        rows.episode_return += reward
        return obs.astype(np.float32), reward, terminated | unstable, unstable

    # ------------------------------------------------------------------ exact snapshots
    def episode_state(self, rows: EpisodeRows) -> dict:
        """One env's rule state beyond the shared rows' fields (none on a track)."""
        return {}

    def check_episode_state(self, state) -> dict:
        return {}

    def set_episode_state(self, checked: dict, rows: EpisodeRows) -> None:
        """Restore what `check_episode_state` returned."""
