"""Height scan: terrain heights on a grid around the body, in its heading frame.

What legged-robot frameworks give a 3D walker instead of a sagittal lidar: the terrain height at
points laid out on a forward x lateral grid that turns with the body's heading (yaw only, so the
grid stays level when the body pitches or rolls), each reported relative to the root's height.
Heights are interpolated bilinearly from the heightfield array itself (no ray casts): the cost
is a few array operations for all points of all envs, whatever the terrain. Points off the field
read its nearest edge. On the tracks the height line is the same across the track, so the scan
sees it at every lateral offset.

One implementation for every backend: `read_batch` is written over `ArrayOps` (numpy on the CPU,
torch for the many-world simulation: `on(ops)`).
"""

from __future__ import annotations

import copy

import numpy as np

from acl3d.envs.arena import TRACK_HALF_WIDTH
from acl3d.envs.array_ops import NUMPY, ArrayOps
from acl3d.envs.lidar import TerrainSensor

FORWARD = np.linspace(-1.0, 3.0, 9)  # metres along the heading: 1 m behind to 3 m ahead
LATERAL = np.linspace(-1.5, 1.5, 7)  # metres to the body's left (+) and right (-)
MIN_NORM = 1e-12  # below this the body's forward axis has no horizontal heading


class HeightScan(TerrainSensor):
    """Heights around a body's root on its arena's heightfield: the rules' terrain sensor.

    Args:
        arena: the body's arena; a 2D field (`heights` (rows, cols)) or a track (one height line
            `heights` (cols,), the same at every y).
        forward, lateral: the scan points' offsets in the heading frame (metres).

    The rules keep each env's heights in a row of `batch_heights(n)` (a track's height line as two
    equal rows) and `read_batch` gives the `nb_rays` readings of N envs (forward offsets varying
    fastest): terrain height - root height, in metres.
    """

    reads_height_rows = True
    ops: ArrayOps = NUMPY
    _constants = ("_cos_part", "_sin_part", "_inv_cell", "_min")

    def __init__(self, arena, forward: np.ndarray = FORWARD, lateral: np.ndarray = LATERAL):
        self.arena = arena
        g = arena.grid
        line = np.ndim(arena.heights) == 1  # a track: rows across it are all the same
        y_min = -TRACK_HALF_WIDTH if line else -g.half_width
        self._shape = (2, g.ncol) if line else np.shape(arena.heights)
        dx, dy = np.meshgrid(np.asarray(forward, float), np.asarray(lateral, float))
        # metres -> grid cells, (row, column) = (y, x); a field's rows may lie further apart
        # than its columns (a track's two rows are equal: any row spacing reads the same)
        row_cell = g.cell if line else 2 * g.half_width / (self._shape[0] - 1)
        inv_cell = 1.0 / np.array([[row_cell], [g.cell]])
        self._inv_cell = inv_cell[:, 0]
        # a point's offset in grid cells, turned by the heading yaw:
        # cos(yaw) * (dy, dx) + sin(yaw) * (dx, -dy)
        self._cos_part = np.stack((dy.ravel(), dx.ravel())) * inv_cell
        self._sin_part = np.stack((dx.ravel(), -dy.ravel())) * inv_cell
        self._min = np.array([y_min, g.x_min])
        self._yx = np.array([1, 0])  # an origin's (y, x): the grid's (row, column)
        self.nb_rays = dx.size

    def on(self, ops: ArrayOps) -> HeightScan:
        """This scan reading arrays of `ops` (the many-world simulation's tensors)."""
        out = copy.copy(self)
        out.ops = ops
        for name in self._constants:
            setattr(out, name, ops.asarray(getattr(self, name)))
        out._yx = ops.index(self._yx)
        return out

    def batch_heights(self, n: int):
        """Buffer of N envs' heights for `read_batch`: (N, rows, cols)."""
        return self.ops.full((n, *self._shape), 0.0)

    def read_batch(self, heights, origins, rotations):
        """(N, nb_rays) readings from heights (N, rows, cols), the roots' positions (N, 3) and
        orientations (N, 9 or N, 3, 3: row-major rotation matrices).

        The heading is the root's forward axis projected on the ground (x and y of the matrix's
        first column), normalised; a body pointing straight up or down has none, and its scan
        collapses onto its root. Heights are bilinear between the four surrounding samples,
        points off the field read its nearest edge. Every operation is element-wise per env, so
        each row is bit-identical to the same env scanned alone, whatever N.
        """
        ops, xp = self.ops, self.ops.xp
        n = origins.shape[0]
        m = rotations.reshape(n, 9)
        a, b = m[:, 0], m[:, 3]
        norm = ops.clip(xp.hypot(a, b), low=MIN_NORM)
        shift = (origins[:, self._yx] - self._min) * self._inv_cell  # (N, 2): (row, column)
        coords = (
            (a / norm)[:, None, None] * self._cos_part
            + (b / norm)[:, None, None] * self._sin_part
            + shift[:, :, None]
        )  # (N, 2, points)
        rows, cols = self._shape
        r = ops.clip(coords[:, 0], 0.0, rows - 1.0)
        c = ops.clip(coords[:, 1], 0.0, cols - 1.0)
        r0 = ops.clip(xp.floor(r), high=rows - 2.0)
        c0 = ops.clip(xp.floor(c), high=cols - 2.0)
        fr, fc = r - r0, c - c0
        flat = heights.reshape(n, rows * cols)
        base = ops.to_int(r0) * cols + ops.to_int(c0)
        top = ops.gather(flat, base) * (1.0 - fc) + ops.gather(flat, base + 1) * fc
        bottom = ops.gather(flat, base + cols) * (1.0 - fc) + ops.gather(flat, base + cols + 1) * fc
        return top * (1.0 - fr) + bottom * fr - origins[:, 2:3]
