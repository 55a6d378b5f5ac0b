"""Training throughput: SB3 students on Stump Tracks with a teacher in the loop, on the batched
env (all envs in this process) vs the one-env-per-process path, and vs Gymnasium's Walker2d-v5.

    python scripts/bench_training.py                    # ~2-4 min: ppo + sac
    python scripts/bench_training.py --students ppo --batched-envs 16 32 --teacher random
    python scripts/bench_training.py --update-threads 1 2   # PPO's update alone per torch threads
    python scripts/bench_training.py --students ppo --batched-envs 16 32 --rsl-envs 16 32 64

Every cell is `model.learn()` steps per wall-clock second after a warm-up (PPO: whole rollouts;
SAC: past learning_starts, so gradient steps are included), with the `fast` preset for that
number of envs and one torch thread. Columns: the batched env (`vec_env="batched"`, N envs,
physics on one thread per core; sub-envs pull their tasks from the teacher at reset); the old
path (`--old-envs` SubprocVecEnv workers, forkserver, tasks pushed to worker queues); Walker2d-v5
on the same SubprocVecEnv setting. "teacher" is the share of the batched run's wall time spent in
the teacher (sampling tasks, recording episodes). Ratios compare cells measured in this run; on
shared machines repeat with --repeats and read the best. Each repeat is a round of every cell
(rsl-ppo first, then the SB3 cells), and rsl-ppo's ratio to the round's best SB3 PPO cell is
printed per round: a host whose speed drifts shows as spread there.

`--rsl-envs`: the torch-native rsl-ppo student (its own loop on `CpuTensorVectorEnv`, the same
teacher feeding the worlds) at these world counts, with its `--preset`-named preset: whole
rollouts and updates after one warm-up rollout (printed with the shares of the wall time in the
worlds' steps, the policy's act + record and the updates); compared with the best SB3 PPO cell.
`--rsl-param K=V` changes the preset (e.g. `hidden_dims=[64,64]`); `--env-only N ...` times the
tensor worlds alone with random actions, the bound no student on them can pass.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
import yaml
from stable_baselines3.common.vec_env import VecNormalize

from acl3d.training import students
from acl3d.training.curriculum import CurriculumVecEnv
from acl3d.training.workers import make_env, make_vec_env


class TimedCurriculumVecEnv(CurriculumVecEnv):
    """Counts the wall time spent on the teacher side (learning episodes, sampling tasks)."""

    teacher_time = 0.0

    def _sync(self, finished, n):
        start = time.perf_counter()
        out = super()._sync(finished, n)
        TimedCurriculumVecEnv.teacher_time += time.perf_counter() - start
        return out


def build_env(kind: str, n_envs: int, teacher: str, seed: int, student: str):
    if kind == "walker2d":
        venv = make_vec_env("Walker2d-v5", None, n_envs, curriculum=False, vec_env="subproc")
    else:
        from acl3d.teachers.controller import TeacherController

        probe = make_env("stump-tracks", "classic_bipedal")
        space, profile = probe.unwrapped.task_space, probe.unwrapped.curriculum_profile
        probe.close()
        controller = TeacherController(teacher, space, seed, profile=profile)
        vec_env = "batched" if kind == "batched" else "subproc"
        workers = make_vec_env("stump-tracks", "classic_bipedal", n_envs, vec_env=vec_env)
        venv = TimedCurriculumVecEnv(workers, controller)
    if students.uses_vecnormalize(student):
        venv = VecNormalize(venv, clip_obs=10.0, clip_reward=10.0)
    return venv


def measure(kind, student, n_envs, steps, teacher, preset="fast"):
    """(steps/s, share of the wall time spent on the teacher side)."""
    env = build_env(kind, n_envs, teacher, 0, student)
    try:
        params = students.hyperparameters(student, preset, n_envs)
        model = students.build(student, params, env, seed=0)
        # Warm up past one PPO rollout / SAC's learning_starts, so training is in the timing.
        if student == "ppo":
            warmup = params["n_steps"] * n_envs
            steps = max(steps, warmup)
        else:
            warmup = params["learning_starts"]
        model.learn(warmup)
        TimedCurriculumVecEnv.teacher_time = 0.0
        start = time.perf_counter()
        before = model.num_timesteps
        model.learn(steps, reset_num_timesteps=False)
        elapsed = time.perf_counter() - start
        steps_per_s = (model.num_timesteps - before) / elapsed
        return steps_per_s, TimedCurriculumVecEnv.teacher_time / elapsed
    finally:
        env.close()


class ControllerSync:
    """The worlds' curriculum as a torch-native run drives it: the controller learns each
    step's finished episodes, then draws the next tasks of the worlds that reset."""

    def __init__(self, controller):
        self.controller = controller

    def sync(self, finished, env_ids):
        if len(finished):
            self.controller.record_episodes(finished)
        return self.controller.sample_training_tasks(len(env_ids))[0]


def tensor_worlds(n_envs: int, teacher: str):
    """`n_envs` CPU tensor worlds of Stump Tracks, `teacher` drawing their tasks."""
    from acl3d.envs.tensor_vector import CpuTensorVectorEnv
    from acl3d.teachers.controller import TeacherController

    probe = make_env("stump-tracks", "classic_bipedal")
    space, profile = probe.unwrapped.task_space, probe.unwrapped.curriculum_profile
    probe.close()
    source = ControllerSync(TeacherController(teacher, space, 0, profile=profile))
    return CpuTensorVectorEnv("stump-tracks", n_envs, curriculum_sync=source)


def measure_env(n_envs: int, steps: int, teacher: str) -> float:
    """The tensor worlds alone (uniform random actions, no learner): steps/s after 20 steps."""
    env = tensor_worlds(n_envs, teacher)
    generator = torch.Generator().manual_seed(0)
    actions = [torch.rand(n_envs, env.action_size, generator=generator) * 2 - 1
               for _ in range(20 + max(1, steps // n_envs))]  # fmt: skip
    try:
        env.reset(seed=0)
        for a in actions[:20]:
            env.step(a)
        start = time.perf_counter()
        for a in actions[20:]:
            env.step(a)
        return (len(actions) - 20) * n_envs / (time.perf_counter() - start)
    finally:
        env.close()


def measure_rsl(n_envs: int, steps: int, teacher: str, preset: str, overrides=None):
    """rsl-ppo's training steps/s (rollouts + updates) on `n_envs` CPU tensor worlds, and the
    shares of the timed wall time in the worlds' steps, the policy's act + record, and updates."""
    from acl3d.training.torch_student.rsl_ppo import RslPPO

    env = tensor_worlds(n_envs, teacher)
    params = students.hyperparameters("rsl-ppo", preset, n_envs, overrides)
    torch.manual_seed(0)
    student = RslPPO(params, env.observation_size, env.action_size, n_envs, "cpu",
                     env.action_low, env.action_high)  # fmt: skip
    obs = env.reset(seed=0)
    rollout = student.steps_per_env * n_envs
    rounds = 1 + max(1, -(-steps // rollout))
    clock = time.perf_counter
    try:
        for r in range(rounds):  # round 0: warm-up
            if r == 1:
                seconds, start = dict.fromkeys(("env", "act+record", "update"), 0.0), clock()
            with torch.inference_mode():
                for _ in range(student.steps_per_env):
                    t0 = clock()
                    actions = student.act(obs)
                    t1 = clock()
                    obs, rew, term, trunc, extras = env.step(actions)
                    t2 = clock()
                    student.record(rew, term, trunc, extras["final_obs"])
                    if r:
                        seconds["env"] += t2 - t1
                        seconds["act+record"] += t1 - t0 + clock() - t2
            t0 = clock()
            student.update(obs)
            if r:
                seconds["update"] += clock() - t0
        total = clock() - start
        return (rounds - 1) * rollout / total, {k: v / total for k, v in seconds.items()}
    finally:
        env.close()


def update_seconds(thread_counts, n_envs: int, rounds: int) -> dict[int, float]:
    """PPO `fast`'s update (`model.train()`: 10 epochs over one rollout) in wall seconds, per
    torch thread count (best of interleaved rounds), on a rollout the batched env collected."""
    env = build_env("batched", n_envs, "random", 0, "ppo")
    params = students.hyperparameters("ppo", "fast", n_envs)
    model = students.build("ppo", params, env, seed=0)
    model.learn(params["n_steps"] * n_envs)  # one rollout (and one update)
    best = {t: float("inf") for t in thread_counts}
    for _ in range(rounds):
        for t in thread_counts:
            torch.set_num_threads(t)
            start = time.perf_counter()
            model.train()
            best[t] = min(best[t], time.perf_counter() - start)
    torch.set_num_threads(1)
    env.close()
    return best


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--students", nargs="+", default=["ppo", "sac"], choices=students.STUDENTS)
    p.add_argument("--batched-envs", nargs="+", type=int, default=[16], help="batched env sizes")
    p.add_argument(
        "--old-envs",
        type=int,
        default=2,
        help="SubprocVecEnv workers (old path; 0: skip it and Walker2d)",
    )
    p.add_argument("--teacher", default="alp-gmm", help="teacher in the loop (default alp-gmm)")
    p.add_argument(
        "--ppo-steps", type=int, default=8192, help="timed PPO steps (at least 1 rollout)"
    )
    p.add_argument("--sac-steps", type=int, default=3000, help="timed SAC steps")
    p.add_argument("--repeats", type=int, default=1, help="best of N measurements per cell")
    p.add_argument("--preset", default="fast", choices=students.PRESETS, help="student preset")
    p.add_argument("--rsl-envs", nargs="+", type=int, default=[], help="rsl-ppo world counts")
    p.add_argument(
        "--rsl-param", action="append", default=[], metavar="K=V",
        help="rsl-ppo preset override (YAML value, repeatable), e.g. hidden_dims=[64,64]",
    )  # fmt: skip
    p.add_argument(
        "--env-only", nargs="+", type=int, default=[],
        help="also time the tensor worlds alone (random actions) at these world counts",
    )  # fmt: skip
    p.add_argument(
        "--update-threads",
        nargs="+",
        type=int,
        help="instead: time PPO's update alone with these torch thread counts",
    )
    args = p.parse_args()
    torch.set_num_threads(1)
    if args.update_threads:
        n = args.batched_envs[0]
        best = update_seconds(args.update_threads, n, max(3, args.repeats))
        print(f"PPO 'fast' update of one {n}-env rollout, wall seconds (best of rounds):")
        for t, seconds in best.items():
            ratio = best[args.update_threads[0]] / seconds
            print(f"  torch threads {t}: {seconds:.3f} s ({ratio:.2f}x)")
        return

    overrides = {k: yaml.safe_load(v) for k, v in (kv.split("=", 1) for kv in args.rsl_param)}
    rsl, env_only = {}, {}
    rounds = []  # per repeat: ({rsl worlds: steps/s}, {SB3 PPO envs: steps/s}), measured together
    cells = {}
    for student in args.students:
        cells[student] = [("batched", n) for n in args.batched_envs]
        if args.old_envs:
            cells[student] += [("old", args.old_envs), ("walker2d", args.old_envs)]
    best = {student: {cell: 0.0 for cell in cells[student]} for student in args.students}
    share = {student: {n: 1.0 for n in args.batched_envs} for student in args.students}
    for _ in range(args.repeats):  # every cell once per round, so load changes hit all alike
        for n in args.env_only:
            sps = measure_env(n, args.ppo_steps, args.teacher)
            env_only[n] = max(env_only.get(n, 0.0), sps)
            print(f"  tensor worlds alone x{n}: {sps:.0f} steps/s", flush=True)
        this_round = ({}, {})
        for n in args.rsl_envs:
            sps, shares = measure_rsl(n, args.ppo_steps, args.teacher, args.preset, overrides)
            rsl[n] = max(rsl.get(n, 0.0), sps)
            this_round[0][n] = sps
            split = ", ".join(f"{k} {100 * v:.0f}%" for k, v in shares.items())
            print(f"  rsl-ppo tensor worlds x{n}: {sps:.0f} steps/s ({split})", flush=True)
        for student in args.students:
            steps = args.ppo_steps if student == "ppo" else args.sac_steps
            for kind, n in cells[student]:
                sps, teacher_share = measure(kind, student, n, steps, args.teacher, args.preset)
                best[student][(kind, n)] = max(best[student][(kind, n)], sps)
                if kind == "batched":
                    share[student][n] = min(share[student][n], teacher_share)
                    if student == "ppo":
                        this_round[1][n] = sps
                print(f"  {student} {kind} x{n}: {sps:.0f} steps/s", flush=True)
        rounds.append(this_round)
    rows = [(student, best[student], share[student]) for student in args.students]

    print()
    print(
        f"training steps/s (SB3 '{args.preset}' preset; teacher = {args.teacher}; "
        f"best of {args.repeats})"
    )
    old, walker = ("old", args.old_envs), ("walker2d", args.old_envs)
    print(
        f"| student | envs | batched | old path ({args.old_envs} workers) | "
        f"Walker2d-v5 ({args.old_envs} workers) | batched/old | batched/Walker2d | teacher time |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for student, best, share in rows:
        for n in args.batched_envs:
            b = best[("batched", n)]
            o, w = best.get(old), best.get(walker)
            others = (
                f"{o:.0f} | {w:.0f} | {b / o:.2f} | {b / w:.2f}" if o and w else "- | - | - | -"
            )
            print(f"| {student} | {n} | {b:.0f} | {others} | {100 * share[n]:.2f}% |")
    if rsl:
        sb3 = (
            max(
                (b[("batched", n)], n)
                for s_, b, _ in rows
                for n in args.batched_envs
                if s_ == "ppo"
            )
            if "ppo" in args.students
            else None
        )
        print()
        changed = "".join(f", {k}={v}" for k, v in overrides.items())
        print(f"rsl-ppo ('{args.preset}' preset{changed}) training steps/s on CPU tensor worlds")
        print("| worlds | rsl-ppo | vs best SB3 PPO batched |")
        print("|---|---|---|")
        for n, sps in rsl.items():
            ratio = f"{sps / sb3[0]:.2f}x (SB3 at {sb3[1]} envs)" if sb3 else "-"
            print(f"| {n} | {sps:.0f} | {ratio} |")
        if sb3:
            print()
            print(
                "per round, rsl-ppo / the round's best SB3 PPO batched (measured back to back), "
                "then the median round (less moved by a host whose speed drifts than the best)"
            )
            for n in args.rsl_envs:
                ratios = [r[n] / max(s_.values()) for r, s_ in rounds]
                median = statistics.median(ratios)
                print(f"| {n} | " + ", ".join(f"{x:.2f}x" for x in ratios) + f" | {median:.2f}x |")
    if env_only:
        print()
        print("tensor worlds alone (uniform random actions, no learner), steps/s")
        for n, sps in env_only.items():
            print(f"| {n} | {sps:.0f} |")


if __name__ == "__main__":
    main()
