"""Stump Tracks and Hexagon Tracks as Gymnasium environments (one class, two track kinds).

Composition, as in dm_control locomotion: a body (acl3d.bodies), a terrain generator
(acl3d.terrain, pure numpy) and a task (TrackTask), bound together in one compiled model.
The task (track parameters) can change at every reset without recompiling: the new profile is
written into the heightfield in place. Per-episode randomness comes from `self.np_random`.
"""

from __future__ import annotations

from collections.abc import Mapping

import gymnasium as gym
import mujoco
import numpy as np

from acl3d.bodies import Body, make_body
from acl3d.envs.arena import Arena
from acl3d.envs.lidar import ProfileLidar
from acl3d.envs.track_task import SUCCESS_RETURN, TrackTask
from acl3d.rendering import TrackRenderer
from acl3d.task_space import TaskSpace
from acl3d.terrain.tracks import (
    TrackGenerator,
    TrackGrid,
    check_buildable,
    track_task_space,
)

TRACKS = {
    "stump": ("stump_height", "obstacle_spacing"),
    "hexagon": ("poly_shape",),
}
CONTROL_DT = 1 / 50  # 50 Hz control, as the original
INIT_PUSH = 5.0  # the original pushes the hull once with a horizontal force U(-5, 5)


class TrackEnv(gym.Env):
    """A straight ~93 m track along +x with stumps or hexagons; any body runs on it.

    Args:
        track: "stump" or "hexagon".
        body: a body name (see `acl3d.bodies.BODIES`) or a `Body` instance.
        planar: sagittal-plane joints (True) or a free-floating 3D body (False); default per body.
        task_parameters: which track parameters form the task space (default per track kind).
        body_options: options of the body (e.g. leg counts), validated by the body.
        frame_skip: physics steps per control step (timestep = 0.02 / frame_skip); default per body.
        render_mode, width, height, camera, quality: offscreen rendering ("fast" or "high").
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(
        self,
        track: str = "stump",
        body: str | Body = "classic_bipedal",
        planar: bool | None = None,
        task_parameters: tuple[str, ...] | None = None,
        body_options: Mapping | None = None,
        frame_skip: int | None = None,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        camera: str | None = None,
        quality: str = "fast",
    ):
        if track not in TRACKS:
            raise ValueError(f"track={track!r}; valid: {list(TRACKS)}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode={render_mode!r}; valid: None, 'rgb_array'")
        if quality not in ("fast", "high"):
            raise ValueError(f"quality={quality!r}; valid: 'fast' (no MSAA, no shadows) or 'high'")
        self.track = track
        self.body = (
            body
            if isinstance(body, Body)
            else make_body(body, planar=planar, **dict(body_options or {}))
        )
        frame_skip = self.body.frame_skip if frame_skip is None else frame_skip
        if not isinstance(frame_skip, int) or not 1 <= frame_skip <= 20:
            raise ValueError(f"frame_skip={frame_skip!r}; valid: an integer in [1, 20]")
        self.task_space: TaskSpace = self._make_task_space(task_parameters)
        self.generator = self._make_generator()
        self.frame_skip = frame_skip
        self.arena = self._build_arena()
        self.model, self.bound = self.arena.model, self.arena.bound
        self.model.opt.timestep = CONTROL_DT / frame_skip
        self.data = mujoco.MjData(self.model)
        self._warning_counts = self.data.warning.number  # a live view
        self.task = self._make_task()

        self.action_space = gym.spaces.Box(
            -1.0, 1.0, shape=(self.body.action_size,), dtype=np.float32
        )
        self.observation_space = gym.spaces.Box(
            -np.inf, np.inf, shape=(self.task.obs_size,), dtype=np.float32
        )
        self._speeds = self.bound.speeds
        self._forcerange = self.model.actuator_forcerange
        self._ctrl_ids = self.bound.actuator_ids
        self._nb_motors = len(self._speeds)
        self._task_vector = self.task_space.to_vector({})
        self._episode_return = 0.0
        self._warnings = 0

        self.render_mode = render_mode
        self._render_args = dict(
            width=width, height=height, camera=camera or self.arena.camera, quality=quality
        )
        self._renderer: TrackRenderer | None = None

    # ------------------------------------------------------------------ construction hooks
    def _make_task_space(self, task_parameters) -> TaskSpace:
        return track_task_space(task_parameters or TRACKS[self.track])

    def _make_generator(self):
        return TrackGenerator(TrackGrid())

    def _check_buildable(self, task: dict) -> None:
        """Raise ValueError if the generator cannot build `task` (names the parameter and range)."""
        check_buildable(task)

    def _build_arena(self) -> Arena:
        return Arena(self.body, self.generator.grid)

    def _make_task(self) -> TrackTask:
        return TrackTask(self.bound, ProfileLidar(self.arena, "down"))

    # ------------------------------------------------------------------ tasks
    def set_task(self, task) -> None:
        """Set the task used from the next reset on: a dict (partial: defaults fill the rest) or a flat vector."""
        if isinstance(task, Mapping):
            vector = self.task_space.to_vector(task)
        else:
            vector = self.task_space.validate_vector(task)
        self._check_buildable(self.task_space.to_dict(vector))
        self._task_vector = vector

    def set_environment(self, **params) -> None:
        """TeachMyAgent's name for `set_task(params)`."""
        self.set_task(params)

    def get_task(self) -> dict:
        return self.task_space.to_dict(self._task_vector)

    @property
    def task_vector(self) -> np.ndarray:
        return self._task_vector.copy()

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if options and "task" in options:
            self.set_task(options["task"])
        unknown = set(options or {}) - {"task"}
        if unknown:
            raise ValueError(f"unknown reset option(s) {sorted(unknown)}; valid: ['task']")
        self._new_terrain()
        mujoco.mj_resetData(self.model, self.data)
        self._place_body()
        mujoco.mj_forward(self.model, self.data)
        self._episode_return = 0.0
        self._warnings = 0
        self._apply_action(
            np.zeros(self.body.action_size)
        )  # the original returns the obs after one idle step
        mujoco.mj_step(self.model, self.data, nstep=self.frame_skip)
        obs = self.task.reset(self.model, self.data)
        return obs, self._info(False)

    def step(self, action):
        action = np.asarray(action, dtype=np.float64)
        if action.shape != (self.body.action_size,):
            raise ValueError(
                f"action: expected shape ({self.body.action_size},), got {action.shape}"
            )
        if not np.isfinite(action).all():
            raise ValueError(f"action: non-finite values {action}")
        self._apply_action(action)
        mujoco.mj_step(self.model, self.data, nstep=self.frame_skip)
        obs, reward, terminated, _ = self.task.step(self.model, self.data, action)
        unstable = self._check_instability()
        if unstable:
            terminated = True
        self._episode_return += reward
        return obs, reward, terminated, False, self._info(unstable)

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = TrackRenderer(self.model, **self._render_args)
        for hfield in self.arena.hfield_ids:
            self._renderer.upload_hfield(hfield, self.arena.version)
        return self._renderer.render(self.data)

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # ------------------------------------------------------------------ internals
    def _new_terrain(self) -> None:
        self.arena.write_heights(
            self.generator.profile(self.get_task(), self.np_random, self.arena.start_pad)
        )

    def _place_body(self) -> None:
        self.bound.place(self.data, self.arena.start_x, self.body.spawn_height)
        push = self.np_random.uniform(-INIT_PUSH, INIT_PUSH)  # drawn for every body: same stream
        if not self.body.initial_push:  # the original never pushes the fish
            return
        # the one-off horizontal force of the original, as the velocity change it gives in one step
        self.data.qvel[self.bound.root_dof] = push * CONTROL_DT / self.bound.total_mass

    def _apply_action(self, action: np.ndarray) -> None:
        """Velocity servos towards speed*sign(a) with torque capped at torque*|a| (Box2D motor semantics)."""
        motors = action[: self._nb_motors]
        magnitude = np.minimum(np.abs(motors), 1.0) * self.body.torque
        self._forcerange[self._ctrl_ids, 0] = -magnitude
        self._forcerange[self._ctrl_ids, 1] = magnitude
        self.data.ctrl[self._ctrl_ids] = self._speeds * np.sign(motors)

    def _check_instability(self) -> bool:
        """MuJoCo resets a diverged simulation and counts it; end the episode when that happens."""
        count = int(self._warning_counts[mujoco.mjtWarning.mjWARN_BADQACC])
        unstable = count > self._warnings
        self._warnings = count
        return unstable

    def _info(self, unstable: bool) -> dict:
        info = {"success": bool(self._episode_return > SUCCESS_RETURN)}
        if unstable:
            info["unstable"] = True
        return info
