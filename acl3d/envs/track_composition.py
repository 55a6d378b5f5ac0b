"""Stump and Hexagon Tracks as compositions: a track arena (one heightfield) and the tracks' rules.

A composition is what tells envs apart: its task space and curriculum facts, which tasks its
generator can build, and the arena and rules it builds for a body (`TrackEnv` binds and steps
them; Parkour's composition is in acl3d.envs.parkour_env).
"""

from __future__ import annotations

from typing import NamedTuple

from acl3d import validation
from acl3d.bodies.base import Body
from acl3d.curriculum_profile import CurriculumProfile
from acl3d.envs.arena import TrackArena
from acl3d.envs.height_scan import HeightScan
from acl3d.envs.lidar import HeightLineLidar
from acl3d.envs.profiles import HEXAGON_TRACKS, STUMP_TRACKS
from acl3d.envs.track_rules import TrackRules
from acl3d.terrain.tracks import TrackGenerator, TrackGrid, check_buildable, track_task_space


class TrackKind(NamedTuple):
    """One kind of track: its default task parameters and its curriculum facts."""

    parameters: tuple[str, ...]
    profile: CurriculumProfile


OBSERVATIONS = ("lidar", "height_scan")  # the terrain sensor: 10 sagittal rays or a height scan

TRACKS = {
    "stump": TrackKind(("stump_height", "obstacle_spacing"), STUMP_TRACKS),
    "hexagon": TrackKind(("poly_shape",), HEXAGON_TRACKS),
}


class TrackComposition:
    """Stump or Hexagon Tracks: a `TrackArena` (one heightfield) and a `TrackRules`.

    A composition is what tells envs apart: its task space and curriculum facts, which tasks its
    generator can build, and the arena and rules it builds for a body.
    """

    def __init__(
        self, track: str, task_parameters: tuple[str, ...] | None, observation: str = "lidar"
    ):
        self.track = track
        self.observation = validation.choice("observation", observation, OBSERVATIONS)
        names = validation.optional_names(
            "task_parameters", task_parameters, "track parameter names"
        )
        self.task_space = track_task_space(TRACKS[track].parameters if names is None else names)
        self.profile = TRACKS[track].profile

    def check_buildable(self, task: dict) -> None:
        """Raise ValueError if the generator cannot build `task` (names the parameter and range)."""
        check_buildable(task)

    def build_arena(self, body: Body) -> TrackArena:
        return TrackArena(body, TrackGenerator(TrackGrid()))

    def build_rules(self, arena: TrackArena) -> TrackRules:
        if self.observation == "height_scan":
            sensor = HeightScan(arena)
        else:
            sensor = HeightLineLidar(arena, "down")
        return TrackRules(arena.bound, sensor, success_return=self.profile.success_return)

    def signature(self) -> str:
        """What a saved state must match beyond the body and model sizes (the sensor, if not
        the lidar)."""
        return "" if self.observation == "lidar" else f" observation={self.observation}"
