"""Height scan: terrain heights on a grid around the body, in its heading frame.

What legged-robot frameworks give a 3D walker instead of a sagittal lidar: the terrain height at
points laid out on a forward x lateral grid that turns with the body's heading (yaw only, so the
grid stays level when the body pitches or rolls), each reported relative to the root's height.
Heights are interpolated bilinearly from the heightfield array itself (no ray casts): the cost
is a few array operations for all points of all envs, whatever the terrain. Points off the field
read its nearest edge. On the tracks and Parkour's ground the profile is the same across the
track, so the scan sees it at every lateral offset.
"""

from __future__ import annotations

import math

import numpy as np

from acl3d.envs.arena import TRACK_HALF_WIDTH

FORWARD = np.linspace(-1.0, 3.0, 9)  # metres along the heading: 1 m behind to 3 m ahead
LATERAL = np.linspace(-1.5, 1.5, 7)  # metres to the body's left (+) and right (-)
MIN_NORM = 1e-12  # below this the body's forward axis has no horizontal heading


class HeightScan:
    """Heights around a body's root on its arena's heightfield: a task's terrain sensor.

    Args:
        arena: the body's arena; a 2D field (`heights` (rows, cols)) or a track (one profile
            `heights` (cols,), the same at every y).
        forward, lateral: the scan points' offsets in the heading frame (metres).

    `read` gives the `nb_rays` readings (forward offsets varying fastest):
    terrain height - root height, in metres.
    """

    def __init__(self, arena, forward: np.ndarray = FORWARD, lateral: np.ndarray = LATERAL):
        self.arena = arena
        self.root_id = arena.bound.root_id
        g = arena.grid
        profile = np.ndim(arena.heights) == 1  # a track: rows across it are all the same
        y_min = -TRACK_HALF_WIDTH if profile else -g.half_width
        dx, dy = np.meshgrid(np.asarray(forward, float), np.asarray(lateral, float))
        inv_cell = 1.0 / float(g.cell)
        # offsets in grid cells: (x, y) of the forward axis and of the left axis, per point
        self._along = np.stack((dx.ravel(), dy.ravel())) * inv_cell
        self._across = np.stack((-dy.ravel(), dx.ravel())) * inv_cell
        self._origin = np.array([[g.x_min], [y_min]])
        self._inv_cell = inv_cell
        self.nb_rays = dx.size
        self._shape = (0, 0, 0)
        self._profile_version, self._profile_rows = -1, np.zeros((2, 2))

    def heights(self) -> np.ndarray:
        """The arena's heights as (rows, cols); a track's profile as two equal rows."""
        h = self.arena.heights
        if h.ndim == 2:
            return h
        if self._profile_version != self.arena.version:
            self._profile_rows = np.vstack((h, h))
            self._profile_version = self.arena.version
        return self._profile_rows

    def read(self, model, data, origin) -> np.ndarray:
        """One env's readings (the lidars' interface; `origin` is the root's position)."""
        r = data.xmat[self.root_id]
        a, b = float(r[0]), float(r[3])
        norm = max(math.sqrt(a * a + b * b), MIN_NORM)  # the same arithmetic as `read_batch`
        cos_sin = np.array((a / norm, b / norm)).reshape(2, 1, 1, 1)
        return self._scan(self.heights()[None], origin[None], cos_sin)[0]

    def read_batch(
        self, heights: np.ndarray, origins: np.ndarray, heading: np.ndarray
    ) -> np.ndarray:
        """N envs: heights (N, rows, cols), root positions (N, 3), heading vectors (N, 2).

        `heading` is the body's forward axis projected on the ground (the first column of its
        rotation matrix, x and y); it is normalised here. A body pointing straight up or down
        has no heading: its scan collapses onto its root. Every operation is element-wise per
        env, so a row is bit-identical to `read` on the same env alone (heights as `heights()` gives).
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
