"""Training throughput: SB3 students on Stump Tracks with a teacher in the loop vs without one,
and vs Gymnasium's Walker2d-v5 under the same student settings.

    python scripts/bench_training.py                    # ~1-2 min: ppo+sac, 1 and 2 envs
    python scripts/bench_training.py --students ppo --envs 2 --ppo-steps 8192

Every cell is `model.learn()` steps per wall-clock second after a warm-up (PPO: whole rollouts;
SAC: past learning_starts, so gradient steps are included). "Stump, no teacher" draws the same
uniform tasks inside the env (no teacher, no curriculum sync), so teacher/no-teacher is the cost
of the teacher in the loop. Ratios compare cells measured in this same run; on shared machines
repeat with --repeats and read the best.
"""

from __future__ import annotations

import argparse
import functools
import time

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecNormalize

from acl3d.training import students
from acl3d.training.curriculum import CurriculumVecEnv
from acl3d.training.workers import make_env, make_vec_env


class UniformTasks(gym.Wrapper):
    """The no-teacher baseline: the env itself draws a uniform task at every reset.

    Same task distribution as the Random teacher, so episode lengths (and reset costs) match
    the teacher runs and the ratio isolates the teacher + curriculum-sync overhead."""

    def __init__(self, env, seed: int):
        super().__init__(env)
        self.space = env.unwrapped.task_space
        self.rng = np.random.default_rng(seed)

    def reset(self, *, seed=None, options=None):
        task = self.rng.uniform(self.space.low, self.space.high)
        return self.env.reset(seed=seed, options={**(options or {}), "task": task})


def make_uniform_stump(seed: int):
    return UniformTasks(make_env("stump-tracks", "classic_bipedal"), seed)


class TimedCurriculumVecEnv(CurriculumVecEnv):
    """Counts the wall time spent on the teacher side (sampling, pushing, reporting)."""

    teacher_time = 0.0

    def _push(self, index):
        start = time.perf_counter()
        super()._push(index)
        TimedCurriculumVecEnv.teacher_time += time.perf_counter() - start

    def _report(self, worker, info):
        start = time.perf_counter()
        super()._report(worker, info)
        TimedCurriculumVecEnv.teacher_time += time.perf_counter() - start


def build_env(kind: str, n_envs: int, teacher: str, seed: int, student: str):
    if kind == "walker2d":
        venv = make_vec_env("Walker2d-v5", None, n_envs, curriculum=False)
    elif kind == "stump":
        fns = [functools.partial(make_uniform_stump, seed + i) for i in range(n_envs)]
        venv = DummyVecEnv(fns) if n_envs == 1 else SubprocVecEnv(fns, "forkserver")
    else:
        from acl3d.teachers.controller import TeacherController

        probe = make_env("stump-tracks", "classic_bipedal")
        space, profile = probe.unwrapped.task_space, probe.unwrapped.curriculum_profile
        probe.close()
        controller = TeacherController(teacher, space, seed, profile=profile)
        venv = TimedCurriculumVecEnv(
            make_vec_env("stump-tracks", "classic_bipedal", n_envs, curriculum=True), controller
        )
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


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--students", nargs="+", default=["ppo", "sac"], choices=students.STUDENTS)
    p.add_argument("--envs", nargs="+", type=int, default=[1, 2], help="numbers of workers")
    p.add_argument("--teacher", default="alp-gmm", help="teacher in the loop (default alp-gmm)")
    p.add_argument(
        "--ppo-steps", type=int, default=4096, help="timed PPO steps (at least 1 rollout)"
    )
    p.add_argument("--sac-steps", type=int, default=1500, help="timed SAC steps")
    p.add_argument("--repeats", type=int, default=1, help="best of N measurements per cell")
    p.add_argument("--preset", default="fast", choices=students.PRESETS, help="student preset")
    args = p.parse_args()
    torch.set_num_threads(1)

    kinds = ("teacher", "stump", "walker2d")
    rows = []
    for student in args.students:
        steps = args.ppo_steps if student == "ppo" else args.sac_steps
        for n_envs in args.envs:
            best = {k: 0.0 for k in kinds}
            share = 1.0
            for _ in range(args.repeats):
                for kind in kinds:  # interleaved, so load changes hit all three alike
                    sps, teacher_share = measure(
                        kind, student, n_envs, steps, args.teacher, args.preset
                    )
                    best[kind] = max(best[kind], sps)
                    if kind == "teacher":
                        share = min(share, teacher_share)
            best["share"] = share
            rows.append((student, n_envs, best))
            print(
                f"  measured {student} x{n_envs}: "
                + ", ".join(f"{k} {best[k]:.0f}" for k in kinds)
                + f", teacher side {100 * share:.1f}% of the wall time",
                flush=True,
            )

    print()
    print(
        f"training steps/s (SB3 '{args.preset}' preset; teacher = {args.teacher}; "
        f"best of {args.repeats})"
    )
    print(
        "| student | envs | Stump+teacher | Stump, no teacher | Walker2d-v5 "
        "| teacher/no-teacher | teacher-side time | Stump+teacher/Walker2d |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for student, n_envs, b in rows:
        print(
            f"| {student} | {n_envs} | {b['teacher']:.0f} | {b['stump']:.0f} | {b['walker2d']:.0f} "
            f"| {b['teacher'] / b['stump']:.2f} | {100 * b['share']:.1f}% "
            f"| {b['teacher'] / b['walker2d']:.2f} |"
        )


if __name__ == "__main__":
    main()
