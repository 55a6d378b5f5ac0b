"""What one step's rules cost on each array library: the rules (written once over the Array API)
on the CPU path's numpy arrays against the same rules on the many-world simulation's torch
tensors, on the CPU.

    python scripts/bench_rules.py [--env stump-tracks] [--sizes 1 64] [--steps 300]

Per size, in one run, one torch thread, after a few warm-up steps, best of `--rounds`:
* numpy: `servo` + `step` of the env's rules (or Parkour's / 3D Terrain's) on a single env
  (size 1) or the batched env's rows (larger sizes), as the CPU path calls them;
* torch: `before_physics` + `servo` + `outcome` of the family's rules on torch on a many-world
  simulation on Warp's CPU device (its first run compiles Warp's CPU kernels, then cached).
Only the rules are timed; the physics does not step between calls (the rules only read it), so
both read the same state every time. Ratios are torch / numpy at the same size.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from acl3d.envs.batched import BatchedEnvs
from acl3d.envs.many_worlds import many_worlds


def best_of(call, steps: int, rounds: int) -> float:
    """Best seconds per call over `rounds` rounds of `steps` calls."""
    times = []
    for _ in range(rounds):
        start = time.perf_counter()
        for _ in range(steps):
            call()
        times.append((time.perf_counter() - start) / steps)
    return min(times)


def numpy_rules(env: str, n: int, steps: int, rounds: int) -> float:
    vec = BatchedEnvs(env, n, threads=1)
    try:
        vec.reset(seed=0)
        rng = np.random.default_rng(0)
        actions = rng.uniform(-1.0, 1.0, (n, vec.action_size))
        vec.step(actions)
        sub = vec.envs[0]
        rules, rows = (sub.rules, sub.rows) if n == 1 else (vec.rules, vec.rows)

        def call():
            rules.servo(rules.before_physics(vec.physics, actions, rows), vec.physics)
            rules.step(vec.physics, actions, rows)

        return best_of(call, steps, rounds)
    finally:
        vec.close()


def torch_rules(env: str, n: int, steps: int, rounds: int) -> float:
    worlds = many_worlds(env, n, "cpu")
    try:
        worlds.reset(seed=0)
        actions = torch.rand((n, worlds.action_size), generator=torch.Generator().manual_seed(0))
        actions = (2.0 * actions - 1.0).to(worlds.sim.dtype)
        worlds.step(actions)
        rules, sim, heights = worlds.rules, worlds.sim, worlds.heights

        def call():
            rules.servo(rules.before_physics(sim, actions, heights), sim)
            rules.outcome(sim, actions, heights, worlds.prev_shaping)

        return best_of(call, steps, rounds)
    finally:
        worlds.close()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument(
        "--env", default="stump-tracks", choices=["stump-tracks", "terrain3d", "parkour"]
    )
    p.add_argument("--sizes", type=int, nargs="+", default=[1, 64])
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--rounds", type=int, default=5)
    args = p.parse_args()
    for name in ("steps", "rounds"):
        if getattr(args, name) < 1:
            p.error(f"--{name}: {getattr(args, name)} (allowed: >= 1)")
    if min(args.sizes) < 1:
        p.error(f"--sizes: {args.sizes} (allowed: integers >= 1)")
    torch.set_num_threads(1)
    print(f"{args.env}: one step's rules, microseconds (best of {args.rounds} x {args.steps})")
    for n in args.sizes:
        a = numpy_rules(args.env, n, args.steps, args.rounds)
        b = torch_rules(args.env, n, args.steps, args.rounds)
        print(
            f"  {n:>5} worlds: numpy {a * 1e6:8.1f}  torch on CPU tensors {b * 1e6:8.1f}  "
            f"torch/numpy {b / a:5.1f}x"
        )


if __name__ == "__main__":
    main()
