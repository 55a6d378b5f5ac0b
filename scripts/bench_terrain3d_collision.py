"""What 3D Terrain's raw physics would gain from other terrain geometry (MuJoCo Warp).

    python scripts/bench_terrain3d_collision.py                        # Warp's CPU device
    python scripts/bench_terrain3d_collision.py --device cuda --worlds 16384 --steps 50

3D Terrain's big quadruped steps its raw physics 4x slower on a GPU than the reference's one
flat terrain, and its heightfield collision was the suspect: one thread runs GJK over every
prism under a geom. This measures the routes that would change the terrain, on one device, in
interleaved rounds, against "today's" model: blocks stamped into a 0.1 x 0.2 m grid, the default
when this bench was written (the default is 0.1 x 0.5 m since):

* the same field on coarser grids (0.2 x 0.2 m, the reference's; 0.5 x 0.5 m): the blocks
  become wedges;
* the ground alone on a 0.25 or 0.5 m grid, its blocks as box geoms (sunk 1 m into the ground,
  the same for every world: where they stand does not change what a contact costs);
* flat ground without blocks on today's grid, as the reference's terrain was (whether the
  rough ground's content, rather than its grid, is what costs);
* today's field as the env lays it out: a draw of its own in every world (the others repeat
  256 draws), then also MuJoCo Warp's reservations (the others: 192 constraint rows and 24
  contact slots a world), then also `bench_gpu.py`'s 20 steps before timing (the bodies still
  falling): where this bench's raw physics and `bench_gpu.py`'s part;
* today's field with each world's heightfield only as tall as its own highest point: MuJoCo
  Warp skips a geom above a heightfield's top without visiting its prisms, and at the compiled
  top (10 m above the ground) every geom visits every prism under its box;
* today's field cut along x into tiles 1 or 2 m long, each its own heightfield and geom (each
  as tall as its own ground): the same prisms, but one thread per geom and tile instead of one
  per geom, so that a body lying on the ground is no longer one thread's serial work.

On a GPU a kernel lasts as long as its slowest thread, on a CPU the sum of its threads: a
lying quadruped's hull meets hundreds of prisms in one thread, so the tiles may gain on a GPU
what they cannot show on a CPU.

Every world plays the bench task of `bench_gpu.py` (roughness 0.1 m, full-width 0.3 m blocks
every 4.5 m), each with its own copy of the heights, with 192 constraint rows and 24 contact
slots; the bodies start on their feet, random controls fold them onto the ground in the
`--warmup` steps (several values: each measured), then `--steps` are timed: random controls
fold the quadrupeds onto the ground over ~100 steps, and the heightfield's cost grows with it
(docs/benchmarks.md). Random controls do not carry the quadruped to the
first block, so the blocks' own contacts are not measured: what is measured is the ground's grid
and the geoms a world holds. The heightfield kernels' share of a step comes from
`profile_warp_kernels.py`'s timing.
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from typing import NamedTuple

import mujoco
import numpy as np
import torch
from bench_gpu import raw_rate
from profile_warp_kernels import HFIELD_KERNEL, kernel_times

from acl3d.bodies import make_body
from acl3d.envs.arena import CONTROL_DT
from acl3d.envs.terrain3d_arena import Terrain3DArena
from acl3d.sim.warp_backend import WarpSimulation, import_warp
from acl3d.sim.worlds import WorldFields
from acl3d.terrain.terrain3d import BLOCK_LENGTH, Terrain3DGenerator, start_pad_for

TASK = {"roughness": 0.1, "block_height": 0.3}  # bench_gpu.py's, without its ~0 degree slopes
SPACING = 4.0  # metres between blocks: the task space's default block_spacing
SINK = 1.0  # metres a box block reaches below the ground
DRAWS = 256  # distinct draws of the roughness, repeated over the worlds (0.3 ms each on a CPU)
FIELD, BOXES, FLAT = "blocks in the heightfield", "blocks as boxes", "flat, no blocks"


class Variant(NamedTuple):
    cell: float  # metres between the heightfield's points along x
    row_cell: float  # ... and across
    holds: str  # FIELD, BOXES or FLAT
    own_draws: bool = False  # each world its own draw of the roughness (else one of DRAWS)
    estimates: bool = False  # MuJoCo Warp's reservations (else 192 rows and 24 slots a world)
    warmup: int | None = None  # steps before timing (else --warmup)
    own_top: bool = False  # each world's heightfield (or tile) only as tall as its own ground
    tile: float | None = None  # metres: the field cut into tiles this long along x

    @property
    def slots(self) -> int | None:
        """Contact slots a world: 24, or MuJoCo Warp's estimate; a geom meets ~2 tiles."""
        return None if self.estimates else 48 if self.tile else 24

    def label(self, grid) -> str:
        label = f"{self.cell} x {self.row_cell} m grid ({grid.ncol} x {grid.nrow}), {self.holds}"
        if self.own_draws:
            label += ", one draw a world"
        if self.estimates:
            label += ", MuJoCo Warp's reservations"
        if self.tile:
            label += f", {self.tile:g} m tiles"
        elif self.own_top:
            label += ", each world's field only as tall as its ground"
        return label + (f", {self.warmup} steps first" if self.warmup is not None else "")


VARIANTS = (
    Variant(0.1, 0.2, FIELD),
    Variant(0.2, 0.2, FIELD),
    Variant(0.5, 0.5, FIELD),
    Variant(0.25, 0.25, BOXES),
    Variant(0.5, 0.5, BOXES),
    Variant(0.1, 0.2, FLAT),
    Variant(0.1, 0.2, FIELD, own_draws=True),
    Variant(0.1, 0.2, FIELD, own_draws=True, estimates=True),
    Variant(0.1, 0.2, FIELD, own_draws=True, estimates=True, warmup=20),
    Variant(0.1, 0.2, FIELD, own_draws=True, own_top=True),
    Variant(0.1, 0.2, FIELD, own_draws=True, own_top=True, tile=2.0),
    Variant(0.1, 0.2, FIELD, own_draws=True, own_top=True, tile=1.0),
)


def build(v: Variant, worlds: int, device: str):
    """(simulation, label): big_quadru on its start pad in every world, the bench task's field
    as variant `v` lays it out."""
    body = make_body("big_quadru")
    generator = Terrain3DGenerator(start_pad_for(body.length), v.cell, v.row_cell)
    arena = Terrain3DArena(body, generator)
    model, task = arena.model, TASK
    if v.holds == BOXES:
        model, task = _with_box_blocks(arena), {**TASK, "block_height": 0.0}
    elif v.holds == FLAT:
        task = {"roughness": 0.0, "block_height": 0.0}
    spans = {"terrain": slice(None)}
    if v.tile:
        model, spans = _tiled(arena, v.tile)
    model.opt.timestep = CONTROL_DT / body.frame_skip
    n = worlds if v.own_draws else min(worlds, DRAWS)
    draws = np.stack([generator.heights(task, np.random.default_rng(i)) for i in range(n)])
    fields = WorldFields(tuple(spans), tuple(spans), force_caps=True)
    sim = WarpSimulation(
        model, worlds, body.frame_skip, fields, device, None if v.estimates else 192, v.slots
    )
    rows = torch.as_tensor(arena.fractions(draws), device=sim.device, dtype=sim.dtype)
    world = torch.arange(worlds, device=sim.device)
    for name, columns in spans.items():
        sim.terrain(name).copy_(rows[world % n][:, :, columns])
    if v.own_top:
        _own_tops(sim, model, tuple(spans))
    data = mujoco.MjData(model)
    arena.bound.place(data, arena.start_x, body.spawn_height)
    qpos = torch.as_tensor(data.qpos, device=sim.device).expand(worlds, -1)
    qvel = torch.zeros((worlds, model.nv), device=sim.device)
    sim.reset_worlds(world, qpos, qvel)
    return sim, v.label(generator.grid)


def _with_box_blocks(arena: Terrain3DArena) -> mujoco.MjModel:
    """The arena's model with the task's full-width blocks as box geoms that collide as the
    terrain does."""
    spec, generator = arena.spec, arena.generator
    terrain, height = spec.geom("terrain"), TASK["block_height"]
    for k, x in enumerate(generator.block_starts(SPACING)):
        spec.worldbody.add_geom(
            name=f"block{k}", type=mujoco.mjtGeom.mjGEOM_BOX,
            size=[BLOCK_LENGTH / 2, generator.grid.half_width, (height + SINK) / 2],
            pos=[x + BLOCK_LENGTH / 2, 0.0, (height - SINK) / 2],
            contype=terrain.contype, conaffinity=terrain.conaffinity, friction=terrain.friction,
        )  # fmt: skip
    return spec.compile()


def _tiled(arena: Terrain3DArena, tile: float) -> tuple[mujoco.MjModel, dict[str, slice]]:
    """The arena's model with its heightfield cut along x into heightfields `tile` m long (the
    last shorter), neighbours sharing their edge column; and each tile's columns of the field."""
    spec, g = arena.spec, arena.generator.grid
    terrain = spec.geom("terrain")
    whole = spec.hfield("terrain")
    per = max(1, round(tile / g.cell))  # cells a tile
    spans = {}
    for k, first in enumerate(range(0, g.ncol - 1, per)):
        last = min(first + per, g.ncol - 1)
        name, ncol = f"tile{k}", last - first + 1
        spec.add_hfield(
            name=name, nrow=g.nrow, ncol=ncol, userdata=np.zeros(g.nrow * ncol),
            size=[(last - first) * g.cell / 2, g.half_width, whole.size[2], whole.size[3]],
        )  # fmt: skip
        spec.worldbody.add_geom(
            name=name, type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname=name,
            pos=[g.x_min + (first + last) * g.cell / 2, 0.0, terrain.pos[2]],
            contype=terrain.contype, conaffinity=terrain.conaffinity, condim=terrain.condim,
            friction=terrain.friction, solref=terrain.solref, solimp=terrain.solimp,
        )  # fmt: skip
        spans[name] = slice(first, last + 1)
    spec.delete(terrain)
    return spec.compile(), spans


def _own_tops(sim: WarpSimulation, model: mujoco.MjModel, names: tuple[str, ...]) -> None:
    """Each world's copy of each heightfield only as tall as its own highest point: the same
    heights, stored as fractions of that top, which goes into the copy's `hfield_size`. Reaches
    into MuJoCo Warp's model: world w's copy of the j-th declared heightfield is entry
    `model.nhfield + j * N + w` (`WarpSimulation._route_terrain`)."""
    sizes = import_warp()[0].to_torch(sim.m.hfield_size)
    for j, name in enumerate(names):
        data = sim.terrain(name)
        copies = slice(model.nhfield + j * sim.nworld, model.nhfield + (j + 1) * sim.nworld)
        tops = data.flatten(1).amax(1).clamp_min(1e-6)  # fractions of the compiled top
        data.copy_(data / tops[:, None, None])
        sizes[copies, 2] *= tops


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cpu")
    p.add_argument("--worlds", type=int, default=1024)
    p.add_argument("--steps", type=int, default=10)
    p.add_argument(
        "--warmup", type=int, nargs="+", default=[40], help="steps before timing, each measured"
    )  # fmt: skip
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument(
        "--variants", type=int, nargs="+", metavar="K",
        help=f"measure only these variants (0-{len(VARIANTS) - 1}, in the docstring's order; "
        "0, today's terrain, is always measured: the others' reference)",
    )  # fmt: skip
    a = p.parse_args()
    chosen = [VARIANTS[k] for k in sorted({0, *(a.variants or range(len(VARIANTS)))})]
    rates: dict[tuple[int, str], list[float]] = defaultdict(list)
    shares: dict[tuple[int, str], float] = {}
    print(f"3D Terrain, big_quadru, {a.worlds} worlds on {a.device}, {a.steps} timed steps")
    for round_ in range(1, a.rounds + 1):
        for variant in chosen:
            for warmup in a.warmup if variant.warmup is None else [variant.warmup]:
                sim, label = build(variant, a.worlds, a.device)
                key = (warmup, label)
                rates[key].append(raw_rate(sim, a.steps, warmup))
                if key not in shares:
                    times = kernel_times(sim, 3)
                    hfield = sum(s for name, s in times.items() if HFIELD_KERNEL in name)
                    shares[key] = hfield / sum(times.values())
                del sim
                # each measurement as it comes: a run cut short by a time limit keeps those done
                print(f"round {round_}: {rates[key][-1]:,.0f} env steps/s  {label}, timed after "
                      f"{warmup} steps", flush=True)  # fmt: skip
    print(f"{'raw physics (env steps/s)':>28} {'against today':>14} {'heightfield':>12}  "
          "steps first, terrain")  # fmt: skip
    today_label = next(iter(rates))[1]  # variant 0's, measured first
    for (warmup, label), values in rates.items():
        # against today's terrain after as many steps (or after the first --warmup)
        today = np.mean(rates.get((warmup, today_label), rates[a.warmup[0], today_label]))
        rounds = " / ".join(f"{v:,.0f}" for v in values)
        print(f"{rounds:>28} {np.mean(values) / today:>13.2f}x {shares[warmup, label]:>12.1%}  "
              f"{warmup:>4}  {label}")  # fmt: skip


if __name__ == "__main__":
    main()
