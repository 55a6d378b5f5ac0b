"""Throughput of the ways to drive acl3d from your own code, measured in one run (docs/own-loop.md).

    python scripts/bench_own_loop.py                  # ~2-3 min on 2 cores
    python scripts/bench_own_loop.py --repeats 3      # best of 3 per cell, interleaved

Training (16 envs of Stump Tracks, ALP-GMM choosing every task, one torch thread):
* `acl3d train` PPO: SB3's PPO (`fast` preset) on the batched env, as `acl3d train --student ppo
  --preset fast --n-envs 16` runs it (timed after one warm-up rollout);
* the CleanRL-style example (scripts/examples/cleanrl_ppo.py): the same network, rollout and
  epochs in plain PyTorch on the Gymnasium vector env (timed from its first reset).

Stepping with random actions (no learning), tasks from ALP-GMM at every reset:
* the batched vector env with `teacher=` (NEXT_STEP autoreset), bare and under Gymnasium's
  vector wrappers (RecordEpisodeStatistics, ClipAction, NormalizeObservation,
  TransformObservation, NormalizeReward);
* `CurriculumWrapper` single envs in Gymnasium's `SyncVectorEnv`;
* Syllabus' DomainRandomization through the batched env's task source (scripts/examples).

Ratios compare cells of this run; on a shared machine repeat with --repeats and read the best.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from gymnasium.wrappers import vector as vw

import acl3d  # noqa: F401
from acl3d.envs.batched_vector import BatchedVectorEnv
from acl3d.envs.curriculum_wrapper import CurriculumWrapper
from acl3d.teachers import make as make_teacher

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE / "examples")]

from bench_training import measure  # noqa: E402
from cleanrl_ppo import parse_args as cleanrl_args  # noqa: E402
from cleanrl_ppo import train as cleanrl_train  # noqa: E402

ENV = "acl3d/StumpTracks-v0"


def teacher(seed=0):
    space = BatchedVectorEnv(ENV, 1, threads=1).task_space
    return make_teacher("alp-gmm", space, seed=seed)


def random_steps(envs, steps: int) -> float:
    """Steps/s of `envs` (a vector env) under uniform random actions, after a warm-up."""
    rng = np.random.default_rng(0)
    shape = envs.action_space.shape
    envs.reset(seed=0)
    for _ in range(20):
        envs.step(rng.uniform(-1, 1, shape))
    start = time.perf_counter()
    for _ in range(steps // envs.num_envs):
        envs.step(rng.uniform(-1, 1, shape))
    rate = (steps // envs.num_envs) * envs.num_envs / (time.perf_counter() - start)
    envs.close()
    return rate


def gymnasium_wrapped(envs):
    envs = vw.NormalizeObservation(vw.ClipAction(vw.RecordEpisodeStatistics(envs)))
    envs = vw.TransformObservation(envs, lambda o: np.clip(o, -10, 10), envs.observation_space)
    return vw.NormalizeReward(envs)


def wrapped_singles(n: int):
    """n single envs, each under a CurriculumWrapper sharing one teacher."""
    shared = teacher()
    return gym.vector.SyncVectorEnv(
        [lambda: CurriculumWrapper(gym.make(ENV), shared) for _ in range(n)]
    )


def syllabus_source():
    from syllabus_curriculum import SyllabusSync, domain_randomization

    space = BatchedVectorEnv(ENV, 1, threads=1).task_space
    return SyllabusSync(domain_randomization(space, seed=0))


CELLS = {
    "acl3d train PPO (SB3, batched)": lambda a: measure("batched", "ppo", a.n, a.train_steps, "alp-gmm")[0],
    "CleanRL-style PPO example": lambda a: cleanrl_train(
        cleanrl_args(["--total-steps", str(a.train_steps), "--num-envs", str(a.n), "--quiet",
                      "--out", "/tmp/acl3d_bench_cleanrl"])
    )["steps_per_s"],
    "batched vector env, teacher=": lambda a: random_steps(
        BatchedVectorEnv(ENV, a.n, teacher=teacher()), a.random_steps
    ),
    "  + Gymnasium vector wrappers": lambda a: random_steps(
        gymnasium_wrapped(BatchedVectorEnv(ENV, a.n, teacher=teacher())), a.random_steps
    ),
    "SyncVectorEnv of CurriculumWrapper": lambda a: random_steps(
        wrapped_singles(a.n), a.random_steps
    ),
    "Syllabus DomainRandomization, batched": lambda a: random_steps(
        BatchedVectorEnv(ENV, a.n, curriculum_sync=syllabus_source()), a.random_steps
    ),
}  # fmt: skip


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=16, help="envs")
    p.add_argument("--train-steps", type=int, default=4096 * 4, help="timed training steps")
    p.add_argument("--random-steps", type=int, default=16_000, help="timed random-action steps")
    p.add_argument("--repeats", type=int, default=1, help="best of N per cell")
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    best = {name: 0.0 for name in CELLS}
    for _ in range(args.repeats):
        for name, cell in CELLS.items():  # interleaved: load changes hit every cell alike
            rate = cell(args)
            best[name] = max(best[name], rate)
            print(f"  {name}: {rate:.0f} steps/s", flush=True)
    ref = best[next(iter(CELLS))]
    print(f"\n{args.n} envs of {ENV}, ALP-GMM tasks; best of {args.repeats}")
    print("| path | steps/s | ratio to acl3d train PPO |\n|---|---|---|")
    for name, rate in best.items():
        print(f"| {name.strip()} | {rate:.0f} | {rate / ref:.2f} |")


if __name__ == "__main__":
    main()
