"""Stump Tracks and Hexagon Tracks terrain: task parameters -> a height line along the track.

Pure numpy, no MuJoCo. The height line (heights along x, the same across the track) is sampled
on a regular x grid and becomes the columns of a heightfield extruded across the track; stumps,
stump sequences and hexagons are part of that line (their upper envelope). Units follow
TeachMyAgent: metres, with stump heights in terrain steps (TS = 14/30 m) and obstacle spacing in
metres of flat ground between obstacles.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from acl3d import validation
from acl3d.task_space import TaskParameter, TaskSpace

TERRAIN_STEP = 14 / 30  # TS, metres
TERRAIN_LENGTH = 200  # in TS: the obstacle course ends at 200 TS = 93.33 m
START_PAD = 20  # in TS: 9.33 m of flat start pad
START_X = TERRAIN_STEP * START_PAD / 2  # 4.67 m, where bodies spawn (default start pad)
END_X = (TERRAIN_LENGTH - 10) * TERRAIN_STEP  # 88.67 m, crossing it ends the episode (success)
NOISE_STD = 0.1  # per-obstacle noise on the task means, as in the original
MIN_OBSTACLE = 0.05  # floor on drawn heights/widths (in their own units)
MAX_TERRAIN_HEIGHT = 10.0  # metres: the heightfield's vertical range above the flat ground

# The default hexagon (base-relative vertices in TS units), §2.2 of the reference.
HEXAGON_BASE = np.array(
    [(-0.5, 0.0), (-0.5, 0.25), (-0.25, 0.5), (0.25, 0.5), (0.5, 0.25), (0.5, 0.0)]
)

# Every parameter the generator understands; environments expose a subset as their task space.
TRACK_PARAMETERS: dict[str, TaskParameter] = {
    p.name: p
    for p in (
        TaskParameter(
            "stump_height",
            (0.0,),
            (3.0,),
            "TS",
            "mean stump height; each stump ~ max(0.05, N(h, 0.1)) TS",
            (0.0,),
        ),
        TaskParameter(
            "obstacle_spacing", (0.0,), (6.0,), "m", "flat ground between two obstacles", (8.0,)
        ),
        TaskParameter(
            "stump_width",
            (0.5,),
            (2.0,),
            "TS",
            "mean stump width; each ~ max(0.05, N(w, 0.1)) TS",
            (1.0,),
        ),
        TaskParameter(
            "stump_rot",
            (0.0,),
            (0.5,),
            "rad",
            "mean stump tilt about its base centre; each ~ N(r, 0.1) clipped to [0, 2pi]",
            (0.0,),
        ),
        TaskParameter(
            "stump_seq",
            (0.0,) * 10,
            (6.0,) * 10,
            "TS/m",
            "5 (height TS, width m) pairs per obstacle",
            (0.0,) * 10,
        ),
        TaskParameter(
            "poly_shape",
            (0.0,) * 12,
            (4.0,) * 12,
            "TS",
            "6 (dx, dy) hexagon vertex offsets",
            (0.0,) * 12,
        ),
    )
}

# Buildable ranges: outside the benchmark bounds is fine, outside these the generator cannot build.
_MAX_STUMP_HEIGHT_TS = (
    MAX_TERRAIN_HEIGHT - 1.0
) / TERRAIN_STEP  # keeps noise margin under the ceiling
_BUILDABLE = {
    "stump_height": (-np.inf, _MAX_STUMP_HEIGHT_TS),
    "obstacle_spacing": (0.0, TERRAIN_LENGTH * TERRAIN_STEP),
    "stump_width": (0.0, 20.0),
    "stump_rot": (-2 * np.pi, 2 * np.pi),
    "stump_seq": (0.0, _MAX_STUMP_HEIGHT_TS),
    "poly_shape": (-1.0, (MAX_TERRAIN_HEIGHT - 1.0) / TERRAIN_STEP - 0.5),
}


def start_pad_for(body_length: float) -> int:
    """Start pad in TS: 20, widened to body length / TS + 5 for long bodies (as the original)."""
    return max(START_PAD, int(np.ceil(body_length / TERRAIN_STEP)) + 5)


def track_task_space(names) -> TaskSpace:
    """The task space made of the named track parameters (benchmark bounds)."""
    unknown = [n for n in names if n not in TRACK_PARAMETERS]
    if unknown:
        raise ValueError(f"unknown track parameter(s) {unknown}; valid: {list(TRACK_PARAMETERS)}")
    return TaskSpace(tuple(TRACK_PARAMETERS[n] for n in names))


def check_buildable(task: Mapping[str, np.ndarray]) -> None:
    """Raise ValueError naming the parameter, value and range if the generator cannot build it."""
    for name, value in task.items():
        validation.choice("track parameter", name, list(_BUILDABLE))
        validation.real_array_in(name, value, *_BUILDABLE[name], "values in the buildable range")


@dataclass(frozen=True)
class TrackGrid:
    """The x sampling of the height line: heightfield columns from x_min to x_max."""

    x_min: float = -5.0
    x_max: float = TERRAIN_LENGTH * TERRAIN_STEP + 10.0
    ncol: int = 2048

    @property
    def x(self) -> np.ndarray:
        return np.linspace(self.x_min, self.x_max, self.ncol)

    @property
    def cell(self) -> float:
        return (self.x_max - self.x_min) / (self.ncol - 1)


def _convex_upper_envelope(points: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Height of the convex hull of `points` above each x (nan outside its x-range).

    The upper hull at x is the highest point of any segment between two vertices that spans x;
    with 4-6 vertices, checking all pairs at once is faster than building the hull.
    """
    i, j = np.triu_indices(len(points), k=1)
    p, q = points[i], points[j]
    left, right = np.minimum(p[:, 0], q[:, 0]), np.maximum(p[:, 0], q[:, 0])
    dx = q[:, 0] - p[:, 0]
    safe_dx = np.where(dx == 0, 1.0, dx)
    t = (x[:, None] - p[None, :, 0]) / safe_dx[None, :]
    y = p[None, :, 1] + t * (q[None, :, 1] - p[None, :, 1])
    vertical = dx == 0  # a vertical segment contributes its top where it stands
    y[:, vertical] = np.maximum(p[vertical, 1], q[vertical, 1])[None, :]
    inside = (x[:, None] >= left[None, :] - 1e-12) & (x[:, None] <= right[None, :] + 1e-12)
    y[~inside] = -np.inf
    top = y.max(axis=1)
    top[~np.isfinite(top)] = np.nan
    return top


def _columns(grid: TrackGrid, x0: float, x1: float) -> slice:
    """Grid columns whose x lies in [x0, x1]."""
    i0 = max(0, int(np.ceil((x0 - grid.x_min) / grid.cell - 1e-9)))
    i1 = min(grid.ncol - 1, int(np.floor((x1 - grid.x_min) / grid.cell + 1e-9)))
    return slice(i0, i1 + 1)


def _column_ranges(grid: TrackGrid, x0: np.ndarray, x1: np.ndarray):
    """`_columns` of many intervals at once: their (first, last) columns, as arrays."""
    first = np.maximum(0, np.ceil((x0 - grid.x_min) / grid.cell - 1e-9).astype(np.int64))
    last = np.minimum(
        grid.ncol - 1, np.floor((x1 - grid.x_min) / grid.cell + 1e-9).astype(np.int64)
    )
    return first, last


class TrackGenerator:
    """Builds the height line of one episode from a task dict and the env's generator."""

    def __init__(self, grid: TrackGrid = TrackGrid()):
        self.grid = grid
        self.x = grid.x

    def _stamp_boxes(self, heights: np.ndarray, boxes: list[tuple[float, float, float]]) -> None:
        """Raise `heights` to each box (x0, x1, h) over its columns, all boxes in one pass (a
        maximum: the order of stamping does not matter)."""
        if not boxes:
            return
        x0, x1, h = np.array(boxes).T
        first, last = _column_ranges(self.grid, x0, x1)
        widths = np.maximum(last - first + 1, 0)
        starts = np.cumsum(widths) - widths  # each box's offset among all stamped columns
        cols = np.arange(widths.sum()) + np.repeat(first - starts, widths)
        np.maximum.at(heights, cols, np.repeat(h, widths))

    def _stamp_polygon(self, heights: np.ndarray, polygon: np.ndarray) -> None:
        """Raise `heights` to the polygon's upper envelope where it covers the grid."""
        cols = _columns(self.grid, polygon[:, 0].min(), polygon[:, 0].max())
        y = _convex_upper_envelope(polygon, self.x[cols])
        np.fmax(heights[cols], y, out=heights[cols])

    def heights(
        self, task: Mapping[str, object], rng: np.random.Generator, start_pad: int = START_PAD
    ) -> np.ndarray:
        """Heights (metres above the flat ground) at `self.x` for one episode.

        `task` holds the parameters to use; obstacle kinds present among stump_height, stump_seq
        and poly_shape alternate uniformly at random (as the original), separated by
        `obstacle_spacing` metres of flat ground, from the end of the start pad (`start_pad` TS,
        widened for long bodies) to 200 TS.
        """
        heights = np.zeros_like(self.x)
        kinds = [k for k in ("stump_height", "stump_seq", "poly_shape") if k in task]
        if not kinds:
            return heights
        spacing = float(
            task.get("obstacle_spacing", TRACK_PARAMETERS["obstacle_spacing"].default[0])
        )
        x = start_pad * TERRAIN_STEP
        end = TERRAIN_LENGTH * TERRAIN_STEP
        boxes: list[tuple[float, float, float]] = []  # stamped together at the end
        while x < end:
            kind = kinds[int(rng.integers(len(kinds)))] if len(kinds) > 1 else kinds[0]
            if kind == "stump_height":
                x = self._stump(heights, boxes, x, task, rng)
            elif kind == "stump_seq":
                x = self._stump_sequence(
                    boxes, x, np.asarray(task["stump_seq"], dtype=np.float64), rng
                )
            else:
                x = self._hexagon(heights, x, np.asarray(task["poly_shape"], dtype=np.float64), rng)
            x += spacing
        self._stamp_boxes(heights, boxes)
        return np.minimum(heights, MAX_TERRAIN_HEIGHT)

    def _stump(self, heights, boxes, x0, task, rng) -> float:
        h = max(MIN_OBSTACLE, rng.normal(float(task["stump_height"]), NOISE_STD)) * TERRAIN_STEP
        w = TERRAIN_STEP
        if "stump_width" in task:
            w = max(MIN_OBSTACLE, rng.normal(float(task["stump_width"]), NOISE_STD)) * TERRAIN_STEP
        if "stump_rot" not in task:
            boxes.append((x0, x0 + w, h))
            return x0 + w
        corners = np.array([(0.0, 0.0), (0.0, h), (w, h), (w, 0.0)])
        angle = float(np.clip(rng.normal(float(task["stump_rot"]), NOISE_STD), 0.0, 2 * np.pi))
        c, s = np.cos(angle), np.sin(angle)
        centre = np.array([w / 2, 0.0])
        corners = (corners - centre) @ np.array([[c, s], [-s, c]]) + centre
        corners[:, 1] = np.maximum(corners[:, 1], 0.0)
        corners[:, 0] += x0
        self._stamp_polygon(heights, corners)
        return x0 + w

    def _stump_sequence(self, boxes, x0, seq, rng) -> float:
        x = x0
        for h_mean, w_mean in seq.reshape(5, 2):
            h = max(MIN_OBSTACLE, rng.normal(h_mean, NOISE_STD)) * TERRAIN_STEP
            w = max(MIN_OBSTACLE, rng.normal(w_mean, NOISE_STD))  # metres, as the original
            boxes.append((x, x + w, h))
            x += w
        return x

    def _hexagon(self, heights, x0, shape, rng) -> float:
        offsets = shape.reshape(6, 2) + rng.normal(0.0, NOISE_STD, size=(6, 2))
        offsets[[0, 5], 1] = 0.0  # first and last vertices stay on the ground
        vertices = (HEXAGON_BASE + offsets) * TERRAIN_STEP
        vertices[:, 1] = np.maximum(vertices[:, 1], 0.0)
        vertices[:, 0] += x0
        self._stamp_polygon(heights, vertices)
        return x0 + 1.0
