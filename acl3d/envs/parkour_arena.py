"""Parkour's arena: the track template with a ceiling, water and a pool of creepers.

The ground and the ceiling are two heightfields (the ceiling one turned upside down) whose
columns sit exactly on the terrain points (one every TS); water and creepers are geoms in their
own static bodies, moved and resized in the compiled model by `write_terrain`, so a new task
never recompiles. The arena also owns the water's forces and, for climbers, the grasp welds
(`Climbing`): climbers start hanging from the start-pad ceiling (placed with their highest hand
at it, then 5 + 1 steps with the grasp actions at +1, as the original).
"""

from __future__ import annotations

import mujoco
import numpy as np

from acl3d import validation
from acl3d.bodies.base import Body
from acl3d.envs import env_state
from acl3d.envs.arena import Arena, add_touch_sensors, resize_hfield
from acl3d.envs.climbing import Climbing, add_grasp_welds
from acl3d.envs.water import PUSH_CLIP, Water
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
HANG_STEPS = 6  # 5 + 1 steps with the grasp actions at +1 at reset
TERRAIN_KEYS = ("terrain/ground", "terrain/ceiling", "terrain/creepers", "terrain/water_z")
GRASP = ("ready", "holding", "touching")  # Climbing's per-hand flags


class ParkourArena(Arena):
    """The Parkour template sized to the terrain grid, with a creeper pool and grasp welds."""

    def __init__(
        self,
        body: Body,
        generator: ParkourGenerator,
        movable_creepers: bool = False,
        water_clip: float = PUSH_CLIP,
    ):
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
        # this episode's creeper boxes, padded to the pool: half sizes and bounding radii
        self.creeper_size = np.zeros((len(self.creeper_geoms), 3))
        self.creeper_rbound = np.zeros(len(self.creeper_geoms))
        self.terrain: ParkourTerrain | None = None
        self.water = Water(m, self.bound.body_geom_ids, push_clip=water_clip)
        sensors = body.grasp_sensors
        self.climbing = Climbing(m, sensors, self.creeper_geoms) if sensors else None
        self._nb_grasp = len(sensors)

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
        add_touch_sensors(spec, self.body, against="ceiling")

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
        self.creeper_size[:] = self.creeper_rbound[:] = 0.0
        self.creeper_size[: used.size] = m.geom_size[used]
        self.creeper_rbound[: used.size] = m.geom_rbound[used]

    # ------------------------------------------------------------------ episodes
    def regenerate(self, task: dict, rng: np.random.Generator) -> None:
        """This episode's terrain for `task`, drawn from `rng`, written in place."""
        self.use_terrain(self.generator.generate(task, rng))

    def use_terrain(self, terrain: ParkourTerrain) -> None:
        self.write_terrain(terrain)
        self.water.level = terrain.water_z

    def place_body(self, data: mujoco.MjData, rng: np.random.Generator) -> None:
        """Walkers as on a track; the fish 1 m higher (in its spawn height) with no push and no
        push drawn (as recorded); climbers lifted to hang from the start-pad ceiling."""
        if self.body.initial_push:
            super().place_body(data, rng)
        else:
            self.bound.place(data, self.start_x, self.body.spawn_height)
        self.water.clear(data)
        if self.climbing:
            self.climbing.reset(data, self)
            self._lift_to_ceiling(data)

    def _lift_to_ceiling(self, data: mujoco.MjData) -> None:
        """Lift the climber so that its highest hand touches the start-pad ceiling."""
        mujoco.mj_kinematics(self.model, data)
        c = self.climbing
        tops = data.geom_xpos[c.geom_ids, 2] + c.radius
        lift = self.terrain.ceiling[0] - tops.max()
        data.qpos[self.bound.root_qpos + (1 if self.body.planar else 2)] += lift

    def settle(self, data: mujoco.MjData, control_step) -> None:
        """Climbers grasp the ceiling: HANG_STEPS control steps with the grasp actions at +1."""
        if not self.climbing:
            return
        grasp = np.zeros(self.body.action_size)
        grasp[-self._nb_grasp :] = 1.0
        for _ in range(HANG_STEPS):
            control_step(grasp)
            self.climbing.after_step(data)

    # ------------------------------------------------------------------ exact snapshots
    def episode_state(self) -> dict:
        """Terrain (ground, ceiling, water level, creepers), water and grasp state."""
        t = self.terrain
        state = {
            "terrain/ground": t.ground.copy(),
            "terrain/ceiling": t.ceiling.copy(),
            "terrain/creepers": t.creepers.copy(),
            "terrain/water_z": float(t.water_z),
            "water/wet": self.water.wet,
        }
        for key in GRASP if self.climbing else ():
            state[f"climbing/{key}"] = getattr(self.climbing, key).copy()
        return state

    def check_episode_state(self, state) -> dict:
        grasp = [f"climbing/{key}" for key in GRASP] if self.climbing else []
        env_state.check_keys(state, (*TERRAIN_KEYS, "water/wet", *grasp))
        creepers = np.asarray(state["terrain/creepers"])
        pool = len(self.creeper_bodies) // self.segments
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
        line = np.zeros(self.generator.nb_points)
        checked = {
            "ground": env_state.array(state, "terrain/ground", line),
            "ceiling": env_state.array(state, "terrain/ceiling", line),
            "creepers": creepers.astype(np.float64),
            "water_z": env_state.scalar(state, "terrain/water_z", "real"),
            "wet": env_state.scalar(state, "water/wet", "flag"),
        }
        for key in GRASP if self.climbing else ():
            checked[key] = env_state.array(state, f"climbing/{key}", getattr(self.climbing, key))
        return checked

    def set_episode_state(self, c: dict, data: mujoco.MjData) -> None:
        g = self.generator
        self.use_terrain(
            ParkourTerrain(g.x, c["ground"], c["ceiling"], c["water_z"], c["creepers"])
        )
        self.water.wet = c["wet"]
        if self.climbing:  # welds: eq_active comes back with the physics
            self.climbing.reset(data, self)
            for key in GRASP:
                setattr(self.climbing, key, c[key])
