"""Lidars: 10 rays cast from the body's head in the sagittal plane, as in TeachMyAgent.

Ray i points along (sin t_i, 0, -cos t_i) in the world frame with t_i = a*i/10 + b; the reading is
the hit distance as a fraction of the range (1 = nothing within range). Only geoms in group 0
(the terrain and, in Parkour, water and creepers) are seen: never the body itself.
"""

from __future__ import annotations

import mujoco
import numpy as np

LIDAR_RANGE = 160 / 30  # 5.33 m
LIDAR_TYPES = {"down": (1.5, 0.0), "up": (2.3, 1.5), "full": (np.pi, 0.0)}
NB_RAYS = 10


class Lidar:
    def __init__(self, kind: str = "down", nb_rays: int = NB_RAYS, ray_range: float = LIDAR_RANGE):
        if kind not in LIDAR_TYPES:
            raise ValueError(f"lidar type {kind!r}; valid: {list(LIDAR_TYPES)}")
        a, b = LIDAR_TYPES[kind]
        angles = a * np.arange(nb_rays) / nb_rays + b
        self.kind = kind
        self.range = ray_range
        self._inv_range = 1.0 / ray_range
        self.nb_rays = nb_rays
        self._vec = np.stack([np.sin(angles), np.zeros(nb_rays), -np.cos(angles)], axis=1).ravel()
        self._groups = np.array([1, 0, 0, 0, 0, 0], dtype=np.uint8)
        self.geom_ids = np.zeros(nb_rays, dtype=np.int32)
        self._dist = np.zeros(nb_rays)

    def read(self, model: mujoco.MjModel, data: mujoco.MjData, origin: np.ndarray) -> np.ndarray:
        """Fractions in [0, 1] (1 = no hit); `self.geom_ids` holds the hit geoms (-1 = none)."""
        mujoco.mj_multiRay(
            model,
            data,
            origin,
            self._vec,
            self._groups,
            1,
            -1,
            self.geom_ids,
            self._dist,
            None,
            self.nb_rays,
            self.range,
        )
        fraction = self._dist * self._inv_range
        miss = (self.geom_ids < 0) | (fraction > 1.0)
        fraction[miss] = 1.0
        self.geom_ids[miss] = -1
        return fraction
