"""3D Terrain: a field whose obstacles, slopes and roughness vary across it as well as along it.

`gymnasium.make("acl3d/Terrain3D-v0", body=...)`. The env is the track core (`TrackEnv`)
composed with the field's arena (`acl3d.envs.terrain3d_arena`: one 2D heightfield, rewritten in
place at every reset) and its rules (`acl3d.envs.terrain3d_rules`: progress, heading and drift,
leaving the field fails, crossing succeeds). The terrain and its task space are in
`acl3d.terrain.terrain3d`; `docs/terrain3d.md` describes the family.
"""

from __future__ import annotations

from collections.abc import Mapping

from acl3d import validation
from acl3d.bodies.base import Body
from acl3d.envs.profiles import TERRAIN3D
from acl3d.envs.terrain3d_arena import Terrain3DArena
from acl3d.envs.terrain3d_rules import Terrain3DRules, make_sensor
from acl3d.envs.track_composition import OBSERVATIONS
from acl3d.envs.track_env import TrackEnv
from acl3d.terrain.terrain3d import (
    CELL,
    ROW_CELL,
    Terrain3DGenerator,
    check_buildable,
    grid_spacing,
    start_pad_for,
    terrain3d_task_space,
)


class Terrain3DEnv(TrackEnv):
    """A 6 m wide, ~30 m long 3D field; any body crosses it (default: big_quadru, free 3D).

    Args:
        body, planar, body_options, frame_skip, render_mode, width, height, camera, quality:
            as for the tracks (`acl3d.envs.track_env.TrackEnv`).
        task_parameters: which terrain parameters form the task space (default: all six of
            `acl3d.terrain.terrain3d.TERRAIN3D_PARAMETERS`); the others keep their defaults.
        observation: the terrain sensor: "height_scan" (63 heights around the body in its
            heading frame, `acl3d.envs.height_scan`) or "lidar" (10 sagittal rays).
        grid_spacing: metres between the heightfield's points, along x then across (default
            (0.1, 0.5)). A coarser grid collides faster (on a GPU, where collision is most of a
            step) and turns blocks into wedges; (0.1, 0.2) keeps narrow blocks' sides steep at
            ~0.7x the GPU speed: docs/terrain3d.md.
    """

    def __init__(
        self,
        body: str | Body = "big_quadru",
        planar: bool | None = None,
        task_parameters: tuple[str, ...] | None = None,
        observation: str = "height_scan",
        body_options: Mapping | None = None,
        frame_skip: int | None = None,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        camera: str | None = None,
        quality: str = "fast",
        grid_spacing: tuple[float, float] = (CELL, ROW_CELL),
    ):
        self._compose(
            Terrain3DComposition(task_parameters, observation, grid_spacing),
            body,
            planar,
            body_options,
            frame_skip,
            render_mode,
            dict(width=width, height=height, camera=camera, quality=quality),
        )
        self.observation = observation


class Terrain3DComposition:
    """The field's arena (one 2D heightfield) and rules (progress, heading, drift, crossing)."""

    track = "terrain3d"

    def __init__(self, task_parameters, observation: str, spacing=(CELL, ROW_CELL)):
        names = validation.optional_names(
            "task_parameters", task_parameters, "terrain parameter names"
        )
        self.task_space = terrain3d_task_space(names)
        self.observation = validation.choice("observation", observation, OBSERVATIONS)
        self.spacing = grid_spacing(spacing)
        self.profile = TERRAIN3D

    def check_buildable(self, task: dict) -> None:
        check_buildable(task)

    def build_arena(self, body: Body) -> Terrain3DArena:
        generator = Terrain3DGenerator(start_pad_for(body.length), *self.spacing)
        return Terrain3DArena(body, generator)

    def build_rules(self, arena: Terrain3DArena) -> Terrain3DRules:
        sensor = make_sensor(self.observation, arena)
        return Terrain3DRules(arena.bound, sensor, arena.grid.half_width, arena.generator.end_x)

    def signature(self) -> str:
        grid = "" if self.spacing == (CELL, ROW_CELL) else f", grid_spacing={self.spacing}"
        return f" observation={self.observation}{grid}"
