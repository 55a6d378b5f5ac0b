"""Parkour's rules on torch tensors: the N worlds of the many-world simulation.

The rules shared with the CPU envs run here on torch: the tracks' part (`TrackRules`: head, motor
state, shaping, servos), the typed lidar (`ParkourLidar.cast`, on the records' lines and boxes),
the water forces (`Water.forces`), the climbers' touch test and release (`hand_touches`,
`release`), the survival counters and critical contacts (`count_survival`, `critical_touch`).
What is this module's own: reading and writing them through each world's record, dead bodies
playing zeros, and a grab's anchor (welded to the world: creepers are static), for all worlds at
once with no per-world Python and no host round trip; tests/test_many_worlds_parkour.py checks it
against the CPU env on the same physics.

Each world's episode lives in one float row, its *record* (`ParkourRecord`: ground and ceiling
lines, water level, creeper boxes, survival counters, grasp flags and anchors, the water forces
for the next step), which `ManyWorlds` keeps where the tracks keep their height lines: it is
written at resets, copied to the start worlds and saved in checkpoints. The simulation's
per-world Parkour fields (the ceiling heightfield, `eq_active`, the weld anchors and
`xfrc_applied`) are written from it before every step, so the record is their one source.
Creepers are static boxes (their geoms never collide): their poses are read from the record.
"""

from __future__ import annotations

import numpy as np
import torch

from acl3d.envs.array_ops import TorchOps
from acl3d.envs.climbing import hand_touches, release
from acl3d.envs.parkour_arena import CEILING_RANGE, CREEPER_HALF_DEPTH
from acl3d.envs.parkour_lidar import CreeperBoxes, ParkourLidar
from acl3d.envs.parkour_rules import ParkourRules, count_survival, critical_touch
from acl3d.envs.track_rules import FAIL_REWARD, Outcome, TrackRules, torque_use
from acl3d.sim.worlds import Simulation


class ParkourRecord:
    """Column layout of a world's record (see the module docstring)."""

    def __init__(self, ncol: int, pool: int, hands: int, bodies: int):
        widths = {
            "ground": ncol, "ceiling": ncol, "water": 1,
            "creepers": 4 * pool,  # centre x, centre z, half width, half height (0: unused)
            "survival": 3,  # steps under water, steps out of water, dead
            "ready": hands, "holding": hands, "touching": hands, "anchors": 3 * hands,
            "forces": 3 * bodies,  # water forces for the next step: fx, fz, torque y per body
        }  # fmt: skip
        self.slices, start = {}, 0
        for name, width in widths.items():
            self.slices[name] = slice(start, start + width)
            start += width
        self.width = start

    def terrain_row(self, ground, ceiling, water_z: float, creepers) -> np.ndarray:
        """A new episode's record: lines on the grid's columns, creepers (k, 4) as the
        generator gives them (x left, x right, z top, z bottom), counters and grasps cleared."""
        row = np.zeros(self.width)
        row[self.slices["ground"]], row[self.slices["ceiling"]] = ground, ceiling
        row[self.slices["water"]] = water_z
        boxes = row[self.slices["creepers"]].reshape(-1, 4)[: len(creepers)]
        boxes[:, 0] = (creepers[:, 0] + creepers[:, 1]) / 2
        boxes[:, 1] = (creepers[:, 2] + creepers[:, 3]) / 2
        boxes[:, 2] = (creepers[:, 1] - creepers[:, 0]) / 2
        boxes[:, 3] = (creepers[:, 2] - creepers[:, 3]) / 2
        return row

    def __call__(self, record: torch.Tensor, name: str) -> torch.Tensor:
        """The (N, width) view of one part of (N, record width) records."""
        return record[:, self.slices[name]]

    def creepers(self, record: torch.Tensor):
        """(centre x, centre z, half width, half height, used) of each creeper box (N, pool)."""
        c = self(record, "creepers").unflatten(1, (-1, 4))
        return c[..., 0], c[..., 1], c[..., 2], c[..., 3], c[..., 2] > 0.0


class TensorParkourLidar:
    """`ParkourLidar.cast` on the worlds' records (its rows of heights): reads (N, 2 rays),
    fractions then surface flags."""

    reads_height_rows = True

    def __init__(self, lidar: ParkourLidar, record: ParkourRecord, ops: TorchOps):
        self.ops, self.record = ops, record
        self.lidar = lidar.on(ops)
        self.nb_rays = 2 * lidar.nb_rays

    def batch_heights(self, n: int) -> torch.Tensor:
        return self.ops.full((n, self.record.width), 0.0)

    def read_batch(self, record: torch.Tensor, origins: torch.Tensor, rotations=None):
        rec = self.record
        fractions, flags = self.lidar.cast(
            rec(record, "ground"), rec(record, "ceiling"), rec(record, "water")[:, 0], origins,
            self.creeper_boxes(record),
        )  # fmt: skip
        return torch.cat((fractions, flags), dim=1)

    def creeper_boxes(self, record: torch.Tensor) -> CreeperBoxes:
        """The worlds' creeper boxes from their records: static, upright, at y = 0."""
        cx, cz, hx, hz, used = self.record.creepers(record)
        half = torch.stack((hx, torch.full_like(hx, CREEPER_HALF_DEPTH), hz), -1)
        centres = torch.stack((cx, torch.zeros_like(cx), cz), -1)
        return CreeperBoxes(centres, None, half, half.norm(dim=-1), used)


class TensorParkourRules(TrackRules):
    """Parkour's rules for N worlds of a `Simulation` (see the module docstring).

    Args:
        rules: the compiled env's `ParkourRules` (static creepers).
        ops: the torch device and precision the worlds' tensors live in.
    """

    def __init__(self, rules: ParkourRules, ops: TorchOps):
        arena = rules.arena
        device, dtype = ops.device, ops.dtype
        self.climbing = arena.climbing
        hands = self.climbing.nb_sensors if self.climbing else 0
        self.water = arena.water.on(ops)
        self.record = ParkourRecord(
            arena.grid.ncol, len(arena.creeper_geoms), hands, len(self.water.body_ids)
        )
        sensor = TensorParkourLidar(rules.lidar, self.record, ops)
        super().__init__(rules.bound, sensor, rules.end_x, rules.success_return)
        f = {"device": device, "dtype": dtype}
        self.hands, self.kind, self.end_on_death = hands, rules.kind, rules.end_on_death
        self.grid = arena.grid
        self.survival_steps = rules.survival_steps
        self.critical_any = ops.index(rules._critical_any)
        self.critical_ceiling = ops.index(rules._critical_ceiling)
        self.ceiling_lo, self.ceiling_hi = CEILING_RANGE
        if hands:
            c = self.climbing
            self.hand_geoms, self.eq_ids = ops.index(c.geom_ids), ops.index(c.eq_ids)
            self.radius = torch.as_tensor(c.radius).to(**f)
            self.weld = torch.zeros((hands, 12), **f)  # hand point, identity quaternion
            self.weld[:, 3:6] = torch.as_tensor(c.local_point).to(**f)
            self.weld[:, 6] = 1.0  # torquescale 0 (column 10): the grasp pins a point only

    def extra_obs_size(self) -> int:
        return 2  # under water, dead (the lidar's reading holds the surface flags)

    # ------------------------------------------------------------------ before physics
    def before_physics(self, sim: Simulation, actions: torch.Tensor, heights: torch.Tensor):
        """Dead bodies play zeros; climbers release what their grasp actions let go; the
        world's Parkour fields are written from its record (see the module docstring)."""
        rec = self.record
        dead = rec(heights, "survival")[:, 2:3] > 0.0
        actions = actions.masked_fill(dead, 0.0)
        ceiling = rec(heights, "ceiling")
        rows = ((self.ceiling_hi - ceiling) / (self.ceiling_hi - self.ceiling_lo)).clamp(0.0, 1.0)
        sim.terrain("ceiling").copy_(rows[:, None, :].expand_as(sim.terrain("ceiling")))
        xfrc = sim.field("xfrc_applied")
        xfrc[:, self.water.body_ids, 0::2] = rec(heights, "forces").unflatten(1, (-1, 3))
        if self.hands:
            ready, holding = release(actions[:, -self.hands :], rec(heights, "holding") > 0.0)
            rec(heights, "ready").copy_(ready)
            rec(heights, "holding").copy_(holding)
            sim.field("eq_active")[:, self.eq_ids] = holding
            weld = self.weld.expand(len(actions), -1, -1).clone()
            weld[..., 0:3] = rec(heights, "anchors").unflatten(1, (-1, 3))
            sim.weld_anchors()[:, self.eq_ids] = weld
        return actions

    # ------------------------------------------------------------------ after physics
    def _grasp(self, sim: Simulation, record: torch.Tensor) -> None:
        """Touch flags; ready, free hands touching the ceiling or a creeper grab it where they
        are (a weld to the world: creepers are static)."""
        rec = self.record
        points = sim.field("geom_xpos")[:, self.hand_geoms]  # (N, hands, 3)
        at_ceiling, inside = hand_touches(
            self.ops, points, self.radius, rec(record, "ceiling"), self.grid,
            self.lidar.creeper_boxes(record),
        )  # fmt: skip
        touching = at_ceiling | inside.any(axis=2)
        rec(record, "touching").copy_(touching)
        ready, holding = rec(record, "ready") > 0.0, rec(record, "holding") > 0.0
        grab = ready & ~holding & touching
        anchors = rec(record, "anchors").unflatten(1, (-1, 3))
        anchors.copy_(torch.where(grab[..., None], points, anchors))
        holding |= grab
        rec(record, "holding").copy_(holding)

    def _survive(self, sim: Simulation, record: torch.Tensor) -> torch.Tensor:
        """Count consecutive steps in/out of water; (N,) flags: the body died this step."""
        survival = self.record(record, "survival")
        below, above, dead = survival.unbind(1)
        under = sim.field("xpos")[:, self._root, 2] <= self.record(record, "water")[:, 0]
        alive = dead == 0.0
        below, above, died = count_survival(
            torch, self.kind, self.survival_steps, under, below, above, alive
        )
        survival.copy_(torch.stack((below, above, (~alive | died).to(below.dtype)), dim=1))
        return died

    def observe(self, sim: Simulation, heights: torch.Tensor):
        """Parkour's layout: head, under water, dead, motor state, per hand (touching, holding),
        lidar fractions, surface flags."""
        x, track = super().observe(sim, heights)  # head, motor state, zero grasps, readings
        rec, head, grasp = self.record, self.head_size, self._lidar_col - self.grasp_size
        under = sim.field("xpos")[:, self._root, 2] <= rec(heights, "water")[:, 0]
        dead = rec(heights, "survival")[:, 2]
        hands = torch.stack((rec(heights, "touching"), rec(heights, "holding")), 2).flatten(1)
        obs = torch.cat(
            (
                track[:, :head],
                under[:, None].to(self.ops.dtype),
                dead[:, None],
                track[:, head:grasp],
                hands,
                track[:, self._lidar_col : self._lidar_col + self.lidar.nb_rays],
            ),
            dim=1,
        )
        return x, obs

    def critical(self, sim: Simulation) -> torch.Tensor:
        return critical_touch(sim.field("sensordata"), self.critical_any, self.critical_ceiling)

    def outcome(self, sim: Simulation, actions, heights, prev_shaping) -> Outcome:
        rec = self.record
        if self.hands:
            self._grasp(sim, heights)
        alive = rec(heights, "survival")[:, 2] == 0.0  # dead bodies played zeros: no cost
        died = self._survive(sim, heights)
        x, obs = self.observe(sim, heights)
        shaping = self.potential(sim, x, obs)
        cost = self.body.torque_cost_per_unit * torque_use(self.ops, actions)
        reward = shaping - prev_shaping - torch.where(alive, cost, 0.0)
        critical = self.critical(sim)
        fail = critical | (x < 0.0)
        terminated = fail | (x > self.end_x)
        if self.end_on_death:
            terminated = terminated | died
        level = rec(heights, "water")[:, 0]
        rec(heights, "forces").copy_(self.water.forces(sim, level)[0].flatten(1))
        reward = torch.where(fail, FAIL_REWARD, reward)
        return Outcome(obs, reward, terminated, shaping, critical)
