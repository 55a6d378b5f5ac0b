"""Climbing: a climber's hands grasp the ceiling or a creeper through weld equalities.

The original creates a free revolute joint between a hand sensor and the grasped surface
(§2.6 of the reference). Here each hand has one weld equality to the world, compiled inactive;
grasping sets its anchors from the current poses (zero constraint error at the grab) and
activates it, with torquescale 0 so it pins the grasp point and leaves rotation free (the 3D
counterpart of the free revolute joint). Releasing deactivates it.

"Touch" is geometric, like the original's coarse AABB test: the sensor point, padded by its
radius + 1 cm, reaches the ceiling line or lies in a creeper box (in the box's own frame, so
swinging creeper segments work too). Creepers never collide with bodies, and a hand can grasp
the ceiling from slightly below it, so contacts are not needed. A weld holds the world (ceiling)
or the creeper's body: `model.eq_obj2id` is set at the grab. Anchors and targets live in the
model: each env compiles its own model, so envs never share them.
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
        self, model: mujoco.MjModel, sensors: Sequence[GraspSensor], creeper_geoms: np.ndarray
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
        self.creeper_geoms = creeper_geoms
        self._active = creeper_geoms[:0]
        self.terrain: ParkourTerrain | None = None
        self._held = np.full(self.nb_sensors, -1)  # creeper geom touched by each hand, -1: ceiling
        self.ready = np.zeros(self.nb_sensors, dtype=bool)
        self.holding = np.zeros(self.nb_sensors, dtype=bool)
        self.touching = np.zeros(self.nb_sensors, dtype=bool)
        self._quat = np.zeros(4)

    def reset(self, data: mujoco.MjData, terrain: ParkourTerrain, nb_creeper_geoms: int) -> None:
        """New episode: everything released; the first `nb_creeper_geoms` creeper geoms are in use."""
        self.terrain = terrain
        self._active = self.creeper_geoms[:nb_creeper_geoms]
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
        self.touching = self._touches(data, points)
        grab = self.ready & ~self.holding & self.touching
        for i in np.flatnonzero(grab):
            self._grab(data, i, points[i], self._held[i])

    def state(self) -> np.ndarray:
        """Per sensor [touching a graspable surface, holding], as the original's sensor state."""
        return np.column_stack((self.touching, self.holding)).astype(np.float64).ravel()

    def _touches(self, data: mujoco.MjData, points: np.ndarray) -> np.ndarray:
        """Per hand: touching the ceiling or a creeper (which one goes to `self._held`)."""
        pad = self.radius + TOUCH_MARGIN
        ceiling = points[:, 2] + self.radius + CEILING_MARGIN >= self.terrain.ceiling_at(
            points[:, 0]
        )
        self._held[:] = -1
        g = self._active
        if not len(g):
            return ceiling
        rel = points[:, None, :] - data.geom_xpos[g][None, :, :]
        reach = self.model.geom_rbound[g] + pad.max()
        near = (np.einsum("snk,snk->sn", rel, rel) <= reach * reach).any(axis=0)
        if not near.any():
            return ceiling
        g, rel = g[near], rel[:, near]
        local = np.einsum("snk,nkj->snj", rel, data.geom_xmat[g].reshape(-1, 3, 3))
        inside = np.all(np.abs(local) <= self.model.geom_size[g] + pad[:, None, None], axis=-1)
        on_creeper = inside.any(axis=1) & ~ceiling  # the ceiling wins when both are touched
        self._held[on_creeper] = g[inside.argmax(axis=1)[on_creeper]]
        return ceiling | on_creeper

    def _grab(self, data: mujoco.MjData, i: int, point: np.ndarray, creeper_geom: int) -> None:
        """Weld hand i where it is to the creeper's body (or the world: the ceiling)."""
        eq = self.eq_ids[i]
        target = int(self.model.geom_bodyid[creeper_geom]) if creeper_geom >= 0 else 0
        self.model.eq_obj2id[eq] = target
        d = self.model.eq_data[eq]
        rot = data.xmat[target].reshape(3, 3)
        d[0:3] = rot.T @ (point - data.xpos[target])  # the grasp point in the held body's frame
        d[3:6] = self.local_point[i]  # the same point in the hand's frame
        mujoco.mju_negQuat(self._quat, data.xquat[self.body_ids[i]])
        mujoco.mju_mulQuat(d[6:10], self._quat, data.xquat[target])
        d[10] = 0.0  # torquescale 0: position-only, rotation free
        data.eq_active[eq] = 1
        self.holding[i] = True
