"""Parkour's arena: the track template with a ceiling, water and a pool of creepers.

The ground and the ceiling are two heightfields (the ceiling one turned upside down) whose
columns sit exactly on the terrain points (one every TS); water and creepers are geoms in their
own static bodies, moved and resized in the compiled model by `write_terrain`, so a new task
never recompiles.
"""

from __future__ import annotations

import mujoco
import numpy as np

from acl3d.bodies.base import Body
from acl3d.envs.arena import Arena, resize_hfield
from acl3d.envs.climbing import add_grasp_welds
from acl3d.terrain.parkour import ParkourGenerator, ParkourTerrain
from acl3d.terrain.tracks import TERRAIN_STEP, TrackGrid

GRID_MARGIN = 10  # heightfield columns (TS each) before x = 0 and after the last terrain point
GROUND_RANGE = (-60.0, 60.0)  # metres: what the ground heightfield can represent
CEILING_RANGE = (-60.0, 80.0)
CREEPER_HALF_DEPTH = 0.5  # creepers are 1 m deep across the track
PARKED_Z = -1000.0  # unused creepers wait here, invisible
MOVABLE_SEGMENTS = 4  # a movable creeper is a chain of 4 equal segments
SEGMENT_MASS = 5.0 * 0.25 * 1.0  # density 5 on a 0.25 x 1 m piece, as the original's pieces
SEGMENT_RANGE = 0.4 * np.pi  # joint limits between pieces
WATER_HALF_HEIGHT = 100.0
WATER_HALF_WIDTH = 1.98  # just inside the terrain faces (y = +-2), so they do not z-fight


class ParkourArena(Arena):
    """The Parkour template sized to the terrain grid, with a creeper pool and grasp welds."""

    def __init__(self, body: Body, generator: ParkourGenerator, movable_creepers: bool = False):
        self.generator = generator
        self.segments = MOVABLE_SEGMENTS if movable_creepers else 1
        n = generator.nb_points
        grid = TrackGrid(
            x_min=-GRID_MARGIN * TERRAIN_STEP,
            x_max=(n - 1 + GRID_MARGIN) * TERRAIN_STEP,
            ncol=n + 2 * GRID_MARGIN,
        )
        super().__init__(body, grid, template="arena/parkour.xml")
        m = self.model
        self.ceiling_id = m.hfield("ceiling").id
        self.ceiling_geom = m.geom("ceiling").id
        adr = m.hfield_adr[self.ceiling_id]
        self._ceiling = m.hfield_data[adr : adr + 2 * grid.ncol].reshape(2, grid.ncol)
        self.water_body = m.body("water").id
        names = [f"creeper{k}_{j}" for k in range(self._pool) for j in range(self.segments)]
        self.creeper_bodies = np.array([m.body(name).id for name in names])
        self.creeper_geoms = np.array([m.geom(name).id for name in names])
        self._creeper_rgba = m.geom_rgba[self.creeper_geoms[0]].copy()
        self.ceiling_heights = np.full(grid.ncol, CEILING_RANGE[1])
        self.nb_creeper_geoms = 0
        self.terrain: ParkourTerrain | None = None

    @property
    def hfield_ids(self) -> tuple[int, ...]:
        return (self.hfield_id, self.ceiling_id)

    def customise(self, spec: mujoco.MjSpec) -> None:
        centre_x = (self.grid.x_max + self.grid.x_min) / 2
        half_length = (self.grid.x_max - self.grid.x_min) / 2
        lo, hi = GROUND_RANGE
        resize_hfield(spec.hfield("terrain"), self.grid.ncol, [half_length, 2.0, hi - lo, 1.0])
        spec.geom("terrain").pos = [centre_x, 0.0, lo]
        lo, hi = CEILING_RANGE
        resize_hfield(spec.hfield("ceiling"), self.grid.ncol, [half_length, 2.0, hi - lo, 1.0])
        spec.geom("ceiling").pos = [centre_x, 0.0, hi]
        mid_z, half_z = (
            (CEILING_RANGE[1] + GROUND_RANGE[0]) / 2,
            (CEILING_RANGE[1] - GROUND_RANGE[0]) / 2,
        )
        for name in ("wall_left", "wall_right"):
            wall = spec.geom(name)
            wall.size = [half_length, wall.size[1], half_z]
            wall.pos = [centre_x, wall.pos[1], mid_z]
        spec.geom("water").size = [half_length, WATER_HALF_WIDTH, WATER_HALF_HEIGHT]
        spec.body("water").pos = [centre_x, 0.0, PARKED_Z]
        finish = spec.geom("finish_line")
        finish.pos = [self.generator.end_x, 0.0, mid_z]
        finish.size = [0.05, 2.0, half_z]
        self._pool = self.generator.max_creepers()
        for k in range(self._pool):
            self._add_creeper(spec, k)
        add_grasp_welds(spec, self.body.grasp_sensors)

    def _add_creeper(self, spec: mujoco.MjSpec, k: int) -> None:
        """Creeper k: one static box, or a chain of hinged segments (movable creepers).

        Geoms and inertial frames start off their body's origin so that moving them at reset
        is seen (MuJoCo skips the offset of geoms compiled at their body's origin).
        """
        parent = spec.worldbody
        for j in range(self.segments):
            pos = [0.0, 0.0, PARKED_Z] if j == 0 else [0.0, 0.0, -1.0]
            body = parent.add_body(name=f"creeper{k}_{j}", pos=pos)
            if self.segments > 1:
                body.add_joint(
                    name=f"creeper{k}_{j}",
                    type=mujoco.mjtJoint.mjJNT_HINGE,
                    axis=[0.0, 1.0, 0.0],
                    range=[-SEGMENT_RANGE, SEGMENT_RANGE],
                    limited=mujoco.mjtLimited.mjLIMITED_TRUE,
                )
                body.explicitinertial = True
                body.mass = SEGMENT_MASS
                body.ipos = [0.0, 0.0, -0.5]
                body.inertia = [SEGMENT_MASS / 12] * 3
            body.add_geom(
                name=f"creeper{k}_{j}",
                type=mujoco.mjtGeom.mjGEOM_BOX,
                pos=[0.0, 0.0, -0.5],
                size=[0.1, CREEPER_HALF_DEPTH, 0.5],
                contype=0,
                conaffinity=0,
                group=0,
                material="creeper",
            )
            parent = body

    def write_terrain(self, terrain: ParkourTerrain) -> None:
        """Ground, ceiling, water level and creepers of one episode, written in place."""
        self.terrain = terrain
        g = self.grid
        lo, hi = GROUND_RANGE
        self.heights = np.clip(np.interp(g.x, terrain.x, terrain.ground), lo, hi)
        self._hfield[:] = ((self.heights - lo) / (hi - lo))[None, :]
        lo, hi = CEILING_RANGE
        self.ceiling_heights = np.clip(np.interp(g.x, terrain.x, terrain.ceiling), lo, hi)
        self._ceiling[:] = ((hi - self.ceiling_heights) / (hi - lo))[None, :]
        m = self.model
        m.body_pos[self.water_body, 2] = terrain.water_z - WATER_HALF_HEIGHT
        self._place_creepers(terrain.creepers)
        self.version += 1

    def _place_creepers(self, creepers: np.ndarray) -> None:
        """Hang the first creepers of the pool (K equal segments each); park the others."""
        m, n, k = self.model, len(creepers), self.segments
        bodies, geoms = self.creeper_bodies.reshape(-1, k), self.creeper_geoms.reshape(-1, k)
        piece = (creepers[:, 2] - creepers[:, 3]) / k  # segment length
        half = np.empty((n, k, 3))
        half[..., 0] = ((creepers[:, 1] - creepers[:, 0]) / 2)[:, None]
        half[..., 1] = CREEPER_HALF_DEPTH
        half[..., 2] = (piece / 2)[:, None]
        m.body_pos[bodies[:n, 0]] = np.column_stack(
            ((creepers[:, 0] + creepers[:, 1]) / 2, np.zeros(n), creepers[:, 2])
        )
        m.body_pos[bodies[:n, 1:], 2] = -piece[:, None]
        m.body_ipos[bodies[:n], 2] = -half[..., 2]
        m.geom_pos[geoms[:n], 2] = -half[..., 2]
        used = geoms[:n].ravel()
        m.geom_size[used] = half.reshape(-1, 3)
        m.geom_aabb[used, 3:] = half.reshape(-1, 3)
        m.geom_rbound[used] = np.linalg.norm(half.reshape(-1, 3), axis=1)
        m.geom_rgba[used] = self._creeper_rgba
        m.body_pos[bodies[n:, 0]] = (0.0, 0.0, PARKED_Z)
        m.geom_rgba[geoms[n:].ravel(), 3] = 0.0  # invisible to renderers and rays
        self.nb_creeper_geoms = used.size
