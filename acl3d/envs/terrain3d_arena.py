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

CAMERA_DISTANCE = 12.0  # metres beside the body: the whole field's width is in view


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
        spec.geom("scenery").pos = [centre_x, 0.0, lo - HFIELD_BASE_DEPTH - 0.01]
        finish = spec.geom("finish_line")
        finish.pos = [generator.end_x, 0.0, 0.01]
        finish.size = [0.05, g.half_width, 0.01]
        spec.material("ground").texrepeat = [half_length / 2, g.half_width / 2]
        attach_body(spec, body, self.start_x, CAMERA_DISTANCE)
        self.spec = spec
        self.model = spec.compile()
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
        np.clip((heights - self._offset) * self._inv_range, 0.0, 1.0, out=self._hfield)
        self.version += 1
