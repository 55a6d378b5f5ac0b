"""What 3D Terrain's raw physics would gain from other terrain geometry (MuJoCo Warp).

    python scripts/bench_terrain3d_collision.py                        # Warp's CPU device
    python scripts/bench_terrain3d_collision.py --device cuda --worlds 16384 --steps 50

3D Terrain's big quadruped steps its raw physics 4x slower on a GPU than the reference's one
flat terrain, and its heightfield collision was the suspect: one thread runs GJK over every
prism under a geom. This measures the routes that would change the terrain, on one device, in
interleaved rounds, against today's model (blocks stamped into a 0.1 x 0.2 m grid):

* the same field on coarser grids (0.2 x 0.2 m, the reference's; 0.5 x 0.5 m): the blocks
  become wedges;
* the ground alone on a 0.25 or 0.5 m grid, its blocks as box geoms (sunk 1 m into the ground,
  the same for every world: where they stand does not change what a contact costs);
* flat ground without blocks on today's grid, as the reference's terrain was (whether the
  rough ground's content, rather than its grid, is what costs);
* today's field as the env lays it out: a draw of its own in every world (the others repeat
  256 draws), then also MuJoCo Warp's reservations (the others: 192 constraint rows and 24
  contact slots a world), then also `bench_gpu.py`'s 20 steps before timing (the bodies still
  falling): where this bench's raw physics and `bench_gpu.py`'s part.

Every world plays the bench task of `bench_gpu.py` (roughness 0.1 m, full-width 0.3 m blocks
every 4.5 m), each with its own copy of the heights, with 192 constraint rows and 24 contact
slots; the bodies start on their feet, random controls fold them onto the ground in the
`--warmup` steps, then `--steps` are timed. Random controls do not carry the quadruped to the
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
from acl3d.envs.world_families import TERRAIN
from acl3d.sim.warp_backend import WarpSimulation
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

    def label(self, grid) -> str:
        label = f"{self.cell} x {self.row_cell} m grid ({grid.ncol} x {grid.nrow}), {self.holds}"
        if self.own_draws:
            label += ", one draw a world"
        if self.estimates:
            label += ", MuJoCo Warp's reservations"
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
    model.opt.timestep = CONTROL_DT / body.frame_skip
    n = worlds if v.own_draws else min(worlds, DRAWS)
    draws = np.stack([generator.heights(task, np.random.default_rng(i)) for i in range(n)])
    reserved = (None, None) if v.estimates else (192, 24)
    sim = WarpSimulation(model, worlds, body.frame_skip, TERRAIN, device, *reserved)
    rows = torch.as_tensor(arena.fractions(draws), device=sim.device, dtype=sim.dtype)
    world = torch.arange(worlds, device=sim.device)
    sim.terrain("terrain").copy_(rows[world % n])
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


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cpu")
    p.add_argument("--worlds", type=int, default=1024)
    p.add_argument("--steps", type=int, default=10)
    p.add_argument("--warmup", type=int, default=40)
    p.add_argument("--rounds", type=int, default=2)
    a = p.parse_args()
    rates: dict[str, list[float]] = defaultdict(list)
    shares: dict[str, float] = {}
    print(f"3D Terrain, big_quadru, {a.worlds} worlds on {a.device}, {a.steps} timed steps")
    for round_ in range(1, a.rounds + 1):
        for variant in VARIANTS:
            sim, label = build(variant, a.worlds, a.device)
            warmup = a.warmup if variant.warmup is None else variant.warmup
            rates[label].append(raw_rate(sim, a.steps, warmup))
            if label not in shares:
                times = kernel_times(sim, 3)
                hfield = sum(s for name, s in times.items() if HFIELD_KERNEL in name)
                shares[label] = hfield / sum(times.values())
            del sim
            # each measurement as it comes: a run cut short by a time limit keeps those done
            print(f"round {round_}: {rates[label][-1]:,.0f} env steps/s  {label}", flush=True)
    today = np.mean(next(iter(rates.values())))
    print(f"{'raw physics (env steps/s)':>28} {'against today':>14} {'heightfield':>12}  terrain")
    for label, values in rates.items():
        rounds = " / ".join(f"{v:,.0f}" for v in values)
        print(f"{rounds:>28} {np.mean(values) / today:>13.2f}x {shares[label]:>12.1%}  {label}")


if __name__ == "__main__":
    main()
