"""Benchmark every available teacher on the toy environment against teachDeepRL's numbers.

For each preset (teachDeepRL / TeachMyAgent-benchmark hyper-parameters) and teacher: % mastered
cubes at 5k/10k/20k episodes (2-D toy, 10 cubes per dimension, mean +- std over seeds) and the
teacher's CPU seconds per 1000 episodes (process time inside sample_task/updates only), next to the
original teachDeepRL results. Teachers whose module cannot be imported are skipped. Teachers that
need more than returns get success = reward > 0.75 and one-step episodes (see
`acl3d.toy.run_teacher`); ADR and the oracle get toy reward thresholds (`toy_teacher_params`).
A teacher that both presets configure alike (e.g. one neither preset mentions) runs once.

    python scripts/bench_teachers.py                      # full run (several minutes)
    python scripts/bench_teachers.py --seeds 1 --episodes 5000 --teachers alp-gmm,riac
"""

from __future__ import annotations

import argparse
import inspect
import math
import sys
import time

import numpy as np

from acl3d.teachers import TEACHERS, make, teacher_class
from acl3d.teachers.presets import PRESETS, preset_params
from acl3d.toy import ToyEnv, run_teacher, toy_teacher_params

# teachDeepRL's toy demo (tDRL defaults, 5 seeds, 20k episodes) and its teachers' CPU time.
REF_SCORE_20K = {"random": 4.6, "alp-gmm": 35.0, "riac": 47.0, "covar-gmm": 63.0}
REF_CPU_PER_1000 = {"alp-gmm": 0.56, "covar-gmm": 0.41, "riac": 1.0}


def bench_one(
    name: str, preset: str, seed: int, episodes: int, checkpoints: list[int]
) -> tuple[list[float], float]:
    env = ToyEnv(nb_dims=2, nb_cubes=10, seed=seed)
    params = preset_params(preset, name) | toy_teacher_params(name, env)
    teacher = make(name, env.task_space(), seed=seed, **params)
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(1)
    every = math.gcd(*checkpoints)
    result = run_teacher(teacher, env, episodes, score_every=every)
    by_episode = dict(zip(result.episodes, result.scores))
    return [by_episode[c] for c in checkpoints], result.cpu_per_1000


def effective_params(name: str, preset: str) -> dict:
    """Class defaults overridden by the preset (presets omit what equals the defaults)."""
    sig = inspect.signature(teacher_class(name).__init__)
    params = {
        k: p.default for k, p in sig.parameters.items() if k not in ("self", "task_space", "seed")
    }
    return params | preset_params(preset, name)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--episodes", type=int, default=20000)
    parser.add_argument(
        "--teachers", default=",".join(TEACHERS), help="comma-separated teacher names"
    )
    parser.add_argument("--preset", default="all", choices=["all", *PRESETS])
    args = parser.parse_args(argv)
    names = [n.strip() for n in args.teachers.split(",") if n.strip()]
    unknown = [n for n in names if n not in TEACHERS]
    if unknown:
        parser.error(f"unknown teacher(s) {unknown}; valid: {', '.join(TEACHERS)}")
    available = []
    for n in names:
        try:
            teacher_class(n)
            make(n, ToyEnv().task_space(), seed=0, **toy_teacher_params(n, ToyEnv()))
            available.append(n)
        except (ImportError, ValueError) as exc:  # not written yet, or needs inputs the toy lacks
            print(f"skipping {n}: {exc}", file=sys.stderr)
    checkpoints = [c for c in (5000, 10000, 20000) if c <= args.episodes] or [args.episodes]
    if checkpoints[-1] != args.episodes:
        checkpoints.append(args.episodes)
    presets = list(PRESETS) if args.preset == "all" else [args.preset]

    head = " | ".join(f"{c // 1000}k" if c % 1000 == 0 else str(c) for c in checkpoints)
    rows = [
        f"| teacher | preset | {head} | tDRL 20k | score ratio | CPU s/1000 ep | tDRL CPU | CPU ratio |",
        "|" + "---|" * (len(checkpoints) + 7),
    ]
    done: dict[tuple[str, str], tuple] = {}  # a teacher the presets configure alike runs once
    for preset in presets:
        for name in available:
            key = (name, repr(sorted(effective_params(name, preset).items())))
            if key not in done:
                scores, cpus = [], []
                t0 = time.time()
                for seed in range(args.seeds):
                    s, cpu = bench_one(name, preset, seed, args.episodes, checkpoints)
                    scores.append(s)
                    cpus.append(cpu)
                scores_arr = np.asarray(scores)
                done[key] = (scores_arr.mean(axis=0), scores_arr.std(axis=0), float(np.mean(cpus)))
                print(
                    f"done {name} ({preset}) in {time.time() - t0:.0f} s",
                    file=sys.stderr,
                    flush=True,
                )
            mean, std, cpu = done[key]
            ref_s, ref_c = REF_SCORE_20K.get(name), REF_CPU_PER_1000.get(name)
            cells = " | ".join(f"{m:.1f} ± {s:.1f}" for m, s in zip(mean, std))
            score_ratio = f"{mean[-1] / ref_s:.2f}" if ref_s and checkpoints[-1] == 20000 else "–"
            cpu_ratio = f"{cpu / ref_c:.2f}" if ref_c else "–"
            rows.append(
                f"| {name} | {preset} | {cells} | {ref_s if ref_s is not None else '–'} | {score_ratio} | {cpu:.3f} | {ref_c if ref_c is not None else '–'} | {cpu_ratio} |"
            )
    print(
        f"\n{args.seeds} seeds, {args.episodes} episodes, 2-D toy, 10 cubes/dim; tDRL references: 5 seeds, 20k episodes, tDRL defaults."
    )
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
