"""Stump Tracks and Hexagon Tracks as Gymnasium environments (one class, two track kinds).

Composition, as in dm_control locomotion: a body (acl3d.bodies), an arena (acl3d.envs.arena: the
terrain generator and what it writes) and the rules (TrackRules: observation, reward,
termination), bound together in one compiled model. A composition
(`acl3d.envs.track_composition`; Parkour's in acl3d.envs.parkour_env) builds the arena and the
rules for a body; `TrackEnv` is the core that binds and steps them.
The task (track parameters) can change at every reset without recompiling: the new height line
is written into the heightfield in place. Per-episode randomness comes from `self.np_random`.
"""

from __future__ import annotations

from collections.abc import Mapping

import gymnasium as gym
import mujoco
import numpy as np

from acl3d import validation
from acl3d.bodies import Body, make_body
from acl3d.curriculum_profile import CurriculumProfile
from acl3d.envs import env_state
from acl3d.envs.arena import CONTROL_DT
from acl3d.envs.track_composition import TRACKS, TrackComposition
from acl3d.rendering import TrackRenderer
from acl3d.task_space import TaskSpace
from acl3d.viewer import HumanViewer, check_display

MAX_IMAGE_SIZE = 8192  # pixels, per side of a rendered frame
_STATE_KEYS = (  # get_state()'s own keys (the RNG, physics and terrain parts check theirs)
    "signature",
    "task_vector",
    "episode_return",
    "instability_warnings",
    "rng_seed",
    "rules/prev_shaping",  # the rules' running numbers
    "rules/critical_contact",
)


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
        observation: the terrain sensor: "lidar" (10 sagittal rays, TeachMyAgent's) or
            "height_scan" (63 heights around the body in its heading frame,
            `acl3d.envs.height_scan`).

    Every argument is checked before anything is built (ValueError naming it, its value and
    what is allowed). `get_state()` / `set_state()` snapshot and restore a running episode
    exactly (see `acl3d.envs.env_state`).
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 50}

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
        observation: str = "lidar",
    ):
        validation.choice("track", track, list(TRACKS))
        self._compose(
            TrackComposition(track, task_parameters, observation),
            body,
            planar,
            body_options,
            frame_skip,
            render_mode,
            dict(width=width, height=height, camera=camera, quality=quality),
        )

    # ------------------------------------------------------------------ composition
    def _check_options(self, render_mode, frame_skip, body_options, width, height, camera, quality):
        """The arguments every env takes, checked before anything is built."""
        validation.choice("render_mode", render_mode, [None, *self.metadata["render_modes"]])
        if render_mode == "human":
            check_display()  # a headless machine fails here, not at the first render
        validation.choice("quality", quality, ("fast", "high"))
        validation.integer("width", width, 1, MAX_IMAGE_SIZE)
        validation.integer("height", height, 1, MAX_IMAGE_SIZE)
        if camera is not None and not isinstance(camera, str):
            raise validation.fail("camera", camera, "None or a camera name")
        if frame_skip is not None:
            validation.integer("frame_skip", frame_skip, 1, 20)
        if body_options is not None and not isinstance(body_options, Mapping):
            raise validation.fail("body_options", body_options, "None or a dict of body options")

    @staticmethod
    def _make_body(body, planar, body_options) -> Body:
        if isinstance(body, Body):
            return body
        if isinstance(body, str):
            return make_body(body, planar=planar, **dict(body_options or {}))
        raise validation.fail("body", body, "a body name or an acl3d.bodies.Body")

    def _compose(
        self, composition, body, planar, body_options, frame_skip, render_mode, render_args
    ) -> None:
        """Check the arguments every env takes, make the body and bind body x arena x rules (from
        `composition`) into one compiled model."""
        self._check_options(render_mode, frame_skip, body_options, **render_args)
        self.body = self._make_body(body, planar, body_options)
        self.composition = composition
        self.track = composition.track
        frame_skip = self.body.frame_skip if frame_skip is None else int(frame_skip)
        self.task_space: TaskSpace = composition.task_space
        self.frame_skip = frame_skip
        self.arena = composition.build_arena(self.body)
        self.generator = self.arena.generator
        self.model, self.bound = self.arena.model, self.arena.bound
        self.model.opt.timestep = CONTROL_DT / frame_skip
        camera = render_args["camera"]
        if (
            camera is not None
            and mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_CAMERA, camera) < 0
        ):
            cameras = [self.model.camera(i).name for i in range(self.model.ncam)]
            raise validation.fail("camera", camera, f"None or one of {cameras}")
        self.data = mujoco.MjData(self.model)
        self.physics = env_state.PhysicsState(self.model, self.data, frame_skip)
        self.rules = composition.build_rules(self.arena)
        self.rows = self.rules.new_rows(1)  # this episode's running numbers (see EpisodeRows)

        self.action_space = gym.spaces.Box(
            -1.0, 1.0, shape=(self.body.action_size,), dtype=np.float32
        )
        self.observation_space = gym.spaces.Box(
            -np.inf, np.inf, shape=(self.rules.obs_size,), dtype=np.float32
        )
        self._task_vector = self.task_space.to_vector({})

        self.render_mode = render_mode
        self._render_args = {**render_args, "camera": camera or self.arena.camera}
        self._renderer: TrackRenderer | None = None
        self._viewer: HumanViewer | None = None

    @property
    def curriculum_profile(self) -> CurriculumProfile:
        """What a curriculum needs to know about this track (reward bounds, priors, test sets)."""
        return self.composition.profile

    # ------------------------------------------------------------------ tasks
    def set_task(self, task) -> None:
        """Set the task used from the next reset on: a dict (partial: defaults fill the rest) or a flat vector."""
        self._task_vector = self._checked_task(task)

    def _checked_task(self, task) -> np.ndarray:
        """The task's flat vector, if the generator can build it (else ValueError)."""
        if isinstance(task, Mapping):
            vector = self.task_space.to_vector(task)
        else:
            vector = self.task_space.validate_vector(task)
        self.composition.check_buildable(self.task_space.to_dict(vector))
        return vector

    def get_task(self) -> dict:
        return self.task_space.to_dict(self._task_vector)

    @property
    def task_vector(self) -> np.ndarray:
        return self._task_vector.copy()

    # ------------------------------------------------------------------ exact snapshots
    def get_state(self) -> dict:
        """This episode as a flat dict of numpy arrays and JSON scalars (store it as JSON + NPZ).

        Physics (with the state the last step started from), terrain, task, the env's RNG and the
        episode's accumulators: an env built with the same arguments continues bit-identically
        after `set_state()`. Gymnasium wrappers keep their own counters (TimeLimit's step count):
        `acl3d.envs.env_state.get_env_state(env)` adds them for an env from `gymnasium.make`.
        """
        if not self.physics.stepped:
            raise gym.error.ResetNeeded("get_state() needs a running episode: call reset() first")
        return {
            "signature": self._signature(),
            "task_vector": self._task_vector.copy(),
            "episode_return": float(self.rows.episode_return[0]),
            "instability_warnings": int(self.rows.warnings[0]),
            "rng_seed": self._np_random_seed,
            "rules/prev_shaping": float(self.rows.prev_shaping[0]),
            "rules/critical_contact": bool(self.rows.critical_contact[0]),
            **env_state.rng_state(self.np_random),
            **self.physics.get(),
            **self._episode_state(),
        }

    def set_state(self, state) -> None:
        """Continue from a `get_state()` snapshot of an env built with the same arguments.

        The whole snapshot is checked before anything changes: a rejected one (ValueError)
        leaves this env as it was.
        """
        env_state.check_keys(state, _STATE_KEYS)
        if state["signature"] != self._signature():
            raise validation.fail(
                "state['signature']", state["signature"], f"this env's {self._signature()!r}"
            )
        seed = state["rng_seed"]
        checked = {
            "task_vector": self._checked_task(
                env_state.array(state, "task_vector", self._task_vector)
            ),
            "episode_return": env_state.scalar(state, "episode_return", "real"),
            "instability_warnings": env_state.scalar(state, "instability_warnings", "integer", 0),
            "rng_seed": None if seed is None else validation.integer("state['rng_seed']", seed, -1),
            "rules/prev_shaping": env_state.scalar(state, "rules/prev_shaping", "real"),
            "rules/critical_contact": env_state.scalar(state, "rules/critical_contact", "flag"),
            "rng": env_state.rng_from_state(state),
            "physics": self.physics.check(state),
            "episode": self._check_episode_state(state),
        }
        previous = self.get_state() if self.physics.stepped else None
        try:
            self._set_checked_state(checked)
        except ValueError:
            if previous is None:
                mujoco.mj_resetData(self.model, self.data)
                self.physics.stepped = False
            else:
                self.set_state(previous)
            raise

    def _set_checked_state(self, s: dict) -> None:
        self._task_vector = s["task_vector"]
        self.rows.episode_return[0] = s["episode_return"]
        self.rows.warnings[0] = s["instability_warnings"]
        self.np_random = s["rng"]
        self._np_random_seed = s["rng_seed"]
        self.rows.prev_shaping[0] = s["rules/prev_shaping"]
        self.rows.critical_contact[0] = s["rules/critical_contact"]
        self._set_episode_state(s["episode"])  # terrain first: the physics replay touches it
        self.physics.set(s["physics"])

    def _signature(self) -> str:
        """What must match between the env that saved a state and the one restoring it."""
        m = self.model
        return (
            f"{type(self).__name__}(track={self.track}, body={self.body.describe()}, "
            f"frame_skip={self.frame_skip}, task={list(self.task_space.names)}, "
            f"nq={m.nq}, nv={m.nv}, nu={m.nu}, ngeom={m.ngeom})"
            f"{self.composition.signature()}"
        )

    def _episode_state(self) -> dict:
        """The per-episode world (the arena's) and the rules' episode state."""
        return {**self.arena.episode_state(), **self.rules.episode_state(self.rows)}

    def _check_episode_state(self, state) -> dict:
        return {
            "arena": self.arena.check_episode_state(state),
            "rules": self.rules.check_episode_state(state),
        }

    def _set_episode_state(self, checked: dict) -> None:
        self.arena.set_episode_state(checked["arena"], self.data)
        self.rules.take_terrain(self.rows)
        self.rules.set_episode_state(checked["rules"], self.rows)

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """New episode; `options={"task": ...}` sets the task first. Everything (seed, options,
        task) is checked before anything changes."""
        seed = validation.seed(seed)
        if options is not None and not isinstance(options, Mapping):
            raise validation.fail("options", options, "None or a dict (valid keys: ['task'])")
        unknown = set(options or {}) - {"task"}
        if unknown:
            raise ValueError(
                f"unknown reset option(s) {sorted(map(str, unknown))}; valid: ['task']"
            )
        task = self._checked_task(options["task"]) if options and "task" in options else None
        super().reset(seed=seed)
        if task is not None:
            self._task_vector = task
        self.arena.regenerate(self.get_task(), self.np_random)
        self.rules.take_terrain(self.rows)
        self.rules.begin_episode(self.rows)
        mujoco.mj_resetData(self.model, self.data)
        self.arena.place_body(self.data, self.np_random)
        mujoco.mj_forward(self.model, self.data)
        # the original returns the obs after one idle step
        self._control_step(np.zeros(self.body.action_size))
        self.arena.settle(self.data, self._control_step)  # Parkour's climbers grasp
        obs = self.rules.reset_rows(self.physics, self.rows)[0]
        if self.render_mode == "human":
            self.render()
        return obs, self._info(False)

    def step(self, action):
        action = validation.real_array("action", action, shape=(self.body.action_size,))
        self.act(action, self.physics)
        self.physics.step()
        if self.render_mode == "human":
            self.render()
        return self.after_physics(action, self.physics)

    def after_physics(self, action: np.ndarray, physics):
        """The step's (obs, reward, terminated, truncated, info) once `physics` (this env's own,
        or its row of a batch) stepped."""
        obs, reward, terminated, unstable = self.rules.step(physics, action[None], self.rows)
        return obs[0], float(reward[0]), bool(terminated[0]), False, self._info(unstable[0])

    def render(self):
        if self.render_mode == "human":  # MuJoCo's interactive viewer, paced to render_fps
            if self._viewer is None:
                self._viewer = HumanViewer(
                    self.model, self.data, self._render_args["camera"], self.metadata["render_fps"]
                )
            self._viewer.sync(self.arena.hfield_ids, self.arena.version)
            return None
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = TrackRenderer(self.model, **self._render_args)
        for hfield in self.arena.hfield_ids:
            self._renderer.upload_hfield(hfield, self.arena.version)
        return self._renderer.render(self.data)

    def close(self):
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # ------------------------------------------------------------------ internals
    def _control_step(self, action: np.ndarray) -> None:
        self.act(action, self.physics)
        self.physics.step()

    def act(self, action: np.ndarray, physics) -> None:
        """Before `physics` (this env's own, or its row of a batch) steps: the rules' servos
        (`TrackRules.servo`), after their `before_physics` (Parkour: dead bodies play zeros) and the
        arena's forces (Parkour: grasps released, water)."""
        played = self.rules.before_physics(physics, action[None], self.rows)
        self.rules.servo(played, physics)

    def _info(self, unstable: bool) -> dict:
        info = {"success": bool(self.rows.success[0])}
        if unstable:
            info["unstable"] = True
        return info
