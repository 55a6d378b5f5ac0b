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
from scipy.ndimage import map_coordinates

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
        self._inv_cell = 1.0 / float(g.cell)
        # a point's offset in grid cells, (row, column) = (y, x), turned by the heading yaw:
        # cos(yaw) * (dy, dx) + sin(yaw) * (dx, -dy)
        self._cos_part = np.stack((dy.ravel(), dx.ravel())) * self._inv_cell
        self._sin_part = np.stack((dx.ravel(), -dy.ravel())) * self._inv_cell
        self._min = (y_min, g.x_min)
        self.nb_rays = dx.size
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
        x, y, z = float(origin[0]), float(origin[1]), float(origin[2])
        shift = np.array(((y - self._min[0]) * self._inv_cell, (x - self._min[1]) * self._inv_cell))
        coords = (a / norm) * self._cos_part + (b / norm) * self._sin_part + shift[:, None]
        return self._sample(self.heights(), coords) - z

    def read_batch(
        self, heights: np.ndarray, origins: np.ndarray, heading: np.ndarray
    ) -> np.ndarray:
        """N envs: heights (N, rows, cols), root positions (N, 3), heading vectors (N, 2).

        `heading` is the body's forward axis projected on the ground (the first column of its
        rotation matrix, x and y); it is normalised here. A body pointing straight up or down
        has no heading: its scan collapses onto its root. Every operation is element-wise per
        env, so a row is bit-identical to `read` on the same env alone (heights as `heights()`
        gives).
        """
        a, b = heading[:, 0], heading[:, 1]
        norm = np.maximum(np.sqrt(a * a + b * b), MIN_NORM)
        shift = np.stack(
            (
                (origins[:, 1] - self._min[0]) * self._inv_cell,
                (origins[:, 0] - self._min[1]) * self._inv_cell,
            ),
            axis=1,
        )
        coords = (
            (a / norm)[:, None, None] * self._cos_part
            + (b / norm)[:, None, None] * self._sin_part
            + shift[:, :, None]
        )
        out = np.empty((len(origins), self.nb_rays))
        for i in range(len(origins)):
            out[i] = self._sample(heights[i], coords[i])
        return out - origins[:, 2:3]

    @staticmethod
    def _sample(heights: np.ndarray, coords: np.ndarray) -> np.ndarray:
        """Bilinear heights at fractional (row, column) coordinates; off the grid, its edge."""
        return map_coordinates(heights, coords, order=1, mode="nearest", prefilter=False)
