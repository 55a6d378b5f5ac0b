"""3D Terrain's `grid_spacing` on the CPU: the big quadruped's env steps/s on coarser grids.

    python scripts/bench_terrain3d_grids.py                  # 16 envs, 1 and 2 threads
    python scripts/bench_terrain3d_grids.py --envs 64 --threads 2 --rounds 5

On a GPU heightfield collision is most of a physics step and a coarser grid pays 1.5-2.4x
(`gpu_benchmarks.sh grids`); this measures what it pays on the CPU batched env (MuJoCo's batch,
float64), the path of a machine without a GPU. Every grid steps the same task (`bench_gpu.py`'s:
roughness 0.1 m, full-width 0.3 m blocks), the same seeds and random actions, through
`gymnasium.make_vec(..., vectorization_mode="vector_entry_point")` (resets of finished envs
included), in interleaved rounds; the ratio is the median over rounds of a grid's rate over the
default grid's rate in the same round.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections import defaultdict

import acl3d  # noqa: F401  (first: picks the headless GL backend before mujoco loads)

# isort: split
import gymnasium as gym
import numpy as np

ENV_ID = "acl3d/Terrain3D-v0"
TASK = {"hill_slope": 0.2, "cross_slope": 0.15, "roughness": 0.1, "block_height": 0.3}
SPACINGS = ((0.1, 0.5), (0.1, 0.2), (0.2, 0.2), (0.25, 0.25), (0.5, 0.5))  # the default first


def rate(spacing: tuple[float, float], envs: int, threads: int, steps: int) -> float:
    """Env steps/s of `envs` big quadrupeds on a grid of `spacing`, random actions."""
    venv = gym.make_vec(
        ENV_ID, num_envs=envs, vectorization_mode="vector_entry_point", threads=threads,
        autoreset_mode=gym.vector.AutoresetMode.SAME_STEP, grid_spacing=spacing,
    )  # fmt: skip
    venv.reset(seed=0, options={"task": TASK})
    rounds = max(1, steps // envs)
    actions = np.random.default_rng(0).uniform(
        -1, 1, (rounds, envs, venv.single_action_space.shape[0])
    )
    t0 = time.perf_counter()
    for a in actions:
        venv.step(a)
    elapsed = time.perf_counter() - t0
    venv.close()
    return rounds * envs / elapsed


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--envs", type=int, default=16)
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    p.add_argument("--steps", type=int, default=4000, help="env steps a cell, all envs together")
    p.add_argument("--rounds", type=int, default=3)
    a = p.parse_args()
    rates: dict[tuple, list[float]] = defaultdict(list)
    ratios: dict[tuple, list[float]] = defaultdict(list)
    print(f"3D Terrain, big_quadru, {a.envs} envs, {a.steps} env steps a cell, {a.rounds} rounds")
    for _ in range(a.rounds):
        for threads in a.threads:
            default = None
            for spacing in SPACINGS:
                r = rate(spacing, a.envs, threads, a.steps)
                default = default or r
                rates[spacing, threads].append(r)
                ratios[spacing, threads].append(r / default)
    print("| grid_spacing (m) | " + " | ".join(f"{t} thread(s)" for t in a.threads) + " |")
    print("|---|" + "---|" * len(a.threads))
    for spacing in SPACINGS:
        cells = [
            f"{max(rates[spacing, t]):,.0f} ({statistics.median(ratios[spacing, t]):.2f}x)"
            for t in a.threads
        ]
        print(f"| {spacing[0]} x {spacing[1]} | " + " | ".join(cells) + " |")
    print("(env steps/s: best round; x: median over rounds of the rate over the default grid's)")


if __name__ == "__main__":
    main()
