"""How much heightfield work each collision thread of a many-world physics step does.

    python scripts/hfield_work.py                          # 3D Terrain, 256 worlds
    python scripts/hfield_work.py --worlds 128 --ages 0 40 80 120 160 --tiles 2 1
    python scripts/hfield_work.py --env stump-tracks --tiles   # another family, no tiles
    python scripts/hfield_work.py --worlds 64 --tiles --by-geom  # which geoms send the prisms

MuJoCo Warp collides a geom with a heightfield in one thread: it visits every prism under the
geom's bounding box (a cheap height test each) and runs GJK on those that reach the geom's
lowest point (EPA too where they touch). On a GPU a kernel lasts as long as its slowest thread,
on a CPU the sum of all, so where that work lies decides what a change gains on each. This
counts it, the way MuJoCo Warp's `ccd_hfield` kernel bounds it, from the worlds' states (CPU
MuJoCo's kinematics on each world's qpos and its own heights):

* raw physics at the ages given (random controls from the placed bodies, no rules, no resets:
  `bench_gpu.py`'s raw physics), then the env's steady state (`ManyWorlds.step`, its rules
  ending episodes: a quadruped whose hull touches the ground is reset), `--snapshots` states
  20 steps apart pooled;
* per collision pair (a body geom against the field, or against one tile of it when the field
  is cut into `--tiles` metres along x, as `bench_terrain3d_collision.py`'s tile variants):
  the prisms visited (the field as tall as the compiled one, and were each world's copy only as
  tall as its own ground) and those given to GJK: their mean, 99th percentile and maximum; and
  the heightfield kernel's time on Warp's CPU device;
* with `--by-geom`, the prisms each body geom sends to GJK (a world's mean, and its worst pair).
"""

from __future__ import annotations

import argparse

import mujoco
import numpy as np
import torch
from bench_gpu import add_env_arguments, make_env
from profile_warp_kernels import HFIELD_KERNEL, kernel_times

from acl3d.cli.option_values import key_values


def pair_work(env, tile_cols: int | None) -> np.ndarray:
    """(pairs, 4): prisms visited and prisms given to GJK by each (geom, field or tile) pair
    of every world, as `ccd_hfield` bounds them (the geom's box in the field's frame, the prisms
    with a top point at or above the geom's lowest point), the field as tall as the compiled one;
    then the prisms visited were each field (or tile) only as tall as its own highest point
    (none where the geom is above it); then the pair's geom."""
    model, sim = env.template.model, env.sim
    data = mujoco.MjData(model)
    field = model.geom("terrain")
    hfield = model.hfield(field.dataid[0])
    half_x, half_y, top = hfield.size[:3]
    ncol, nrow = int(hfield.ncol[0]), int(hfield.nrow[0])
    heights = sim.terrain("terrain").cpu().numpy() * top
    qpos = sim.field("qpos").cpu().numpy()
    per_x, per_y = (ncol - 1) / (2 * half_x), (nrow - 1) / (2 * half_y)
    per_tile = tile_cols or ncol  # columns of cells a tile (the whole field: one tile)
    geoms = [
        g for g in range(model.ngeom) if model.geom_bodyid[g] > 0 and model.geom_conaffinity[g]
    ]
    work = []
    for w in range(sim.nworld):
        data.qpos[:] = qpos[w]
        mujoco.mj_kinematics(model, data)
        for g in geoms:
            lo, hi = _box(model, data, g, field.pos)
            cmin, cmax = (
                max(0, int(np.floor((lo[0] + half_x) * per_x))),
                min(ncol - 1, int(np.ceil((hi[0] + half_x) * per_x))),
            )
            rmin, rmax = (
                max(0, int(np.floor((lo[1] + half_y) * per_y))),
                min(nrow - 1, int(np.ceil((hi[1] + half_y) * per_y))),
            )
            if rmax <= rmin or cmax <= cmin:
                continue
            up = heights[w, rmin : rmax + 1, cmin : cmax + 1] >= lo[2]
            reaching = _reaching(up)
            tiles = np.arange(cmin, cmax) // per_tile
            for t in np.unique(tiles):
                on = tiles == t
                visited = int(on.sum()) * (rmax - rmin) * 2
                span = slice(t * per_tile, (t + 1) * per_tile + 1)
                below = heights[w, :, span].max() < lo[2]
                work.append((visited, int(reaching[on].sum()), 0 if below else visited, g))
    return np.array(work)


def _reaching(up: np.ndarray) -> np.ndarray:
    """Prisms given to GJK in each column of cells of a subgrid, from `up` (rows + 1, columns +
    1: the points at or above the geom's lowest point): `ccd_hfield` splits the cell between
    columns j and j + 1 of rows r and r + 1 into the triangles {(r+1, j), (r, j), (r+1, j+1)}
    and {(r, j), (r+1, j+1), (r, j+1)}, and skips a prism when its triangle's three points are
    all below."""
    first = up[1:, :-1] | up[:-1, :-1] | up[1:, 1:]
    second = up[:-1, :-1] | up[1:, 1:] | up[:-1, 1:]
    return first.sum(0) + second.sum(0)


def _box(model, data, g: int, field_pos) -> tuple[np.ndarray, np.ndarray]:
    """Geom g's axis-aligned box in the field's frame (the field is not rotated), from its
    extreme points as MuJoCo Warp's support functions give them."""
    centre, rot = data.geom_xpos[g] - field_pos, data.geom_xmat[g].reshape(3, 3)
    kind = model.geom_type[g]
    if kind == mujoco.mjtGeom.mjGEOM_MESH:
        mesh = model.geom_dataid[g]
        start = model.mesh_vertadr[mesh]
        points = model.mesh_vert[start : start + model.mesh_vertnum[mesh]] @ rot.T
        return centre + points.min(0), centre + points.max(0)
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        radius, half_length = model.geom_size[g][:2]
        extent = np.abs(rot[:, 2]) * half_length + radius
    elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        extent = np.full(3, model.geom_size[g][0])
    else:  # a box (other primitives: the box around them)
        extent = np.abs(rot) @ model.geom_size[g]
    return centre - extent, centre + extent


STATE = ("qpos", "qvel", "qacc_warmstart", "time")
WORK = ("prisms visited", "prisms to GJK", "prisms visited, were each top its own")


def measure(env, tiles: list[float]) -> tuple[float, float, dict]:
    """(heightfield kernel ms a step, its share of the kernels, {tile length or None: pair
    work}) of the worlds' present state, which is left as it was."""
    saved = {name: env.sim.field(name).clone() for name in STATE}
    times = kernel_times(env.sim, 2)  # 2 raw steps on from this state, then back to it
    for name, value in saved.items():
        env.sim.field(name).copy_(value)
    hfield = sum(s for name, s in times.items() if HFIELD_KERNEL in name)
    cell = env.template.arena.grid.cell
    work = {
        tile: pair_work(env, None if tile is None else max(1, round(tile / cell)))
        for tile in [None, *tiles]
    }
    return 1000 * hfield / 2, hfield / sum(times.values()), work


def report(label: str, env, measures: list[tuple[float, float, dict]], by_geom: bool) -> None:
    """Print `measure`s of one kind of state (several: their mean kernel time, pairs pooled)."""
    ms, share = np.mean([m[0] for m in measures]), np.mean([m[1] for m in measures])
    print(f"{label}: heightfield kernel {ms:.1f} ms a step ({share:.0%} of the kernels)")
    for tile in measures[0][2]:
        work = np.concatenate([m[2][tile] for m in measures])
        worlds = env.num_envs * len(measures)
        where = "whole field" if tile is None else f"{tile:g} m tiles"
        print(f"  {where}: {len(work) / worlds:.1f} pairs a world, "
              f"GJK {work[:, 1].sum() / worlds:.1f} prisms a world")  # fmt: skip
        for column, what in enumerate(WORK):
            values = work[:, column]
            print(f"    {what:>34}: mean {values.mean():6.1f}  p99 "
                  f"{np.percentile(values, 99):5.0f}  max {values.max():5d}")  # fmt: skip
        if by_geom and tile is None:
            model = env.template.model
            for g in np.unique(work[:, 3]):
                gjk = work[work[:, 3] == g, 1]
                print(f"    {model.geom(int(g)).name:>34}: GJK {gjk.sum() / worlds:5.1f} a world, "
                      f"worst pair {gjk.max():4d}")  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_env_arguments(p, "terrain3d", "big_quadru on terrain3d, else the env's")
    p.add_argument("--worlds", type=int, default=256)
    p.add_argument("--ages", type=int, nargs="+", default=[40, 120], help="raw physics steps")
    p.add_argument("--env-steps", type=int, default=300, help="env steps to its steady state")
    p.add_argument("--snapshots", type=int, default=5, help="env states measured, 20 steps apart")
    p.add_argument("--tiles", type=float, nargs="*", default=[2.0, 1.0], help="tile lengths, m")
    p.add_argument("--by-geom", action="store_true", help="prisms to GJK by body geom")
    a = p.parse_args()
    body = a.body or ("big_quadru" if a.env == "terrain3d" else None)
    env_kwargs = key_values(a.env_kwarg, "--env-kwarg")
    env = make_env(a.worlds, "cpu", a.env, body, 192, 48, env_kwargs)
    ctrl, g = env.sim.field("ctrl"), torch.Generator().manual_seed(1)
    options = "".join(f", {k}={v}" for k, v in env_kwargs.items())
    print(f"{a.env}, {body or 'its default body'}{options}, {a.worlds} worlds (bench_gpu.py's task) on "
          "Warp's CPU device")  # fmt: skip
    age = 0
    for target in sorted(a.ages):
        for _ in range(target - age):
            ctrl.copy_(torch.rand(ctrl.shape, generator=g) * 2 - 1)
            env.sim.step()
        age = target
        report(f"raw physics after {age} steps", env, [measure(env, a.tiles)], a.by_geom)
    env.reset(seed=0)
    measures, ages = [], []
    for step in range(a.env_steps + 20 * (a.snapshots - 1) + 1):
        if step >= a.env_steps and (step - a.env_steps) % 20 == 0:
            measures.append(measure(env, a.tiles))
            ages.append(float(env.elapsed.float().mean()))
        env.step(torch.rand((env.num_envs, env.action_size), generator=g) * 2 - 1)
    report(f"env, {a.snapshots} states from step {a.env_steps} (episodes {np.mean(ages):.0f} "
           "steps old on average)", env, measures, a.by_geom)  # fmt: skip


if __name__ == "__main__":
    main()
