"""Height scan: terrain heights on a grid around the body, in its heading frame.

What legged-robot frameworks give a 3D walker instead of a sagittal lidar: the terrain height at
points laid out on a forward x lateral grid that turns with the body's heading (yaw only, so the
grid stays level when the body pitches or rolls), each reported relative to the root's height.
Heights are interpolated bilinearly from the heightfield array itself (no ray casts): the cost
is a few array operations for all points of all envs, whatever the terrain. Points off the field
read its nearest edge. On the tracks the profile is the same across the track, so the scan sees
it at every lateral offset.
"""

from __future__ import annotations

import math

import numpy as np

FORWARD = np.linspace(-1.0, 3.0, 9)  # metres along the heading: 1 m behind to 3 m ahead
LATERAL = np.linspace(-1.5, 1.5, 7)  # metres to the body's left (+) and right (-)
MIN_NORM = 1e-12  # below this the body's forward axis has no horizontal heading


class HeightScan:
    """Heights around the root of a body on a regular heightfield grid.

    Args:
        x_min, y_min: world position of the heightfield's first column and first row.
        cell: metres between neighbouring points, along x and y.
        root_id: the body whose position and heading the grid follows.
        forward, lateral: the scan points' offsets in the heading frame (metres).

    The readings (`nb_rays` of them, forward offsets varying fastest) are
    terrain height - root height, in metres.
    """

    def __init__(
        self,
        x_min: float,
        y_min: float,
        cell: float,
        root_id: int,
        forward: np.ndarray = FORWARD,
        lateral: np.ndarray = LATERAL,
    ):
        self.root_id = root_id
        dx, dy = np.meshgrid(np.asarray(forward, float), np.asarray(lateral, float))
        inv_cell = 1.0 / float(cell)
        # offsets in grid cells: (x, y) of the forward axis and of the left axis, per point
        self._along = np.stack((dx.ravel(), dy.ravel())) * inv_cell
        self._across = np.stack((-dy.ravel(), dx.ravel())) * inv_cell
        self._origin = np.array([[x_min], [y_min]])
        self._inv_cell = inv_cell
        self.nb_rays = dx.size
        self._shape = (0, 0, 0)

    def read(self, heights: np.ndarray, data) -> np.ndarray:
        """One env: `heights` (rows, cols), the root read from MuJoCo `data`."""
        r = data.xmat[self.root_id]
        a, b = float(r[0]), float(r[3])
        norm = max(math.sqrt(a * a + b * b), MIN_NORM)  # the same arithmetic as `read_batch`
        origin = data.xpos[self.root_id]
        cos_sin = np.array((a / norm, b / norm)).reshape(2, 1, 1, 1)
        return self._scan(heights[None], origin[None], cos_sin)[0]

    def read_batch(
        self, heights: np.ndarray, origins: np.ndarray, heading: np.ndarray
    ) -> np.ndarray:
        """N envs: heights (N, rows, cols), root positions (N, 3), heading vectors (N, 2).

        `heading` is the body's forward axis projected on the ground (the first column of its
        rotation matrix, x and y); it is normalised here. A body pointing straight up or down
        has no heading: its scan collapses onto its root. Every operation is element-wise per
        env, so a row is bit-identical to `read` on the same env alone.
        """
        a, b = heading[:, 0], heading[:, 1]
        norm = np.maximum(np.sqrt(a * a + b * b), MIN_NORM)
        return self._scan(heights, origins, (heading / norm[:, None]).T[:, :, None, None])

    def _scan(self, heights: np.ndarray, origins: np.ndarray, cos_sin: np.ndarray) -> np.ndarray:
        """Readings (N, P) for unit headings `cos_sin` (2, N, 1, 1)."""
        n, rows, cols = heights.shape
        if self._shape != (n, rows, cols):
            self._setup(n, rows, cols)
        # (N, 2, P) fractional grid coordinates (column, row) of the scan points
        uv = cos_sin[0] * self._along
        uv += cos_sin[1] * self._across
        uv += (origins[:, :2, None] - self._origin) * self._inv_cell
        np.maximum(uv, 0.0, out=uv)
        np.minimum(uv, self._top, out=uv)
        ij = np.minimum(uv.astype(np.int64), self._last)
        w = uv - ij  # weights towards the next column / row
        k = ij[:, 0] + cols * ij[:, 1] + self._env_offsets
        c = heights.reshape(-1)[k[:, None, :] + self._corners]  # (N, 4, P)
        edges = c[:, 0::2] + (c[:, 1::2] - c[:, 0::2]) * w[:, 0, None]
        return edges[:, 0] + (edges[:, 1] - edges[:, 0]) * w[:, 1] - origins[:, 2:3]

    def _setup(self, n: int, rows: int, cols: int) -> None:
        """Constants of a heights array shape: clip bounds, corner offsets, env offsets."""
        self._shape = (n, rows, cols)
        self._top = np.array([[cols - 1.0], [rows - 1.0]])
        self._last = np.array([[cols - 2], [rows - 2]])
        self._corners = np.array([[0], [1], [cols], [cols + 1]])
        self._env_offsets = (rows * cols) * np.arange(n)[:, None]
