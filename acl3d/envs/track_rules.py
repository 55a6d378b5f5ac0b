"""The tracks' rules: observation, reward, termination and success, for N envs at once.

An env's *rules* (dm_control calls this object its task; acl3d keeps "task" for the parameter
vector a teacher picks) turn the physics into what the agent sees and is paid.

Follows TeachMyAgent §2.1: shaping = 130/30 * x_head - 5 * |angle| (angle term dropped for bodies
without it), step reward = shaping difference - torque cost; a critical contact or going behind
the track start replaces the step reward by -100 and terminates; crossing the end line
terminates; an episode succeeds when its return passes the curriculum profile's success_return.

Written once for every backend. The arithmetic (`servo`, `observe`, `potential`, `critical`,
`outcome`, `success`) works on (N, ...) arrays of an `ArrayOps` library: numpy on the CPU (a
single env's `PhysicsState` is N = 1, the batched env's `BatchPhysics` is N), torch on the
many-world simulation (`on(ops)` gives the same rules over torch tensors on a device, reading a
`Simulation`). Element by element the arithmetic is the same whatever N (reductions only along
rows), so every row of a batch is bit-identical to the same env stepped alone.

The CPU envs keep each env's running episode in an `EpisodeRows` row (a sub-env of a batched env
holds a view of its row of the batch's rows, so nothing is mirrored) and use `new_rows(n)`,
`reset_rows(physics, rows)` (first observation), `step(physics, actions, rows)`,
`take_terrain(rows, i)`, and the per-env `begin_episode`, `before_physics`, `episode_state` /
`check_episode_state` / `set_episode_state`. New rules override the hooks they need: `observe`
(the observation layout), `potential` (the shaping), `outcome` (reward and termination), as 3D
Terrain's rules do; Parkour's CPU rules override `observe_rows` and `outcome_rows`, which read
their per-env arenas.
"""

from __future__ import annotations

from typing import NamedTuple

import mujoco
import numpy as np

from acl3d.bodies.base import BoundBody
from acl3d.envs.array_ops import ArrayOps
from acl3d.envs.lidar import TerrainSensor
from acl3d.terrain.tracks import END_X

FAIL_REWARD = -100.0
PROGRESS_GAIN = 130.0 / 30.0  # reward per metre of forward progress
ANGLE_PENALTY = 5.0
TOUCH_SENSOR_PREFIX = "touch_"  # contact sensors on the body's flagged and critical geoms
_BADQACC = int(mujoco.mjtWarning.mjWARN_BADQACC)
_PLANAR_VELOCITY_GAINS = (0.12, 0.08)  # vx, vz in the head observation
_LOW_HIGH = (-1.0, 1.0)  # a force range from a cap (x -1 is exact negation)


def touch_sensor_name(geom: str, against: str | None = None) -> str:
    """The contact sensor that counts the contacts of the (prefixed) geom `geom` (with the geom
    `against` only, if given)."""
    return TOUCH_SENSOR_PREFIX + geom + ("" if against is None else "|" + against)


def torque_use(ops: ArrayOps, actions):
    """(N,) sum of |a| clipped at 1 per env: what the torque cost is proportional to."""
    return ops.clip(ops.xp.abs(actions), high=1.0).sum(axis=1)


class _Scalars(NamedTuple):
    """The step's scalars as 0-d arrays of the rules' library (see `TrackRules.__init__`)."""

    zero: object
    one: object
    torque: object
    torque_cost: object
    progress_gain: object
    angle_penalty: object
    fail_reward: object
    end_x: object
    success_return: object


class Outcome(NamedTuple):
    """What the rules judge after a physics step, (N, ...) arrays: the observation, the step's
    reward, whether the episode ended, the shaping (the next step's `prev_shaping`), whether a
    critical part touched something, and `crossed` (a finish line's success flags; None where
    success is judged by the return)."""

    obs: object
    reward: object
    terminated: object
    shaping: object
    critical: object
    crossed: object = None


class EpisodeRows:
    """The running episodes of N envs, one row each (see the module docstring).

    prev_shaping: the last step's shaping; critical_contact: a critical part touched something
    at the last step; episode_return: the running return; warnings: MuJoCo's count of diverged
    steps seen so far; success: the episode succeeded (as of the last step); heights: each
    env's terrain (for the height-line lidar; None if the lidar reads the arena itself).
    """

    def __init__(self, n: int, heights: np.ndarray | None = None):
        self.prev_shaping = np.zeros(n)
        self.critical_contact = np.zeros(n, dtype=bool)
        self.episode_return = np.zeros(n)
        self.warnings = np.zeros(n, dtype=np.int64)
        self.success = np.zeros(n, dtype=bool)
        self.heights = heights

    def row(self, i: int) -> EpisodeRows:
        """Env i's row as an `EpisodeRows` of one whose arrays are views of these."""
        out = type(self).__new__(type(self))
        for name, value in vars(self).items():
            setattr(out, name, None if value is None else value[i : i + 1])
        return out


class TrackRules:
    """Observation, reward, termination and success of envs of one bound body (see the module
    docstring).

    Args:
        bound: the body bound to the compiled model.
        lidar: the terrain sensor (its `ops` are the rules').
        end_x: the finish line.
        success_return: an episode whose return passes it succeeded (the curriculum profile's).
    """

    # the MjData fields the step reads or writes through `physics.field`
    physics_fields: tuple[str, ...] = ("qpos", "qvel", "ctrl", "xpos", "xmat", "cvel", "sensordata")

    def __init__(
        self,
        bound: BoundBody,
        lidar: TerrainSensor,
        end_x: float = END_X,
        success_return: float = np.inf,
    ):
        self.bound = bound
        self.body = bound.body
        self.lidar = lidar
        self.ops: ArrayOps = lidar.ops
        self.end_x = end_x
        self.success_return = success_return
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
        model, ops = bound.model, self.ops
        # where each motor's entries sit in the motor state (a contact flag follows some)
        width = 2 + bound.has_contact_flag.astype(int)
        starts = np.concatenate(([0], np.cumsum(width)[:-1]))
        self._motor_size = int(width.sum())
        # the motor state's columns of [angles, speeds, contact flags]
        contact_cols = (starts + 2)[bound.has_contact_flag]
        self._motor_order = ops.index(np.concatenate((starts, starts + 1, contact_cols)))
        # per-motor constants as (1, motors) rows and scalars as 0-d arrays: numpy's ufuncs take
        # operands of one shape (one env's are (1, ...)) and 0-d arrays faster than (motors,)
        # rows and Python floats
        self._inv_speeds = ops.asarray(1.0 / bound.speeds)[None]
        self._speeds = ops.asarray(bound.speeds)[None]
        self._angle_correction = ops.asarray(bound.angle_correction)[None]
        self._planar_gains = ops.asarray(_PLANAR_VELOCITY_GAINS)[None]
        self._low_high = ops.asarray(_LOW_HIGH)
        self._scalar = _Scalars(
            *map(ops.asarray, (0.0, 1.0, self.body.torque, self.body.torque_cost_per_unit)),
            *map(ops.asarray, (PROGRESS_GAIN, ANGLE_PENALTY, FAIL_REWARD, end_x, success_return)),
        )
        self._contact_sensors = ops.index(self._sensor_adr(model, bound.contact_geom_ids))
        self._critical_sensors = ops.index(self._sensor_adr(model, bound.critical_geom_ids))
        self._qpos_index = ops.index(bound.qpos_adr)
        self._qvel_index = ops.index(bound.dof_adr)
        self._lidar_col = self.head_size + bound.motor_state_size + self.grasp_size
        self._ctrl_index = ops.index(bound.actuator_ids)
        self._nb_motors = len(bound.speeds)
        self._root = bound.root_id

    def on(self, ops: ArrayOps) -> TrackRules:
        """These rules over arrays of `ops` (the many-world simulation's tensors); the sensor
        must read rows of heights (`on(ops)` too)."""
        return TrackRules(self.bound, sensor_on(self.lidar, ops), self.end_x, self.success_return)

    @staticmethod
    def _sensor_adr(model: mujoco.MjModel, geom_ids: np.ndarray, against=None) -> np.ndarray:
        """sensordata columns of the touch sensors of these geoms (see `touch_sensor_name`)."""
        names = [touch_sensor_name(model.geom(int(g)).name, against) for g in geom_ids]
        return np.array([model.sensor(n).adr[0] for n in names], dtype=int)

    def grasp_state(self):
        """Climbers' sensor state, 2 entries per `Body.grasp_sensors` item: [has_contact,
        has_grasp]; always 0 on tracks without graspable surfaces (Parkour's rules report
        their grasps). Empty for every other body."""
        return self.ops.full((self.grasp_size,), 0.0)

    def extra_obs_size(self) -> int:
        """Hook for rules that add observation entries after the lidars (Parkour's surface flags)."""
        return 0

    @property
    def steps_in_batch(self) -> bool:
        """N envs under these rules step as one batch when its sensor reads rows of heights (the
        batched env steps a ray-cast lidar's one env at a time); Parkour's always do."""
        return self.lidar.reads_height_rows

    # ------------------------------------------------------------------ actions
    def servo(self, actions, physics) -> None:
        """Velocity servos towards speed * sign(a) with torque capped at torque * |a| (Box2D motor
        semantics), written to the physics' controls and per-env force caps."""
        ops = self.ops
        motors = actions[:, : self._nb_motors]
        magnitude = ops.clip(ops.xp.abs(motors), high=self._scalar.one) * self._scalar.torque
        physics.set_force_caps(self._ctrl_index, magnitude[:, :, None] * self._low_high)
        physics.field("ctrl")[:, self._ctrl_index] = self._speeds * ops.xp.sign(motors)

    # ------------------------------------------------------------------ physics readings
    def touched(self, physics, sensors):
        """(N, len(sensors)) flags: the geoms of these touch sensors touch anything."""
        return physics.field("sensordata")[:, sensors] > self._scalar.zero

    def head(self, physics, out):
        """Write the head observation into out (N, 4 or 9): angle, 2*omega/50, 0.12*vx,
        0.08*vz (+ roll, yaw, 0.12*vy, 2*omega_x/50, 2*omega_z/50 for free 3D bodies); return
        the x of the head (N,)."""
        ops, root = self.ops, self._root
        xmat = physics.field("xmat")
        r = xmat[:, root].reshape(xmat.shape[0], 9)  # row-major: columns are the body axes
        qv = physics.field("qvel")
        v = self.bound.root_dof
        out[:, 0] = ops.atan2(r[:, 6], r[:, 0])  # nose-up positive (rotation about -y)
        if self.body.planar:  # 2 omega / 50 is omega / 25 to the bit (2 omega is exact)
            out[:, 1] = qv[:, v + 2] / 25.0
            out[:, 2:4] = qv[:, v : v + 2] * self._planar_gains
        else:
            out[:, 2] = 0.12 * qv[:, v]
            omega = physics.field("cvel")[:, root]  # world angular velocity first
            out[:, 1] = -2.0 * omega[:, 1] / 50.0
            out[:, 3] = 0.08 * qv[:, v + 2]
            out[:, 4] = ops.atan2(r[:, 7], r[:, 8])
            out[:, 5] = ops.atan2(r[:, 3], r[:, 0])
            out[:, 6] = 0.12 * qv[:, v + 1]
            out[:, 7] = 2.0 * omega[:, 0] / 50.0
            out[:, 8] = 2.0 * omega[:, 2] / 50.0
        return physics.field("xpos")[:, root, 0]

    def motor_state(self, physics, out) -> None:
        """Write the motor state into out (N, motor state): per motor [angle + correction,
        speed / servo speed, (contact flag)]."""
        ops = self.ops
        touched = self.touched(physics, self._contact_sensors)
        out[:, self._motor_order] = ops.xp.concatenate(
            (
                physics.field("qpos")[:, self._qpos_index] + self._angle_correction,
                physics.field("qvel")[:, self._qvel_index] * self._inv_speeds,
                ops.to_float(touched),
            ),
            axis=1,
        )

    def critical(self, physics):
        """(N,) flags: a critical part of the body touches something (none: all False)."""
        return self.touched(physics, self._critical_sensors).any(axis=1)

    def sense(self, physics, heights):
        """(N, nb_rays) terrain sensor readings: the height-line lidar and the height scan read all
        envs at once from their rows' `heights` and the roots' positions and orientations; a
        ray-cast sensor (`read(model, data, origin)`, heights None) reads one env."""
        root = self._root
        if heights is not None:
            xpos, xmat = physics.field("xpos")[:, root], physics.field("xmat")[:, root]
            return self.lidar.read_batch(heights, xpos, xmat)
        data = physics.data
        return self.lidar.read(physics.model, data, data.xpos[root])[None]

    # ------------------------------------------------------------------ judging a step
    def observe(self, physics, heights):
        """(x of the head (N,), observation (N, obs_size) in the rules' precision): head, motor
        state, (zero) grasp state, terrain readings; 3D Terrain adds its own."""
        obs = self.ops.full((physics.field("qpos").shape[0], self.obs_size), 0.0)
        x = self.head(physics, obs[:, : self.head_size])
        self.motor_state(physics, obs[:, self.head_size : self.head_size + self._motor_size])
        if self.grasp_size:
            obs[:, self._lidar_col - self.grasp_size : self._lidar_col] = self.grasp_state()
        obs[:, self._lidar_col : self._lidar_col + self.lidar.nb_rays] = self.sense(
            physics, heights
        )
        return x, obs

    def shaping(self, x, angle):
        s = self._scalar.progress_gain * x
        if self.body.head_angle_reward:
            s = s - self._scalar.angle_penalty * self.ops.xp.abs(angle)
        return s

    def potential(self, physics, x, obs):
        """(N,) shaping whose differences reward a step, from the head's x and the observation."""
        return self.shaping(x, obs[:, 0])

    def outcome(self, physics, actions, heights, prev_shaping) -> Outcome:
        """The step's `Outcome` after physics, given the last step's shaping (N,)."""
        x, obs = self.observe(physics, heights)
        shaping = self.potential(physics, x, obs)
        cost = self._scalar.torque_cost * torque_use(self.ops, actions)
        reward = shaping - prev_shaping - cost
        critical = self.critical(physics)
        failed, terminated, crossed = self.ending(physics, x, obs, critical)
        reward = self.ops.xp.where(failed, self._scalar.fail_reward, reward)
        return Outcome(obs, reward, terminated, shaping, critical, crossed)

    def ending(self, physics, x, obs, critical) -> tuple:
        """(failed, terminated, crossed) flags (N,): on a track, a critical contact or going
        behind the start fails, crossing the end line ends the episode; crossed None (success is
        judged by the return)."""
        failed = critical | (x < self._scalar.zero)
        return failed, failed | (x > self._scalar.end_x), None

    def success(self, returns, outcome: Outcome):
        """(N,) success flags of episodes whose return is now `returns`: past the curriculum
        profile's success_return, or across a finish line where the rules have one."""
        if outcome.crossed is None:
            return returns > self._scalar.success_return
        return outcome.crossed

    # ------------------------------------------------------------------ the CPU envs' rows
    def new_rows(self, n: int) -> EpisodeRows:
        """Running-episode rows for n envs under these rules."""
        heights = self.lidar.batch_heights(n) if self.lidar.reads_height_rows else None
        return EpisodeRows(n, heights)

    def take_terrain(self, rows: EpisodeRows, i: int = 0) -> None:
        """Row i's env wrote a new terrain (reset or restore): the lidar reads it from its row."""
        if rows.heights is not None:
            heights = self.lidar.arena.heights  # a height line (cols,) or a field (rows, cols)
            rows.heights[i, ..., : heights.shape[-1]] = heights

    def begin_episode(self, rows: EpisodeRows) -> None:
        """Clear the episode rules of `rows` before the body is placed (the tracks' have none)."""

    def before_physics(self, physics, actions, episodes):
        """The arenas' forces for the coming step; returns the (N, action) actions the bodies
        play (on a track: the ones given, and no forces). `episodes`: the running episodes, the
        CPU envs' `EpisodeRows` or the many worlds' rows of heights (Parkour's records)."""
        return actions

    def observe_rows(self, physics, rows: EpisodeRows):
        """`observe` of the envs in `rows`."""
        return self.observe(physics, rows.heights)

    def outcome_rows(self, physics, actions: np.ndarray, rows: EpisodeRows) -> Outcome:
        """`outcome` of the envs in `rows`."""
        return self.outcome(physics, actions, rows.heights, rows.prev_shaping)

    def reset_rows(self, physics, rows: EpisodeRows) -> np.ndarray:
        """First observation (N, obs) float32 of episodes whose bodies were just placed."""
        x, obs = self.observe_rows(physics, rows)
        rows.prev_shaping[:] = self.potential(physics, x, obs)
        rows.critical_contact[:] = False
        rows.episode_return[:] = 0.0
        rows.success[:] = False
        rows.warnings[:] = 0  # MuJoCo's reset cleared its counts: a diverged idle step counts
        return obs.astype(np.float32)

    def step(self, physics, actions: np.ndarray, rows: EpisodeRows):
        """After physics: (obs (N, obs) float32, reward (N,), terminated (N,), unstable (N,));
        `rows.success` holds the episodes' success flags.

        A simulation MuJoCo had to reset (diverged) ends its episode, flagged `unstable`.
        """
        out = self.outcome_rows(physics, actions, rows)
        rows.prev_shaping[:] = out.shaping
        rows.critical_contact[:] = out.critical
        warnings = physics.warnings[:, _BADQACC]
        unstable = warnings > rows.warnings
        rows.warnings[:] = warnings
        rows.episode_return += out.reward
        rows.success[:] = self.success(rows.episode_return, out)
        return out.obs.astype(np.float32), out.reward, out.terminated | unstable, unstable

    # ------------------------------------------------------------------ exact snapshots
    def episode_state(self, rows: EpisodeRows) -> dict:
        """One env's rule state beyond the shared rows' fields (none on a track)."""
        return {}

    def check_episode_state(self, state) -> dict:
        return {}

    def set_episode_state(self, checked: dict, rows: EpisodeRows) -> None:
        """Restore what `check_episode_state` returned."""


def sensor_on(sensor, ops: ArrayOps):
    """`sensor` reading arrays of `ops`: the height-line lidar and the height scan (rows of
    heights); a ray-cast lidar reads one CPU env's scene and has no such form."""
    if not sensor.reads_height_rows:
        raise ValueError(
            f"observation={type(sensor).__name__}; the many-world simulation reads rows of "
            "heights only (the tracks' observation='lidar', 3D Terrain's 'height_scan')"
        )
    return sensor.on(ops)
