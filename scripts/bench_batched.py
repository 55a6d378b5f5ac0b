"""Batched env speed: N envs through Gymnasium's vector API vs N single envs vs SubprocVecEnv.

    python scripts/bench_batched.py                 # N = 1, 4, 16, 64; threads 1 and 2
    python scripts/bench_env.py --batched           # the same, after the single-env table

Total env steps/s with uniform random actions (classic biped, Stump Tracks h=1 sp=3), through
`gymnasium.make_vec(..., vectorization_mode="vector_entry_point", autoreset_mode="SameStep")`
(its resets of finished sub-envs are timed, as a user sees them), measured in interleaved rounds
in this run (best round per cell); a batched cell's ratio is the median over rounds of its rate
over one `gymnasium.make` env timed right before it (the machine's speed may drift between
cells). "per-env / raw physics" is the vector env's wall time per env step (threads=1) over the
time the physics step itself (`BatchPhysics.step`: MuJoCo's batch, same models, same states)
took for those steps.
SubprocVecEnv (forkserver, N workers) is skipped above --max-subproc workers.
"""

from __future__ import annotations

import argparse
import functools
import statistics
import time

import acl3d  # noqa: F401  (first: picks the headless GL backend before mujoco loads)

# isort: split
import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import SubprocVecEnv

from acl3d.envs.physics import BatchPhysics

TASK = {"stump_height": 1.0, "obstacle_spacing": 3.0}
ENV_ID = "acl3d/StumpTracks-v0"


class BatchClock:
    """Times `BatchPhysics.step` (the physics of every sub-env) inside the vector env's steps."""

    def __init__(self):
        self.seconds = 0.0
        self._step = BatchPhysics.step

    def __enter__(self):
        clock, step = self, self._step

        def timed(physics):
            t0 = time.perf_counter()
            step(physics)
            clock.seconds += time.perf_counter() - t0

        BatchPhysics.step = timed
        return self

    def __exit__(self, *exc):
        BatchPhysics.step = self._step


def batched_rate(n: int, threads: int, steps: int, clock: bool = False) -> tuple[float, float]:
    """(env steps/s, raw physics steps/s or nan) of a vector env of n sub-envs."""
    venv = gym.make_vec(
        ENV_ID,
        num_envs=n,
        vectorization_mode="vector_entry_point",
        threads=threads,
        autoreset_mode=gym.vector.AutoresetMode.SAME_STEP,
    )
    venv.reset(seed=0, options={"task": TASK})
    rng = np.random.default_rng(0)
    rounds = max(1, steps // n)
    actions = rng.uniform(-1, 1, (rounds, n, venv.single_action_space.shape[0]))
    with BatchClock() as timer:
        t0 = time.perf_counter()
        for a in actions:
            venv.step(a)
        elapsed = time.perf_counter() - t0
    venv.close()
    # a batch of one steps its env's own physics, not a `BatchPhysics`: no raw time for it
    raw = rounds * n / timer.seconds if clock and timer.seconds else float("nan")
    return rounds * n / elapsed, raw


def loop_rate(n: int, steps: int) -> float:
    """N single `gymnasium.make` envs stepped one after the other in a Python loop."""
    envs = [gym.make(ENV_ID) for _ in range(n)]
    for i, env in enumerate(envs):
        env.reset(seed=i, options={"task": TASK})
    rng = np.random.default_rng(0)
    rounds = max(1, steps // n)
    actions = rng.uniform(-1, 1, (rounds, n, 4))
    t0 = time.perf_counter()
    for a in actions:
        for i, env in enumerate(envs):
            _, _, terminated, truncated, _ = env.step(a[i])
            if terminated or truncated:
                env.reset()
    return rounds * n / (time.perf_counter() - t0)


def _make_single():
    import acl3d.envs

    env = acl3d.envs.make("stump-tracks")
    env.unwrapped.set_task(TASK)
    return env


def subproc_rate(n: int, steps: int) -> float:
    """SB3 SubprocVecEnv (forkserver) with n workers; its autoresets are inside the timing."""
    venv = SubprocVecEnv([functools.partial(_make_single) for _ in range(n)], "forkserver")
    venv.reset()
    rng = np.random.default_rng(0)
    rounds = max(1, steps // n)
    actions = rng.uniform(-1, 1, (rounds, n, 4))
    t0 = time.perf_counter()
    for a in actions:
        venv.step(a)
    elapsed = time.perf_counter() - t0
    venv.close()
    return rounds * n / elapsed


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=8000, help="env steps per cell and round")
    p.add_argument("--sizes", type=int, nargs="+", default=[1, 4, 16, 64])
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    p.add_argument("--rounds", type=int, default=3, help="interleaved rounds (best is kept)")
    p.add_argument("--max-subproc", type=int, default=16, help="largest SubprocVecEnv measured")
    args = p.parse_args()

    best: dict = {}
    ratios: dict = {}  # per cell: its rate over a single env measured right before it, per round
    for _ in range(args.rounds):
        for n in args.sizes:
            for threads in args.threads:
                single = loop_rate(1, args.steps)
                best["single"] = max(best.get("single", 0.0), single)
                rate, raw = batched_rate(n, threads, args.steps, clock=threads == 1)
                key = ("batched", n, threads)
                ratios.setdefault(key, []).append(rate / single)
                if rate > best.get(key, (0.0,))[0]:
                    best[key] = (rate, raw)
            best[("loop", n)] = max(best.get(("loop", n), 0.0), loop_rate(n, args.steps))
            if n <= args.max_subproc:
                rate = subproc_rate(n, args.steps)
                best[("subproc", n)] = max(best.get(("subproc", n), 0.0), rate)
    single = best["single"]
    print(f"single env (gymnasium.make, one process): {single:,.0f} steps/s (best round)\n")
    head = " | ".join(f"batched, {t} thread{'s' if t > 1 else ''}" for t in args.threads)
    print(
        f"| N | {head} | N single envs, loop | SubprocVecEnv, N workers | per-env / raw physics |"
    )
    print("|---|" + "---|" * (len(args.threads) + 3))
    for n in args.sizes:
        cells = [(best[("batched", n, t)][0], ratios[("batched", n, t)]) for t in args.threads]
        cols = " | ".join(f"{c:,.0f} ({statistics.median(r):.2f}x)" for c, r in cells)
        sub = best.get(("subproc", n))
        sub_cell = f"{sub:,.0f} ({sub / single:.2f}x)" if sub else "-"
        loop = best[("loop", n)]
        raw = best[("batched", n, 1)][1] if 1 in args.threads else float("nan")
        overhead = raw / best[("batched", n, 1)][0] if 1 in args.threads else float("nan")
        print(
            f"| {n} | {cols} | {loop:,.0f} ({loop / single:.2f}x) | {sub_cell} | {overhead:.2f}x |"
        )
    print(
        "\n(steps/s: best round; batched x: median over rounds of the rate over a single env"
        " measured right before it; other x: over the best single env)"
    )


if __name__ == "__main__":
    main()
