"""Climbing: a climber's hands grasp the ceiling or a creeper through weld equalities.

The original creates a free revolute joint between a hand sensor and the grasped surface
(§2.6 of the reference). Here each hand has one weld equality to the world, compiled inactive;
grasping sets its anchors from the current poses (zero constraint error at the grab) and
activates it, with torquescale 0 so it pins the grasp point and leaves rotation free (the 3D
counterpart of the free revolute joint). Releasing deactivates it.

"Touch" is geometric, like the original's coarse AABB test: the sensor point, padded by its
radius + 1 cm, reaches the ceiling profile or lies in a creeper's box. Creepers never collide
with bodies, and a hand can grasp the ceiling from slightly below it, so contacts are not needed.
Anchors live in `model.eq_data`: each env compiles its own model, so envs never share them.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from acl3d.bodies.base import PREFIX, GraspSensor
from acl3d.terrain.parkour import ParkourTerrain

TOUCH_MARGIN = 0.01  # metres, the original's AABB padding
CEILING_MARGIN = 0.03  # a hand within 3 cm under the ceiling touches it
WELD_EQ_PREFIX = "grasp_"


def add_grasp_welds(spec: mujoco.MjSpec, sensors: Sequence[GraspSensor]) -> None:
    """One inactive weld hand -> world per grasp sensor (names resolved when compiling)."""
    for i, sensor in enumerate(sensors):
        spec.add_equality(
            name=f"{WELD_EQ_PREFIX}{i}",
            type=mujoco.mjtEq.mjEQ_WELD,
            objtype=mujoco.mjtObj.mjOBJ_BODY,
            name1=PREFIX + sensor.body,
            name2="world",
            active=False,
        )


class Climbing:
    """Grasp state of a climber's hands: grab, hold and release through the welds."""

    def __init__(
        self,
        model: mujoco.MjModel,
        sensors: Sequence[GraspSensor],
        creeper_half_depth: float,
    ):
        self.model = model
        self.nb_sensors = len(sensors)
        self.geom_ids = np.array([model.geom(PREFIX + s.geom).id for s in sensors], dtype=int)
        self.body_ids = np.array([model.body(PREFIX + s.body).id for s in sensors], dtype=int)
        self.eq_ids = np.array(
            [model.equality(f"{WELD_EQ_PREFIX}{i}").id for i in range(len(sensors))], dtype=int
        )
        self.radius = model.geom_rbound[self.geom_ids].copy()
        # the grasp point in the hand's frame (the sensor geom's centre)
        self.local_point = np.array(
            [
                model.geom_pos[g] if model.geom_bodyid[g] == b else np.zeros(3)
                for g, b in zip(self.geom_ids, self.body_ids)
            ]
        )
        self.creeper_half_depth = creeper_half_depth
        self.terrain: ParkourTerrain | None = None
        self.ready = np.zeros(self.nb_sensors, dtype=bool)
        self.holding = np.zeros(self.nb_sensors, dtype=bool)
        self.touching = np.zeros(self.nb_sensors, dtype=bool)
        self._quat = np.zeros(4)

    def reset(self, data: mujoco.MjData, terrain: ParkourTerrain) -> None:
        self.terrain = terrain
        data.eq_active[self.eq_ids] = 0
        self.ready[:] = self.holding[:] = self.touching[:] = False

    def before_step(self, data: mujoco.MjData, grasp_actions: np.ndarray) -> None:
        """Positive grasp action: ready to grab; otherwise release any hold."""
        self.ready = grasp_actions > 0
        release = self.holding & ~self.ready
        if release.any():
            data.eq_active[self.eq_ids[release]] = 0
            self.holding &= self.ready

    def after_step(self, data: mujoco.MjData) -> None:
        """Update touch flags; ready, free hands that touch a graspable surface grab it."""
        points = data.geom_xpos[self.geom_ids]
        self.touching = self._touches(points)
        grab = self.ready & ~self.holding & self.touching
        for i in np.flatnonzero(grab):
            self._grab(data, i, points[i])

    def state(self) -> np.ndarray:
        """Per sensor [touching a graspable surface, holding], as the original's sensor state."""
        return np.column_stack((self.touching, self.holding)).astype(np.float64).ravel()

    def _touches(self, points: np.ndarray) -> np.ndarray:
        t = self.terrain
        pad = self.radius + TOUCH_MARGIN
        x, y, z = points[:, 0], points[:, 1], points[:, 2]
        touch = z + self.radius + CEILING_MARGIN >= t.ceiling_at(x)
        if len(t.creepers):
            c = t.creepers
            inside = (
                (x[:, None] >= c[None, :, 0] - pad[:, None])
                & (x[:, None] <= c[None, :, 1] + pad[:, None])
                & (z[:, None] <= c[None, :, 2] + pad[:, None])
                & (z[:, None] >= c[None, :, 3] - pad[:, None])
                & (np.abs(y)[:, None] <= self.creeper_half_depth + pad[:, None])
            )
            touch |= inside.any(axis=1)
        return touch

    def _grab(self, data: mujoco.MjData, i: int, point: np.ndarray) -> None:
        eq = self.eq_ids[i]
        d = self.model.eq_data[eq]
        d[0:3] = point  # anchor in the world frame (body 2)
        d[3:6] = self.local_point[i]  # the same point in the hand's frame (body 1)
        mujoco.mju_negQuat(self._quat, data.xquat[self.body_ids[i]])
        d[6:10] = self._quat
        d[10] = 0.0  # torquescale 0: position-only, rotation free
        data.eq_active[eq] = 1
        self.holding[i] = True
