"""Single-env speed of this checkout against another one (e.g. before a refactor), in one run.

    git worktree add /tmp/acl3d-old <commit>
    python scripts/bench_compare.py /tmp/acl3d-old [--rounds 6] [--steps 20000]

Each round times `env.step` (classic biped, Stump Tracks h=1 sp=3, seeded random actions) and
`env.reset` with a new task, then the same actions through a batch of one
(`gymnasium.make_vec(..., num_envs=1, vectorization_mode="vector_entry_point")`, autoresetting as
each version does by default), in a fresh subprocess per checkout, alternating old and new so that
machine drift hits both alike; prints the medians and new/old ratios (> 1: the new one is faster).

    python scripts/bench_compare.py /tmp/acl3d-old --training ppo --rounds 2 --steps 131072

`--training ppo|sac` times, instead, a whole `acl3d.training.train()` run in each checkout (ALP-GMM
with expert knowledge high, the student's `fast` preset, 16 batched envs, 25 test tasks, the
final evaluation included): steps over the run's
own wall time (the last `wall_time_s` of its evals.csv), and over the process's CPU time (all
its threads: robust to other load on the machine, blind to how well the threads overlap).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PROBE = r"""
import json, sys, time
import numpy as np
import acl3d
from acl3d.envs import make
steps = int(sys.argv[1])
env = make("stump-tracks", body="classic_bipedal")
env.reset(seed=0, options={"task": {"stump_height": 1.0, "obstacle_spacing": 3.0}})
rng = np.random.default_rng(0)
actions = rng.uniform(-1, 1, (steps, env.action_space.shape[0])).astype(np.float32)
start = time.perf_counter()
for action in actions:
    _, _, terminated, truncated, _ = env.step(action)
    if terminated or truncated:
        env.reset()
step_rate = steps / (time.perf_counter() - start)
start = time.perf_counter()
for i in range(200):
    env.reset(options={"task": {"stump_height": (i % 30) / 10, "obstacle_spacing": 3.0}})
reset_ms = (time.perf_counter() - start) / 200 * 1e3
import gymnasium as gym
vec = gym.make_vec("acl3d/StumpTracks-v0", num_envs=1, vectorization_mode="vector_entry_point",
                   body="classic_bipedal")
vec.reset(seed=0, options={"task": {"stump_height": 1.0, "obstacle_spacing": 3.0}})
start = time.perf_counter()
for action in actions:
    vec.step(action[None])
batch_rate = steps / (time.perf_counter() - start)
print(json.dumps({"file": acl3d.__file__, "steps_per_s": step_rate, "reset_ms": reset_ms,
                  "batch_of_one_steps_per_s": batch_rate}))
"""


TRAIN_PROBE = r"""
import csv, json, sys, tempfile, time
import acl3d
from acl3d.training import train
student, steps = sys.argv[1], int(sys.argv[2])
cpu = time.process_time()
with tempfile.TemporaryDirectory() as tmp:
    # every option that decides the work written out (defaults differ between versions)
    train(teacher="alp-gmm", student=student, preset="fast", steps=steps, out=tmp + "/run",
          seed=0, n_envs=16, vec_env="batched", expert_knowledge="high", nb_test_episodes=25,
          progress_bar=False, verbose=0)
    rows = list(csv.DictReader(open(tmp + "/run/evals.csv")))
cpu = time.process_time() - cpu
wall, done = float(rows[-1]["wall_time_s"]), int(rows[-1]["step"])
print(json.dumps({"file": acl3d.__file__, "steps_per_s": done / wall, "steps_per_cpu_s": done / cpu}))
"""


def measure(tree: Path, steps: int, student: str | None = None) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    args = [PROBE, str(steps)] if student is None else [TRAIN_PROBE, student, str(steps)]
    out = subprocess.run(
        [sys.executable, "-c", *args],
        env=env,
        cwd=tree,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    result = json.loads(out.strip().splitlines()[-1])
    if not result["file"].startswith(str(tree)):
        raise RuntimeError(f"{tree}: imported acl3d from {result['file']}")
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("old", type=Path, help="the other checkout (its root folder)")
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument(
        "--training", choices=["ppo", "sac"], help="time a training run instead of the env"
    )
    args = parser.parse_args()
    runs = {"old": [], "new": []}
    for _ in range(args.rounds):
        runs["old"].append(measure(args.old.resolve(), args.steps, args.training))
        runs["new"].append(measure(ROOT, args.steps, args.training))
    keys = ("steps_per_s", "steps_per_cpu_s")
    if not args.training:
        keys = ("steps_per_s", "reset_ms", "batch_of_one_steps_per_s")
    median = {
        (tree, key): statistics.median(r[key] for r in runs[tree]) for tree in runs for key in keys
    }
    for key in keys:
        old, new = median["old", key], median["new", key]
        ratio = old / new if key == "reset_ms" else new / old
        print(f"{key:24s} old {old:10.2f}  new {new:10.2f}  new/old speed {ratio:.3f}")
    if not args.training:
        ratio = median["new", "batch_of_one_steps_per_s"] / median["old", "steps_per_s"]
        print(f"batch of one (new) / single env (old): {ratio:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
