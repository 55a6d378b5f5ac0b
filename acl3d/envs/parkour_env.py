"""TeachMyAgent's Parkour in 3D: CPPN ground and ceiling, water, creepers, climbing; any body.

`gymnasium.make("acl3d/Parkour-v0", body=...)`. The arena (`acl3d.envs.parkour_arena`: ground
and ceiling heightfields, water, creepers) is rewritten in place at every reset, so a new task
never recompiles.

Walkers start on the start pad, the fish 1 m higher with no push, climbers hang from the
start-pad ceiling (placed with their highest hand at it, then 5 + 1 steps with the grasp actions
at +1, as the original). Options: `input_space` ("medium", "easy", "full"), `lidars_type`
("down", "up", "full"; default per body kind), `end_on_death`, `water_clip`, `movable_creepers`.
"""

from __future__ import annotations

from collections.abc import Mapping

import mujoco
import numpy as np

from acl3d import validation
from acl3d.bodies.base import Body
from acl3d.curriculum_profile import CurriculumProfile
from acl3d.envs import env_state
from acl3d.envs.climbing import Climbing
from acl3d.envs.lidar import LIDAR_TYPES
from acl3d.envs.parkour_arena import ParkourArena
from acl3d.envs.parkour_task import DEFAULT_LIDARS, ParkourLidar, ParkourTask
from acl3d.envs.profiles import PARKOUR
from acl3d.envs.track_env import TrackEnv
from acl3d.envs.water import PUSH_CLIP, Water
from acl3d.task_space import TaskSpace
from acl3d.terrain.parkour import (
    INPUT_SPACES,
    ParkourGenerator,
    ParkourTerrain,
    check_buildable,
    parkour_task_space,
)
from acl3d.terrain.tracks import start_pad_for

HANG_STEPS = 6  # 5 + 1 steps with the grasp actions at +1 at reset
_SURVIVAL = ("steps_under_water", "steps_out_of_water", "dead", "under_water")  # ParkourTask's
_GRASP = ("ready", "holding", "touching")  # Climbing's per-hand flags


class ParkourEnv(TrackEnv):
    """Parkour with any body: task = CPPN input (3), water level, creepers (3), CPPN scale.

    Args:
        body, planar, body_options, frame_skip, render_mode, width, height, camera, quality:
            as for the tracks (`acl3d.envs.track_env.TrackEnv`).
        input_space: bounds of the CPPN input in the task space: "medium" (benchmark), "easy",
            "full" ([-1, 1]^3).
        lidars_type: "down", "up" or "full"; default: down for walkers and amphibians, up for
            climbers, full for swimmers.
        end_on_death: end the episode when the body drowns or suffocates (default: it keeps
            running with zero actions and the dead flag up, as the original).
        water_clip: the clip of the swimming thrust per force component (the original's 20).
        movable_creepers: creepers are chains of 4 hinged segments (limits +-0.4 pi) that swing
            and can be pulled; default: static boxes (the benchmark).
    """

    def __init__(
        self,
        body: str | Body = "classic_bipedal",
        planar: bool | None = None,
        body_options: Mapping | None = None,
        input_space: str = "medium",
        lidars_type: str | None = None,
        end_on_death: bool = False,
        water_clip: float = PUSH_CLIP,
        movable_creepers: bool = False,
        frame_skip: int | None = None,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        camera: str | None = None,
        quality: str = "fast",
    ):
        validation.choice("input_space", input_space, list(INPUT_SPACES))
        validation.choice("lidars_type", lidars_type, [None, *LIDAR_TYPES])
        self.input_space = input_space
        self.end_on_death = validation.flag("end_on_death", end_on_death)
        self._lidars_type = lidars_type
        self._water_clip = validation.real("water_clip", water_clip, 0.0)
        self.movable_creepers = validation.flag("movable_creepers", movable_creepers)
        super().__init__(
            track="stump",
            body=body,
            planar=planar,
            body_options=body_options,
            frame_skip=frame_skip,
            render_mode=render_mode,
            width=width,
            height=height,
            camera=camera,
            quality=quality,
        )
        self._zero_action = np.zeros(self.body.action_size)
        self._nb_grasp = len(self.body.grasp_sensors)
        self.terrain: ParkourTerrain | None = None

    # ------------------------------------------------------------------ construction hooks
    def _make_task_space(self, task_parameters) -> TaskSpace:
        return parkour_task_space(self.input_space)

    @property
    def curriculum_profile(self) -> CurriculumProfile:
        """What a curriculum needs to know about Parkour (reward bounds, named test sets)."""
        return PARKOUR

    def _make_generator(self) -> ParkourGenerator:
        return ParkourGenerator(start_pad_for(self.body.length))

    def _check_buildable(self, task: dict) -> None:
        check_buildable(task)

    def _build_arena(self) -> ParkourArena:
        return ParkourArena(self.body, self.generator, self.movable_creepers)

    def _make_task(self) -> ParkourTask:
        arena, model = self.arena, self.model
        self.water = Water(model, self.bound.body_geom_ids, push_clip=self._water_clip)
        self.climbing = (
            Climbing(model, self.body.grasp_sensors, arena.creeper_geoms)
            if self.body.grasp_sensors
            else None
        )
        kind = self._lidars_type or DEFAULT_LIDARS[self.body.kind]
        lidar = ParkourLidar(kind, arena)
        return ParkourTask(
            self.bound,
            lidar,
            self.water,
            self.climbing,
            arena.ceiling_geom,
            self.generator.end_x,
            self.end_on_death,
        )

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = super().reset(seed=seed, options=options)
        if self.climbing:
            grasp = np.zeros(self.body.action_size)
            grasp[-self._nb_grasp :] = 1.0
            for _ in range(HANG_STEPS):
                self._apply_action(grasp)
                self.physics.step()
                self.climbing.after_step(self.data)
            obs = self.task.reset(self.model, self.data)
        return obs, info

    # ------------------------------------------------------------------ internals
    def _new_terrain(self) -> None:
        self._use_terrain(self.generator.generate(self.get_task(), self.np_random))
        self.task.reset_survival()

    def _use_terrain(self, terrain: ParkourTerrain) -> None:
        self.terrain = terrain
        self.arena.write_terrain(terrain)
        self.water.level = terrain.water_z
        self.task.lidar.water_level = terrain.water_z

    # ------------------------------------------------------------------ exact snapshots
    def _signature(self) -> str:
        return (
            f"{super()._signature()} input_space={self.input_space}, "
            f"lidars={self.task.lidar.kind}, end_on_death={self.end_on_death}, "
            f"water_clip={self._water_clip!r}, movable_creepers={self.movable_creepers}"
        )

    def _episode_state(self) -> dict:
        """Terrain (ground, ceiling, water level, creepers), water, survival and grasp state."""
        t, task = self.terrain, self.task
        state = {
            "terrain/ground": t.ground.copy(),
            "terrain/ceiling": t.ceiling.copy(),
            "terrain/creepers": t.creepers.copy(),
            "terrain/water_z": float(t.water_z),
            "water/wet": self.water.wet,
            **{f"survival/{key}": getattr(task, key) for key in _SURVIVAL},
        }
        if self.climbing:
            for key in _GRASP:
                state[f"climbing/{key}"] = getattr(self.climbing, key).copy()
        return state

    def _check_episode_state(self, state) -> dict:
        grasp = [f"climbing/{key}" for key in _GRASP] if self.climbing else []
        terrain = ("terrain/ground", "terrain/ceiling", "terrain/creepers", "terrain/water_z")
        survival = [f"survival/{key}" for key in _SURVIVAL]
        env_state.check_keys(state, (*terrain, "water/wet", *survival, *grasp))
        creepers = np.asarray(state["terrain/creepers"])
        pool = len(self.arena.creeper_bodies) // self.arena.segments
        if (
            creepers.dtype.kind != "f"
            or creepers.ndim != 2
            or creepers.shape[1] != 4
            or len(creepers) > pool
            or not np.all(np.isfinite(creepers))
        ):
            raise validation.fail(
                "state['terrain/creepers']", creepers, f"a finite (k <= {pool}, 4) float array"
            )
        profile = np.zeros(self.generator.nb_points)
        checked = {
            "ground": env_state.array(state, "terrain/ground", profile),
            "ceiling": env_state.array(state, "terrain/ceiling", profile),
            "creepers": creepers.astype(np.float64),
            "water_z": env_state.scalar(state, "terrain/water_z", "real"),
            "wet": env_state.scalar(state, "water/wet", "flag"),
        }
        for key in _SURVIVAL:
            kind = "integer" if key.startswith("steps") else "flag"
            checked[key] = env_state.scalar(state, f"survival/{key}", kind, 0)
        for key in _GRASP if self.climbing else ():
            checked[key] = env_state.array(state, f"climbing/{key}", getattr(self.climbing, key))
        return checked

    def _set_episode_state(self, c: dict) -> None:
        terrain = ParkourTerrain(
            self.generator.x, c["ground"], c["ceiling"], c["water_z"], c["creepers"]
        )
        self._use_terrain(terrain)
        self.water.wet = c["wet"]
        for key in _SURVIVAL:
            setattr(self.task, key, c[key])
        if self.climbing:  # welds: eq_active comes back with the physics
            self.climbing.reset(self.data, terrain, self.arena.nb_creeper_geoms)
            for key in _GRASP:
                setattr(self.climbing, key, c[key])

    def _place_body(self) -> None:
        if self.body.initial_push:
            super()._place_body()
        else:  # the fish: no push (its spawn height already includes the original's +1 m)
            self.bound.place(self.data, self.arena.start_x, self.body.spawn_height)
        self.water.clear(self.data)
        if self.climbing:
            self.climbing.reset(self.data, self.terrain, self.arena.nb_creeper_geoms)
            self._hang_from_ceiling()

    def _hang_from_ceiling(self) -> None:
        """Lift the climber so that its highest hand touches the start-pad ceiling."""
        mujoco.mj_kinematics(self.model, self.data)
        c = self.climbing
        tops = self.data.geom_xpos[c.geom_ids, 2] + c.radius
        lift = self.terrain.ceiling[0] - tops.max()
        z_index = self.bound.root_qpos + (1 if self.body.planar else 2)
        self.data.qpos[z_index] += lift

    def _apply_action(self, action: np.ndarray) -> None:
        """Dead bodies play zeros; grasps are released first; water forces for this step."""
        played = self._zero_action if self.task.dead else action
        if self.climbing:
            self.climbing.before_step(self.data, played[-self._nb_grasp :])
        self.water.apply(self.data)
        super()._apply_action(played)
