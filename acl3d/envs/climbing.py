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

The touch test and the release are written once over `ArrayOps` (`hand_touches`, `release`):
the many-world simulation runs them on torch (`acl3d.envs.tensor_parkour_rules`), where a grab
records its anchor for the per-world weld data instead of writing a model.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from acl3d.bodies.base import PREFIX, GraspSensor
from acl3d.envs.array_ops import NUMPY, ArrayOps
from acl3d.envs.parkour_lidar import CreeperBoxes, creeper_boxes

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
        self.arena = None  # this episode's (its ceiling line and creepers)
        self._held = np.full(self.nb_sensors, -1)  # creeper geom touched by each hand, -1: ceiling
        self.ready = np.zeros(self.nb_sensors, dtype=bool)
        self.holding = np.zeros(self.nb_sensors, dtype=bool)
        self.touching = np.zeros(self.nb_sensors, dtype=bool)
        self._quat = np.zeros(4)

    def reset(self, data: mujoco.MjData, arena) -> None:
        """New episode: everything released; the arena's creepers in use are graspable."""
        self.arena = arena
        data.eq_active[self.eq_ids] = 0
        self.ready[:] = self.holding[:] = self.touching[:] = False

    def before_step(self, data: mujoco.MjData, grasp_actions: np.ndarray) -> None:
        """Positive grasp action: ready to grab; otherwise release any hold."""
        before_steps([self], data.eq_active[None], grasp_actions[None])

    def after_step(self, data: mujoco.MjData) -> None:
        """Update touch flags; ready, free hands that touch a graspable surface grab it."""
        arena, xpos, xmat = self.arena, data.geom_xpos[None], data.geom_xmat[None]
        boxes = creeper_boxes(
            xpos, xmat, self.creeper_geoms, arena.creeper_size[None],
            arena.creeper_rbound[None], np.array([arena.nb_creeper_geoms]),
        )  # fmt: skip
        after_steps(
            [self], lambda i: data, xpos, xmat, arena.ceiling_heights[None], arena.grid, boxes
        )

    def state(self) -> np.ndarray:
        """Per sensor [touching a graspable surface, holding], as the original's sensor state."""
        return np.column_stack((self.touching, self.holding)).astype(np.float64).ravel()

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


def before_steps(climbings: Sequence[Climbing], eq_active: np.ndarray, grasp_actions) -> None:
    """`Climbing.before_step` of N envs' climbers at once: eq_active (N, neq) their weld flags,
    grasp_actions (N, hands)."""
    holding = np.stack([c.holding for c in climbings])
    ready, holding = release(grasp_actions, holding)
    eq_active[:, climbings[0].eq_ids] = holding
    for i, c in enumerate(climbings):
        c.ready, c.holding = ready[i], holding[i]


def release(grasp_actions, holding):
    """(ready, holding) (N, hands): a positive grasp action readies a hand to grab, any other
    releases its hold."""
    ready = grasp_actions > 0.0
    return ready, holding & ready


def after_steps(climbings, row_data, xpos, xmat, ceilings, grid, boxes: CreeperBoxes) -> None:
    """`Climbing.after_step` of N envs' climbers (of one body) at once: touch flags from the
    hands' poses in xpos (N, ngeom, 3), the envs' ceiling lines (N, ncol) on `grid` and their
    creeper boxes, then the grabs, each on its env's data (`row_data(i)`) and model."""
    first = climbings[0]
    points = xpos[:, first.geom_ids]  # (N, hands, 3)
    touching, inside = hand_touches(NUMPY, points, first.radius, ceilings, grid, boxes)
    held = np.full(touching.shape, -1)  # the creeper geom each hand touches (-1: the ceiling)
    if inside is not None:
        on_creeper = inside.any(axis=2) & ~touching  # the ceiling wins when both are touched
        held[on_creeper] = first.creeper_geoms[inside.argmax(axis=2)[on_creeper]]
        touching = touching | on_creeper
    for i, c in enumerate(climbings):
        c.touching, c._held = touching[i], held[i]
        for hand in np.flatnonzero(c.ready & ~c.holding & c.touching):
            c._grab(row_data(i), hand, points[i, hand], c._held[hand])


def hand_touches(ops: ArrayOps, points, radius, ceilings, grid, boxes: CreeperBoxes):
    """(touching the ceiling (N, hands), inside (N, hands, P): in a creeper box in use within
    reach, or None when no box is near any hand and `ops` can tell) for hands at `points`
    (N, hands, 3) of `radius` (hands,). Written once for numpy and torch."""
    xp = ops.xp
    pad = radius + TOUCH_MARGIN
    under = line_at(ops, ceilings, points[..., 0], grid)
    at_ceiling = points[..., 2] + radius + CEILING_MARGIN >= under
    rel = points[:, :, None, :] - boxes.centres[:, None]  # (N, hands, P, 3)
    reach = boxes.rbound + pad.max()  # a box's bounding radius, padded
    near = ((rel * rel).sum(axis=-1) <= (reach * reach)[:, None]).any(axis=1) & boxes.used
    if not ops.needed(near):
        return at_ceiling, None
    if boxes.rotations is not None:  # into each box's frame (swinging creepers)
        rel = xp.einsum("nspk,npkj->nspj", rel, boxes.rotations)
    box = boxes.half[:, None] + pad[None, :, None, None]
    return at_ceiling, (xp.abs(rel) <= box).all(axis=-1) & near[:, None]


def line_at(ops: ArrayOps, lines, x, grid):
    """Lines on the grid's columns (N, ncol) at x (N, k): linear, constant past their ends."""
    u = ops.clip((x - grid.x_min) / grid.cell, 0.0, grid.ncol - 1.0)
    j = ops.clip(ops.to_int(ops.xp.floor(u)), high=grid.ncol - 2)
    a, b = ops.gather(lines, j), ops.gather(lines, j + 1)
    return a + (u - j) * (b - a)
