"""3D Terrain: task parameters -> a 2D heightfield (rows along y, columns along x).

Pure numpy, no MuJoCo. Unlike the tracks (a height line extruded across the track), every quantity
here varies across the field too: blocks cover a fraction of its width at random lateral
positions (full-width walls to climb, or blocks to walk around), the ground twists (a cross
slope whose sign alternates along the field), rolls in hills and is rough on a 0.5 m lattice.
Units: metres for heights and distances, degrees for slopes, a fraction of the field's width for
the block width. Flat ground is at height 0.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass

import numpy as np

from acl3d import validation
from acl3d.task_space import TaskParameter, TaskSpace

# Metres between heightfield points along x (columns) and across y (rows). A block's faces are
# ramps one cell long: 0.1 m along x keeps a 0.5 m block a block (at 0.2 m it was a wedge,
# 0.2 m of flat top between two 0.2 m ramps). Across, 0.5 m puts a row on every roughness
# lattice point, and a GPU steps the field ~1.4x faster than on 0.2 m rows (heightfield
# collision is most of its step); the sides of partial-width blocks become 0.5 m ramps.
CELL = 0.1
ROW_CELL = 0.5
# metres: the spacings a generator accepts (coarser: faster contacts); on a coarser grid than
# a block (0.5 m long, 0.6 m wide at the benchmark's narrowest) whole blocks would fall between
# its points
CELL_RANGE = (0.05, 0.5)
FIELD_HALF_WIDTH = 3.0  # metres: the field spans y in [-3, 3]; leaving it ends the episode
COURSE_LENGTH = 20.0  # metres of terrain from the end of the start pad to the finish line
RUN_OUT = 5.0  # metres of field after the finish line
BACK_MARGIN = 2.5  # metres of field behind x = 0
MIN_START_PAD = 4.0  # metres of flat start pad; longer bodies get their length + 2 m
BLOCK_LENGTH = 0.5  # metres: each block's extent along x
BLOCK_NOISE = 0.05  # metres: std of each block's height around the task's mean
FIRST_BLOCK = 1.0  # metres after the start pad where the first row of blocks begins
HILL_WAVELENGTH = 10.0  # metres along x
TWIST_WAVELENGTH = 8.0  # metres along x: the cross slope's sign alternates every 4 m
ROUGH_LATTICE = 0.5  # metres between the random heights that roughness interpolates
HEIGHT_RANGE = (-4.0, 10.0)  # metres: what the compiled heightfield can represent

TERRAIN3D_PARAMETERS: tuple[TaskParameter, ...] = (
    TaskParameter(
        "block_height",
        (0.0,),
        (1.5,),
        "m",
        "mean block height above the ground under it; each ~ max(0, N(h, 0.05))",
        (0.0,),
    ),
    TaskParameter(
        "block_width",
        (0.1,),
        (1.0,),
        "fraction",
        "block width as a fraction of the field width (1 = full-width wall); 0 = no blocks",
        (1.0,),
    ),
    TaskParameter(
        "block_spacing", (1.0,), (6.0,), "m", "ground between two rows of blocks along x", (4.0,)
    ),
    TaskParameter(
        "cross_slope",
        (0.0,),
        (25.0,),
        "deg",
        "steepest roll of the ground across the field; its sign alternates every 4 m",
        (0.0,),
    ),
    TaskParameter(
        "hill_slope", (0.0,), (25.0,), "deg", "steepest pitch of 10 m hills along the field", (0.0,)
    ),
    TaskParameter(
        "roughness",
        (0.0,),
        (0.3,),
        "m",
        "amplitude of random bumps on a 0.5 m lattice (uniform in [-a, a], interpolated)",
        (0.0,),
    ),
)
PARAMETERS = {p.name: p for p in TERRAIN3D_PARAMETERS}

# Buildable ranges (what the heightfield can represent), wider than the benchmark bounds.
_BUILDABLE = {
    "block_height": (0.0, 3.0),
    "block_width": (0.0, 1.0),
    "block_spacing": (0.0, 100.0),
    "cross_slope": (0.0, 40.0),
    "hill_slope": (0.0, 40.0),
    "roughness": (0.0, 0.5),
}


def terrain3d_task_space(names=None) -> TaskSpace:
    """The task space of the named parameters (default: all six), with benchmark bounds."""
    names = tuple(PARAMETERS) if names is None else tuple(names)
    unknown = [n for n in names if n not in PARAMETERS]
    if unknown or not names:
        raise ValueError(
            f"task_parameters={list(names)!r}; valid: a non-empty subset of {list(PARAMETERS)}"
        )
    return TaskSpace(tuple(PARAMETERS[n] for n in names))


def buildable_range(name: str) -> tuple[float, float]:
    """(low, high) of what the generator can build for parameter `name`."""
    validation.choice("terrain parameter", name, list(_BUILDABLE))
    return _BUILDABLE[name]


def check_buildable(task: Mapping[str, object]) -> None:
    """Raise ValueError naming the parameter, value and range if the generator cannot build it."""
    for name, value in task.items():
        validation.choice("terrain parameter", name, list(_BUILDABLE))
        validation.real_array_in(name, value, *_BUILDABLE[name], "values in the buildable range")


@dataclass(frozen=True)
class FieldGrid:
    """Where the heightfield's points lie: columns along x `cell` apart, rows along y
    `row_cell` apart."""

    x_min: float
    ncol: int
    nrow: int
    cell: float
    row_cell: float

    @classmethod
    def spanning(
        cls, x_min: float, x_max: float, cell: float = CELL, row_cell: float = ROW_CELL
    ) -> FieldGrid:
        """The grid from x_min to at least x_max, across the whole field's width."""
        ncol = int(np.ceil((x_max - x_min) / cell - 1e-9)) + 1
        return cls(x_min, ncol, int(round(2 * FIELD_HALF_WIDTH / row_cell)) + 1, cell, row_cell)

    @property
    def x_max(self) -> float:
        return self.x_min + (self.ncol - 1) * self.cell

    @property
    def half_width(self) -> float:
        return (self.nrow - 1) * self.row_cell / 2

    @property
    def x(self) -> np.ndarray:
        return self.x_min + self.cell * np.arange(self.ncol)

    @property
    def y(self) -> np.ndarray:
        return -self.half_width + self.row_cell * np.arange(self.nrow)


def start_pad_for(body_length: float) -> float:
    """Flat start pad in metres: 4, or the body's length + 2 m for long bodies."""
    return max(MIN_START_PAD, body_length + 2.0)


class Terrain3DGenerator:
    """Builds one episode's heights (rows, cols) from a task dict and the env's generator.

    The field runs from `BACK_MARGIN` m behind x = 0 to `RUN_OUT` m past the finish line
    (`end_x` = start pad + `COURSE_LENGTH`). The start pad is flat; hills, twist and roughness
    start at its end, blocks `FIRST_BLOCK` m later. Every draw comes from the given generator
    in a fixed order (twist sign, roughness lattice, then per block: height, lateral position).
    `cell` and `row_cell` space the points along and across the field (metres, in
    `CELL_RANGE`): the env's `grid_spacing`, by default `CELL` and `ROW_CELL`; a coarser grid
    collides faster and turns blocks into wedges (scripts/bench_terrain3d_collision.py).
    """

    def __init__(self, start_pad: float, cell: float = CELL, row_cell: float = ROW_CELL):
        cell, row_cell = _spacings(cell, row_cell, ("cell", "row_cell"))
        self.start_pad = float(start_pad)
        self.end_x = self.start_pad + COURSE_LENGTH
        self.grid = FieldGrid.spanning(-BACK_MARGIN, self.end_x + RUN_OUT, cell, row_cell)
        g = self.grid
        self._along = np.maximum(g.x - self.start_pad, 0.0)  # metres into the course
        self._y = g.y
        # roughness: bilinear weights from a lattice covering the course
        lattice_x = self._along / ROUGH_LATTICE
        lattice_y = (g.y + g.half_width) / ROUGH_LATTICE
        self._lattice_shape = (
            int(np.floor(lattice_y[-1] + 1e-9)) + 2,
            int(np.floor(lattice_x[-1] + 1e-9)) + 2,
        )
        ix, iy = np.floor(lattice_x).astype(int), np.floor(lattice_y).astype(int)
        self._rough_index = (iy[:, None], ix[None, :])
        self._rough_w = (lattice_y - iy)[:, None], (lattice_x - ix)[None, :]
        self._rough_fade = np.minimum(self._along / ROUGH_LATTICE, 1.0)[None, :]

    def heights(self, task: Mapping[str, object], rng: np.random.Generator) -> np.ndarray:
        """Heights in metres (nrow, ncol): row i at y = grid.y[i], column j at x = grid.x[j]."""
        p = {
            name: float(np.ravel(task.get(name, spec.default))[0])
            for name, spec in PARAMETERS.items()
        }
        twist_sign = 1.0 if rng.random() < 0.5 else -1.0
        lattice = rng.uniform(-1.0, 1.0, size=self._lattice_shape)
        along = self._along
        hill = np.tan(np.radians(p["hill_slope"])) * HILL_WAVELENGTH / (2 * np.pi)
        ground = hill * (1.0 - np.cos(2 * np.pi * along / HILL_WAVELENGTH))
        roll = twist_sign * np.tan(np.radians(p["cross_slope"]))
        twist = roll * np.sin(2 * np.pi * along / TWIST_WAVELENGTH)
        h = ground[None, :] + self._y[:, None] * twist[None, :]
        if p["roughness"] > 0.0:
            h += p["roughness"] * self._rough_fade * self._bilinear(lattice)
        self._stamp_blocks(h, p, rng)
        return h

    def _bilinear(self, lattice: np.ndarray) -> np.ndarray:
        (iy, ix), (wy, wx) = self._rough_index, self._rough_w
        top = lattice[iy, ix] * (1.0 - wx) + lattice[iy, ix + 1] * wx
        bottom = lattice[iy + 1, ix] * (1.0 - wx) + lattice[iy + 1, ix + 1] * wx
        return top * (1.0 - wy) + bottom * wy

    def _stamp_blocks(self, h: np.ndarray, p: dict, rng: np.random.Generator) -> None:
        """Rows of blocks, `block_spacing` m apart, each raised above the ground under it."""
        g = self.grid
        width = p["block_width"] * 2 * g.half_width
        if width <= 0.0 or p["block_height"] <= 0.0:
            return
        for x in self.block_starts(p["block_spacing"]):
            height = max(0.0, rng.normal(p["block_height"], BLOCK_NOISE))
            centre = rng.uniform(-g.half_width + width / 2, g.half_width - width / 2)
            cols = _points(g.x_min, g.cell, g.ncol, x, x + BLOCK_LENGTH, closed=False)
            lo, hi = centre - width / 2, centre + width / 2
            rows = _points(-g.half_width, g.row_cell, g.nrow, lo, hi, closed=True)
            h[rows, cols] += height

    def block_starts(self, spacing: float) -> Iterator[float]:
        """Where each row of blocks begins along x (metres), `spacing` m of ground between
        rows, from `FIRST_BLOCK` m into the course to its end."""
        x = self.start_pad + FIRST_BLOCK
        while x < self.end_x:
            yield x
            x += BLOCK_LENGTH + spacing


def grid_spacing(value) -> tuple[float, float]:
    """An env's `grid_spacing` (metres between the heightfield's points along x, then across)
    as the generator's (cell, row_cell), or a ValueError naming it."""
    if not isinstance(value, (tuple, list, np.ndarray)) or np.shape(value) != (2,):
        raise validation.fail(
            "grid_spacing", value, "two spacings in metres, along x then across, e.g. (0.2, 0.2)"
        )
    return _spacings(*value, ("grid_spacing[0]", "grid_spacing[1]"))


def _spacings(cell, row_cell, names: tuple[str, str]) -> tuple[float, float]:
    """(cell, row_cell) as floats in `CELL_RANGE`, the rows spanning the field's width exactly."""
    cell = validation.real(names[0], cell, *CELL_RANGE)
    row_cell = validation.real(names[1], row_cell, *CELL_RANGE)
    rows = 2 * FIELD_HALF_WIDTH / row_cell
    if abs(rows - round(rows)) > 1e-9:
        raise validation.fail(
            names[1], row_cell, f"a spacing in {list(CELL_RANGE)} m that divides the "
            f"field's {2 * FIELD_HALF_WIDTH:g} m width (e.g. 0.1, 0.2, 0.25, 0.5)",
        )  # fmt: skip
    return cell, row_cell


def _points(start: float, cell: float, n: int, lo: float, hi: float, closed: bool) -> slice:
    """The grid points (start + k * cell, k < n) in [lo, hi], or in [lo, hi) when not `closed`
    (along x: blocks back to back never share a point, where their heights would add up)."""
    k0 = max(0, int(np.ceil((lo - start) / cell - 1e-9)))
    end = (hi - start) / cell
    k1 = int(np.floor(end + 1e-9)) + 1 if closed else int(np.ceil(end - 1e-9))
    return slice(k0, min(n, k1))
