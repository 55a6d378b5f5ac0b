"""The arena: the MJCF track template, sized to the terrain grid, with a body attached at spawn.

An env is composed of a body, an arena and its rules (dm_control's locomotion calls them the
task; in acl3d a task is the parameter vector a teacher picks): the arena owns
the terrain generator and everything it writes per episode (`regenerate(task, rng)`), where the
body starts (`place_body`) and the per-episode world state of exact snapshots.
Topology (which body, which track kind) is fixed when the model is compiled; shape (terrain
heights) is written into the compiled model in place each episode, so a new task never recompiles.
Each env compiles its own model: models hold per-env state (heights, actuator torque caps).
"""

from __future__ import annotations

import mujoco
import numpy as np

from acl3d.assets import mjcf_path
from acl3d.bodies.base import PREFIX, Body, BoundBody
from acl3d.envs import env_state
from acl3d.envs.track_rules import touch_sensor_name
from acl3d.terrain.tracks import (
    MAX_TERRAIN_HEIGHT,
    TERRAIN_STEP,
    TrackGenerator,
    TrackGrid,
    start_pad_for,
)

TRACK_HALF_WIDTH = 2.0  # metres: walls at +-2 m keep full-3D bodies on the track
HFIELD_BASE_DEPTH = 1.0
CONTROL_DT = 1 / 50  # 50 Hz control, as the original
INIT_PUSH = 5.0  # the original pushes the hull once with a horizontal force U(-5, 5)


def resize_hfield(hfield: mujoco.MjsHField, ncol: int, size) -> None:
    """Give a template heightfield `ncol` x 2 flat cells of `size`.

    The template's own elevation data (its XML size) must go too: MuJoCo refuses data whose
    length is not nrow * ncol, which broke grids of another width (e.g. long millipedes).
    """
    hfield.ncol, hfield.nrow = ncol, 2
    hfield.size = size
    hfield.userdata = np.zeros(2 * ncol)


def attach_body(spec: mujoco.MjSpec, body: Body, start_x: float, camera_distance: float) -> None:
    """Attach `body` at its spawn point (start_x, 0, spawn height) with a camera following it
    and the touch sensors its rules read."""
    body_spec = body.spec()
    body_spec.body(body.root).add_camera(
        name="track",
        mode=mujoco.mjtCamLight.mjCAMLIGHT_TRACKCOM,
        pos=[2.0, -camera_distance, 2.5],
        xyaxes=[1, 0, 0, 0, 0.3, 1],
    )
    frame = spec.worldbody.add_frame(pos=[start_x, 0.0, body.spawn_height])
    spec.attach(body_spec, prefix=PREFIX, frame=frame)
    add_touch_sensors(spec, body)


def add_touch_sensors(spec: mujoco.MjSpec, body: Body, against: str | None = None) -> None:
    """A contact sensor (number of contacts found) per geom whose contacts the rules read: the
    motors' contact-flag geoms and the critical geoms, touching anything; with `against` (a
    geom name), the critical geoms' contacts with that geom only (Parkour's ceiling). Sensors
    are part of every backend's derived fields (`sensordata`), where MjData's contact list is
    not."""
    if against is None:
        geoms = [m.contact_geom for m in body.motors if m.contact_geom]
        geoms += list(body.critical_geoms)
    else:
        geoms = list(body.critical_geoms)
    for geom in dict.fromkeys(geoms):
        sensor = spec.add_sensor(
            name=touch_sensor_name(PREFIX + geom, against),
            type=mujoco.mjtSensor.mjSENS_CONTACT,
            objtype=mujoco.mjtObj.mjOBJ_GEOM,
            objname=PREFIX + geom,
        )
        if against is not None:
            sensor.reftype, sensor.refname = mujoco.mjtObj.mjOBJ_GEOM, against
        sensor.intprm[:3] = [1 << int(mujoco.mjtConDataField.mjCONDATA_FOUND), 0, 1]


class Arena:
    """Compiled track model + the in-place terrain writer."""

    def __init__(
        self,
        body: Body,
        grid: TrackGrid,
        template: str = "arena/track.xml",
        camera_distance: float = 10.0,
    ):
        self.body = body
        self.grid = grid
        self.start_pad = start_pad_for(body.length)  # in TS; bodies spawn at its middle
        self.start_x = TERRAIN_STEP * self.start_pad / 2
        spec = mujoco.MjSpec.from_file(str(mjcf_path(template)))
        half_length = (grid.x_max - grid.x_min) / 2
        centre_x = (grid.x_max + grid.x_min) / 2
        resize_hfield(
            spec.hfield("terrain"),
            grid.ncol,
            [half_length, TRACK_HALF_WIDTH, MAX_TERRAIN_HEIGHT, HFIELD_BASE_DEPTH],
        )
        spec.geom("terrain").pos = [centre_x, 0.0, 0.0]
        for name, side in (("wall_left", 1), ("wall_right", -1)):
            wall = spec.geom(name)
            wall.size = [half_length, 0.05, wall.size[2]]
            wall.pos = [centre_x, side * (TRACK_HALF_WIDTH + 0.05), wall.size[2]]
        self.customise(spec)
        attach_body(spec, body, self.start_x, camera_distance)
        self.spec = spec
        self.model = spec.compile()
        self.bound = BoundBody(body, self.model)
        self.hfield_id = self.model.hfield("terrain").id
        adr, n = self.model.hfield_adr[self.hfield_id], grid.ncol * 2
        self._hfield = self.model.hfield_data[adr : adr + n].reshape(2, grid.ncol)
        self.heights = np.zeros(grid.ncol)
        self.version = 0
        self.camera = PREFIX + "track"

    @property
    def hfield_ids(self) -> tuple[int, ...]:
        """Heightfields rewritten per episode (re-uploaded to a renderer when `version` changes)."""
        return (self.hfield_id,)

    def customise(self, spec: mujoco.MjSpec) -> None:
        """Hook for arenas that add to the track template before compiling (e.g. Parkour)."""

    def write_heights(self, heights: np.ndarray) -> None:
        """Write the height line (metres above the flat ground) into the compiled heightfield."""
        self.heights = heights
        self._hfield[:] = np.clip(heights / MAX_TERRAIN_HEIGHT, 0.0, 1.0)[None, :]
        self.version += 1

    def ground_height(self, x: float) -> float:
        return float(np.interp(x, self.grid.x, self.heights))

    def place_body(self, data: mujoco.MjData, rng: np.random.Generator) -> None:
        """Spawn at the start pad's middle; the push is drawn for every body (same RNG stream)."""
        self.bound.place(data, self.start_x, self.body.spawn_height)
        push = rng.uniform(-INIT_PUSH, INIT_PUSH)
        if not self.body.initial_push:  # the original never pushes the fish
            return
        # the one-off horizontal force of the original, as the velocity change it gives in one step
        data.qvel[self.bound.root_dof] = push * CONTROL_DT / self.bound.total_mass

    def settle(self, data: mujoco.MjData, control_step) -> None:
        """Steps after the reset's idle step, before the first observation (none on a track)."""

    # ------------------------------------------------------------------ exact snapshots
    def episode_state(self) -> dict:
        """The per-episode world: the height line."""
        return {"terrain/heights": self.heights.copy()}

    def check_episode_state(self, state) -> dict:
        env_state.check_keys(state, ("terrain/heights",))
        return {"heights": env_state.array(state, "terrain/heights", self.heights)}

    def set_episode_state(self, checked: dict, data: mujoco.MjData) -> None:
        self.write_heights(checked["heights"])


class TrackArena(Arena):
    """Stump and Hexagon Tracks: one heightfield written from a `TrackGenerator` height line."""

    def __init__(self, body: Body, generator: TrackGenerator):
        self.generator = generator
        super().__init__(body, generator.grid)

    def regenerate(self, task: dict, rng: np.random.Generator) -> None:
        """This episode's terrain for `task`, drawn from `rng`, written in place."""
        self.write_heights(self.generator.heights(task, rng, self.start_pad))
