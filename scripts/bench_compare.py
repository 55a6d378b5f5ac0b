"""Speed of this checkout against another one (e.g. before a refactor), in one run.

    git worktree add /tmp/acl3d-old <commit>
    python scripts/bench_compare.py /tmp/acl3d-old [--rounds 30]

One worker process per checkout builds a single env (classic biped, Stump Tracks h=1 sp=3) and a
batch of one (`gymnasium.make_vec(..., num_envs=1, vectorization_mode="vector_entry_point")`,
autoresetting as each version does by default); then blocks of 2,000 seeded random-action steps
(and of 100 resets with a new task) alternate between the two workers, round after round. Each
ratio is the median over rounds of new/old within a round (> 1: the new one is faster), so a
machine whose speed drifts by tens of percent within a minute hits both alike. The last line is
the batch of one of this checkout against the other's single env.

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
# A worker per checkout: builds the envs once, then times one block per command read from stdin,
# so that blocks of the two checkouts alternate every fraction of a second.
WORKER = r"""
import json, sys, time
import numpy as np
import acl3d
import gymnasium as gym
from acl3d.envs import make
TASK = {"stump_height": 1.0, "obstacle_spacing": 3.0}
env = make("stump-tracks", body="classic_bipedal")
env.reset(seed=0, options={"task": TASK})
vec = gym.make_vec("acl3d/StumpTracks-v0", num_envs=1, vectorization_mode="vector_entry_point",
                   body="classic_bipedal")
vec.reset(seed=0, options={"task": TASK})
rng = np.random.default_rng(0)
size = env.action_space.shape[0]
print(json.dumps({"file": acl3d.__file__}), flush=True)
resets = 0
for line in sys.stdin:
    kind, n = line.split()
    actions = rng.uniform(-1, 1, (int(n), size)).astype(np.float32)
    start = time.perf_counter()
    if kind == "single":
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
    elif kind == "batch":
        for action in actions:
            vec.step(action[None])
    else:
        for _ in actions:
            resets += 1
            env.reset(options={"task": {"stump_height": (resets % 30) / 10, "obstacle_spacing": 3.0}})
    print(json.dumps(time.perf_counter() - start), flush=True)
"""

# per kind: (steps per block, what is printed)
BLOCKS = {
    "single": (2000, "single env steps/s"),
    "batch": (2000, "batch of one steps/s"),
    "reset": (100, "resets/s (new task)"),
}


class Worker:
    """A probe process of one checkout (see WORKER)."""

    def __init__(self, tree: Path):
        env = dict(os.environ, PYTHONPATH=str(tree))
        self.proc = subprocess.Popen(
            [sys.executable, "-c", WORKER],
            env=env,
            cwd=tree,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        imported = json.loads(self.proc.stdout.readline())["file"]
        if not imported.startswith(str(tree)):
            raise RuntimeError(f"{tree}: imported acl3d from {imported}")

    def time(self, kind: str, n: int) -> float:
        self.proc.stdin.write(f"{kind} {n}\n")
        self.proc.stdin.flush()
        return json.loads(self.proc.stdout.readline())

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait()


def compare_envs(old_tree: Path, rounds: int) -> None:
    """Blocks of each kind alternate between the checkouts (old first in even rounds); the
    ratio is the median over rounds of new/old within the round, which cancels the drift of a
    machine whose speed wanders by tens of percent within a minute."""
    workers = {"old": Worker(old_tree), "new": Worker(ROOT)}
    rates = {(tree, kind): [] for tree in workers for kind in BLOCKS}
    try:
        for r in range(rounds):
            for kind, (n, _) in BLOCKS.items():
                for tree in ("old", "new") if r % 2 == 0 else ("new", "old"):
                    rates[tree, kind].append(n / workers[tree].time(kind, n))
    finally:
        for worker in workers.values():
            worker.close()
    for kind, (_, label) in BLOCKS.items():
        old, new = rates["old", kind], rates["new", kind]
        ratio = statistics.median(b / a for a, b in zip(old, new))
        print(
            f"{label:22s} old {statistics.median(old):9.0f}  new {statistics.median(new):9.0f}"
            f"  new/old {ratio:.3f}"
        )
    ratio = statistics.median(b / a for a, b in zip(rates["old", "single"], rates["new", "batch"]))
    print(f"batch of one (new) / single env (old): {ratio:.3f}")


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


def measure(tree: Path, steps: int, student: str) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    args = [TRAIN_PROBE, student, str(steps)]
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
    parser.add_argument("--rounds", type=int, default=None, help="default: 30 (env), 2 (training)")
    parser.add_argument("--steps", type=int, default=131_072, help="training steps per run")
    parser.add_argument(
        "--training", choices=["ppo", "sac"], help="time a training run instead of the env"
    )
    args = parser.parse_args()
    if not args.training:
        compare_envs(args.old.resolve(), args.rounds or 30)
        return 0
    runs = {"old": [], "new": []}
    for _ in range(args.rounds or 2):
        runs["old"].append(measure(args.old.resolve(), args.steps, args.training))
        runs["new"].append(measure(ROOT, args.steps, args.training))
    for key in ("steps_per_s", "steps_per_cpu_s"):
        old = statistics.median(r[key] for r in runs["old"])
        new = statistics.median(r[key] for r in runs["new"])
        print(f"{key:16s} old {old:10.2f}  new {new:10.2f}  new/old speed {new / old:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
