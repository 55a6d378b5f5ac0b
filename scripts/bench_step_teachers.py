"""The teachers that learn from steps, under a many-world run's load, without the worlds.

Robust PLR, ACCEL and Self-Paced get every world's step and learn each finished episode; a
many-world run at 4,096 worlds on a GPU spends ~12 ms a step collecting, so a teacher's
milliseconds a step are its share of the run. This feeds a teacher what the torch-native loop
feeds it (`CurriculumRounds`: each step's observations, actions, rewards and ends in one call,
the finished episodes learnt, the resetting worlds' next tasks drawn in rounds), from a seeded
synthetic stream: stump-tracks' task space, observations of `--obs` dimensions, episodes ending
at random (mean `--mean-episode` steps) or at the time limit. The critic is a fixed linear map
(the student's forward pass is the student's cost). After `--warmup` steps (episodes of every
length running), `--steps` steps are timed; printed: the teacher's milliseconds a step, the
episodes and tasks a step, the process's peak memory (of every teacher it ran so far: time
one teacher to read its own), and then the time to write the teacher's state as a checkpoint
does and to read it back into a new teacher, with the files' size.

    python scripts/bench_step_teachers.py [--worlds 4096] [--teachers robust-plr self-paced]
    python scripts/bench_step_teachers.py --against /tmp/acl3d-old --rounds 3

`--against TREE` times another checkout (a `git worktree`) too, round after round in
alternation, each in its own process, and prints the median over rounds of old / new (> 1:
this checkout is faster). Run it alone on the machine.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
from pathlib import Path

import numpy as np

STEP_TEACHERS = ("robust-plr", "accel", "self-paced")


def measure(args) -> dict:
    """{teacher: (teacher ms a step, episodes a step, tasks a step)} of this process's acl3d."""
    import torch

    from acl3d.envs.episode_statistics import EpisodeBatch
    from acl3d.teachers.controller import TeacherController
    from acl3d.training.config import TrainConfig
    from acl3d.training.session import probe_task_space
    from acl3d.training.torch_student.curriculum_rounds import CurriculumRounds, reserve_for
    from acl3d.training.torch_student.phase_times import PhaseTimes

    out, weights = {}, np.random.default_rng(1).standard_normal(args.obs).astype(np.float32)
    for teacher in args.teachers:
        config = TrainConfig(env="stump-tracks", teacher=teacher, steps=20_000_000)
        space, profile = probe_task_space(config)
        controller = TeacherController(
            teacher, space, 0, profile=profile, expert_knowledge="low", total_steps=config.steps
        )
        controller.set_value_estimator(lambda states: np.atleast_2d(states) @ weights)
        times, n = PhaseTimes(), args.worlds
        rounds = CurriculumRounds(controller, times, reserve_for(n, True), n)
        rng = np.random.default_rng(0)
        none = np.zeros(0, np.int64)
        empty = EpisodeBatch(none, np.zeros((0, space.dim), np.float32), np.zeros(0), none,
                             np.zeros(0, bool), np.zeros(0, bool), none)  # fmt: skip
        tasks = rounds.sync(empty, np.arange(n))
        lengths, returns = np.zeros(n, np.int64), np.zeros(n)
        obs = rng.standard_normal((n, args.obs)).astype(np.float32)
        timed = {"teacher": 0.0, "episodes": 0, "tasks": 0}
        for step in range(args.warmup + args.steps):
            if step == args.warmup:
                times.seconds["teacher"], start = 0.0, rounds.episodes_done
            actions = rng.standard_normal((n, 4)).astype(np.float32)
            rewards = rng.standard_normal(n).astype(np.float32)
            next_obs = rng.standard_normal((n, args.obs)).astype(np.float32)
            lengths += 1
            returns += rewards
            ended = (rng.random(n) < 1 / args.mean_episode) | (lengths >= args.max_episode)
            step_arrays = (obs, actions, rewards, ended, next_obs)
            rounds.record_steps(*(torch.from_numpy(a) for a in step_arrays))
            ids = np.flatnonzero(ended)
            if len(ids):
                finished = EpisodeBatch(
                    ids, tasks[ids], returns[ids], lengths[ids], rng.random(len(ids)) < 0.2,
                    lengths[ids] >= args.max_episode, np.full(len(ids), (step + 1) * n),
                )  # fmt: skip
                tasks[ids] = rounds.sync(finished, ids)
                lengths[ids], returns[ids] = 0, 0.0
                if step >= args.warmup:
                    timed["tasks"] += len(ids)
            obs = next_obs
        timed["teacher"] = times.seconds["teacher"]
        timed["episodes"] = rounds.episodes_done - start
        out[teacher] = [1e3 * timed["teacher"] / args.steps] + [
            timed[k] / args.steps for k in ("episodes", "tasks")
        ]
        out[teacher].append(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20)
        out[teacher].extend(checkpoint_times(controller, teacher, space, profile, config))
    return out


def checkpoint_times(controller, teacher, space, profile, config) -> list[float]:
    """[seconds to write the controller's state, seconds to read it into a new controller,
    megabytes written], as a run's checkpoint and resume do, running episodes included."""
    import tempfile
    import time

    from acl3d.teachers.controller import TeacherController
    from acl3d.teachers.state_files import load_state, save_state

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "controller"
        start = time.perf_counter()
        save_state(path, controller.state_dict())
        saved = time.perf_counter()
        fresh = TeacherController(
            teacher, space, 0, profile=profile, expert_knowledge="low", total_steps=config.steps
        )
        fresh.load_state_dict(load_state(path))
        loaded = time.perf_counter()
        size = sum(p.stat().st_size for p in Path(folder).iterdir()) / 2**20
    return [saved - start, loaded - saved, size]


def in_tree(tree: Path, argv: list[str]) -> dict:
    """`measure` run by another checkout, in its own process."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    command = [sys.executable, __file__, *argv, "--json"]
    out = subprocess.run(command, env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--teachers", nargs="+", default=list(STEP_TEACHERS))
    parser.add_argument("--worlds", type=int, default=4096)
    parser.add_argument("--obs", type=int, default=24)
    parser.add_argument("--mean-episode", type=float, default=500.0)
    parser.add_argument("--max-episode", type=int, default=2000)
    parser.add_argument("--warmup", type=int, default=2000)
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--against", type=Path, help="another checkout to time in alternation")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--json", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.json:
        print(json.dumps(measure(args)))
        return
    argv = [a for a in sys.argv[1:] if a not in ("--json",)]
    if args.against is not None:
        cut = argv.index("--against")
        argv = argv[:cut] + argv[cut + 2 :]
    here, there = Path(__file__).resolve().parents[1], args.against
    print(f"{args.worlds} worlds, {args.warmup} steps of warm-up, {args.steps} timed")
    results = {"this": []} | ({"other": []} if there else {})
    for _ in range(args.rounds if there else 1):
        results["this"].append(in_tree(here, argv))
        if there:
            results["other"].append(in_tree(there, argv))
    for teacher in args.teachers:
        mine = [r[teacher] for r in results["this"]]
        line = (
            f"  {teacher:12s} teacher {statistics.median(m[0] for m in mine):6.2f} ms a step "
            f"({mine[0][1]:.1f} episodes, {mine[0][2]:.1f} tasks a step; "
            f"process peak {mine[0][3]:.2f} GB); checkpoint: written in "
            f"{statistics.median(m[4] for m in mine):.2f} s, read in "
            f"{statistics.median(m[5] for m in mine):.2f} s, {mine[0][6]:.0f} MB"
        )
        if there:
            ratios = [
                o[teacher][0] / m[teacher][0] for o, m in zip(results["other"], results["this"])
            ]
            old = statistics.median(o[teacher][0] for o in results["other"])
            peak = results["other"][0][teacher][3]
            line += f"; {there}: {old:.2f} ms, peak {peak:.2f} GB, old / new "
            line += f"{statistics.median(ratios):.2f}x; its checkpoint: written in "
            line += f"{statistics.median(o[teacher][4] for o in results['other']):.2f} s, "
            line += f"read in {statistics.median(o[teacher][5] for o in results['other']):.2f} s, "
            line += f"{results['other'][0][teacher][6]:.0f} MB"
        print(line, flush=True)


if __name__ == "__main__":
    main()
