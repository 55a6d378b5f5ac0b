"""TeachMyAgent's Parkour in 3D: CPPN ground and ceiling, water, creepers, climbing; any body.

`gymnasium.make("acl3d/Parkour-v0", body=...)`. The env is the track core (`TrackEnv`)
composed with Parkour's arena (`acl3d.envs.parkour_arena`: ground and ceiling heightfields,
water, creepers, grasp welds; rewritten in place at every reset, so a new task never recompiles)
and Parkour's rules (`acl3d.envs.parkour_rules`: survival, surface-typed lidars).

Walkers start on the start pad, the fish 1 m higher with no push, climbers hang from the
start-pad ceiling (placed with their highest hand at it, then 5 + 1 steps with the grasp actions
at +1, as the original). Options: `input_space` ("medium", "easy", "full"), `lidars_type`
("down", "up", "full"; default per body kind), `end_on_death`, `water_clip`, `movable_creepers`.
"""

from __future__ import annotations

from collections.abc import Mapping

from acl3d import validation
from acl3d.bodies.base import Body
from acl3d.curriculum_profile import CurriculumProfile
from acl3d.envs.climbing import Climbing
from acl3d.envs.lidar import LIDAR_TYPES
from acl3d.envs.parkour_arena import ParkourArena
from acl3d.envs.parkour_lidar import ParkourLidar
from acl3d.envs.parkour_rules import DEFAULT_LIDARS, ParkourRules
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
        composition = ParkourComposition(
            input_space, lidars_type, end_on_death, water_clip, movable_creepers
        )
        self._compose(
            composition,
            body,
            planar,
            body_options,
            frame_skip,
            render_mode,
            dict(width=width, height=height, camera=camera, quality=quality),
        )
        self.input_space = input_space
        self.end_on_death = composition.end_on_death
        self.movable_creepers = composition.movable_creepers

    @property
    def terrain(self) -> ParkourTerrain | None:
        """This episode's terrain (ground, ceiling, water level, creepers); None before a reset."""
        return self.arena.terrain

    @property
    def water(self) -> Water:
        return self.arena.water

    @property
    def climbing(self) -> Climbing | None:
        """The climbers' grasp state (None for other bodies)."""
        return self.arena.climbing


class ParkourComposition:
    """Parkour's arena (ground, ceiling, water, creepers) and rules (survival, typed lidars)."""

    track = "stump"  # what ParkourEnv's saved-state signature has always said

    def __init__(self, input_space, lidars_type, end_on_death, water_clip, movable_creepers):
        validation.choice("input_space", input_space, list(INPUT_SPACES))
        validation.choice("lidars_type", lidars_type, [None, *LIDAR_TYPES])
        self.input_space = input_space
        self.end_on_death = validation.flag("end_on_death", end_on_death)
        self.lidars_type = lidars_type
        self.water_clip = validation.real("water_clip", water_clip, 0.0)
        self.movable_creepers = validation.flag("movable_creepers", movable_creepers)
        self.task_space: TaskSpace = parkour_task_space(input_space)
        self.profile: CurriculumProfile = PARKOUR
        self._lidar = ""

    def check_buildable(self, task: dict) -> None:
        check_buildable(task)

    def build_arena(self, body: Body) -> ParkourArena:
        generator = ParkourGenerator(start_pad_for(body.length))
        return ParkourArena(body, generator, self.movable_creepers, self.water_clip)

    def build_rules(self, arena: ParkourArena) -> ParkourRules:
        self._lidar = self.lidars_type or DEFAULT_LIDARS[arena.body.kind]
        return ParkourRules(
            arena.bound,
            ParkourLidar(self._lidar, arena),
            arena,
            arena.generator.end_x,
            self.profile.success_return,
            self.end_on_death,
        )

    def signature(self) -> str:
        return (
            f" input_space={self.input_space}, lidars={self._lidar}, "
            f"end_on_death={self.end_on_death}, water_clip={self.water_clip!r}, "
            f"movable_creepers={self.movable_creepers}"
        )
