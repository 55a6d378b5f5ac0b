"""3D Terrain's arena: the track template with one 2D heightfield and no side walls.

The heightfield's rows run across the field (y) and its columns along it (x); every episode's
heights are written into the compiled model in place (`regenerate`), so a new task never
recompiles. The field is `2 * FIELD_HALF_WIDTH` m wide: the rules end an episode whose body
leaves it, so no walls hold bodies in.
"""

from __future__ import annotations

import mujoco
import numpy as np

from acl3d.assets import mjcf_path
from acl3d.bodies.base import PREFIX, Body, BoundBody
from acl3d.envs.arena import HFIELD_BASE_DEPTH, Arena, attach_body
from acl3d.terrain.terrain3d import HEIGHT_RANGE, Terrain3DGenerator

# The tracking camera looks down on the field from behind and beside the body (offsets from its
# centre of mass, metres), so slopes, twist and blocks read as relief, not as a side profile.
CAMERA_OFFSET = (-6.0, -11.0, 7.0)
CAMERA_TARGET = (4.0, 0.0, -1.0)
GROUND_SQUARE = 1.0  # metres: the side of one square of the ground's checker
SUN_DIRECTION = (0.3, 0.6, -1.0)  # shadows fall ahead and away from the camera, beside the body
SHADOW_REACH = 12.0  # metres around the walker where shadows are drawn
# The grass around the field (drawn only, group 2) lies just below the lowest ground of the
# benchmark bounds (25 deg of twist at 3 m and 0.3 m bumps: -1.7 m), so the heightfield's sides
# show a few metres at most instead of its full depth below HEIGHT_RANGE's floor.
SCENERY_HEIGHT = -2.0


class Terrain3DArena(Arena):
    """The field's compiled model and its in-place heightfield writer (`heights`: (rows, cols))."""

    def __init__(self, body: Body, generator: Terrain3DGenerator):
        self.body = body
        self.generator = generator
        self.grid = g = generator.grid
        self.start_x = generator.start_pad / 2
        spec = mujoco.MjSpec.from_file(str(mjcf_path("arena/track.xml")))
        for wall in ("wall_left", "wall_right"):
            spec.delete(spec.geom(wall))
        lo, hi = HEIGHT_RANGE
        half_length, centre_x = (g.x_max - g.x_min) / 2, (g.x_max + g.x_min) / 2
        hfield = spec.hfield("terrain")
        hfield.nrow, hfield.ncol = g.nrow, g.ncol
        hfield.size = [half_length, g.half_width, hi - lo, HFIELD_BASE_DEPTH]
        hfield.userdata = np.zeros(g.nrow * g.ncol)
        spec.geom("terrain").pos = [centre_x, 0.0, lo]
        spec.geom("scenery").pos = [centre_x, 0.0, SCENERY_HEIGHT]
        finish = spec.geom("finish_line")
        finish.pos = [generator.end_x, 0.0, 0.01]
        finish.size = [0.05, g.half_width, 0.01]
        _lighting(spec, half_length, g.half_width)
        attach_body(spec, body, self.start_x, camera_distance=-CAMERA_OFFSET[1])
        camera = spec.camera(PREFIX + "track")  # the tracks' side view, turned to look down
        camera.pos, camera.alt.xyaxes = CAMERA_OFFSET, look_at(CAMERA_OFFSET, CAMERA_TARGET)
        self.spec = spec
        self.model = spec.compile()
        self.model.vis.map.shadowclip = SHADOW_REACH / self.model.stat.extent  # see _lighting
        self.bound = BoundBody(body, self.model)
        self.hfield_id = self.model.hfield("terrain").id
        adr = self.model.hfield_adr[self.hfield_id]
        self._hfield = self.model.hfield_data[adr : adr + g.nrow * g.ncol].reshape(g.nrow, g.ncol)
        self._offset, self._inv_range = lo, 1.0 / (hi - lo)
        self.heights = np.zeros((g.nrow, g.ncol))
        self.version = 0
        self.camera = PREFIX + "track"

    def regenerate(self, task: dict, rng: np.random.Generator) -> None:
        """This episode's terrain for `task`, drawn from `rng`, written in place."""
        self.write_heights(self.generator.heights(task, rng))

    def write_heights(self, heights: np.ndarray) -> None:
        """Write heights (metres, (rows, cols)) into the compiled heightfield.

        The buildable task ranges keep every height inside `HEIGHT_RANGE`; the clip only
        guards the heightfield's [0, 1] encoding against rounding at its ends.
        """
        self.heights = heights
        np.clip(self.fractions(heights), 0.0, 1.0, out=self._hfield)
        self.version += 1

    def fractions(self, heights):
        """Heights in metres (numpy or torch, any shape) as the heightfield stores them: their
        fraction of `HEIGHT_RANGE`, unclipped (the many-world simulation writes its worlds' own)."""
        return (heights - self._offset) * self._inv_range


def _lighting(spec: mujoco.MjSpec, half_length: float, half_width: float) -> None:
    """The field drawn with its checker in every render preset, lit by a sun that casts shadows:
    the squares show slopes and blocks, the walker's shadow where its feet meet the ground."""
    spec.geom("terrain").material = "field"
    square = 2 * GROUND_SQUARE  # the checker texture holds 2 x 2 squares
    spec.material("field").texrepeat = [2 * half_length / square, 2 * half_width / square]
    sun = spec.light("sun")
    sun.castshadow, sun.dir, sun.diffuse = True, SUN_DIRECTION, [0.6] * 3
    # the sun follows the walker (the world's centre of mass is the walker's): its shadow map
    # then covers SHADOW_REACH m around it, not the whole field, and stays sharp at 512 texels
    sun.mode, sun.pos = mujoco.mjtCamLight.mjCAMLIGHT_TRACKCOM, -10 * np.asarray(SUN_DIRECTION)
    spec.visual.headlight.diffuse = [0.35] * 3  # less light from the eye, more shading by the sun


def look_at(offset, target) -> list[float]:
    """A camera's xyaxes (its x then y axis, world frame) at `offset` looking at `target`, level:
    its x axis stays horizontal."""
    forward = np.subtract(target, offset, dtype=float)
    x = np.cross(forward, (0.0, 0.0, 1.0))
    y = np.cross(x, forward)
    return [*(x / np.linalg.norm(x)), *(y / np.linalg.norm(y))]
