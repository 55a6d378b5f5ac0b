"""A teacher of your own, trained with `acl3d train`: one `Teacher` subclass, one `register`.

    python scripts/examples/custom_teacher.py --steps 20000 --out runs/my_teacher

Needs `pip install "acl3d[train]"` (torch and the students, for `acl3d train`).

`EasyFirst` proposes uniform tasks, but only among the easiest `fraction` of each dimension
until the student's recent episodes succeed often enough; then the fraction grows. It declares
what it needs on the class (nothing beyond returns and success here; see `Teacher`'s docstring
for step rewards, initial states, value estimates and exploratory levels) and keeps its state in
`_extra_state` so a run resumes exactly. After `register(EasyFirst)` it is a teacher like the
shipped ones: `train(teacher="easy-first")` or the command line in the same process (or
`acl3d train --teacher mypackage.teachers:EasyFirst` from a shell, with no registration).
"""

from __future__ import annotations

import argparse

import numpy as np

from acl3d.cli import main as acl3d_main
from acl3d.teachers import Teacher, register
from acl3d.training import train


@register
class EasyFirst(Teacher):
    """Uniform tasks in the easy part of each range, widened as the student succeeds."""

    name = "easy-first"
    needs = frozenset({"success"})

    def __init__(self, task_space, seed=None, start: float = 0.2, step: float = 0.2, window=20):
        super().__init__(task_space, seed)
        self.fraction, self.step, self.window = float(start), float(step), int(window)
        self.successes: list[bool] = []

    def _sample(self) -> np.ndarray:
        return self.mins + self.rng.random(self.dim) * self.fraction * (self.maxs - self.mins)

    def _episodic_update(self, task, reward, is_success) -> None:
        self.successes.append(is_success)
        recent = self.successes[-self.window :]
        if len(recent) == self.window and np.mean(recent) >= 0.5 and self.fraction < 1.0:
            self.fraction = min(1.0, self.fraction + self.step)
            self.successes.clear()
            self.bk["fraction"].append(self.fraction)  # book-keeping, saved in the run's dump

    def _extra_state(self) -> dict:
        return {"fraction": self.fraction, "successes": list(self.successes)}

    def _load_extra_state(self, extra: dict) -> None:
        self.fraction = float(extra["fraction"])
        self.successes = [bool(s) for s in extra["successes"]]


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=20_000)
    p.add_argument("--out", default="runs/easy_first")
    p.add_argument("--max-episode-steps", type=int, default=2000)
    p.add_argument("--n-steps", type=int, help="PPO steps per env per rollout (default: preset)")
    args = p.parse_args(argv)
    rollout = {} if args.n_steps is None else {"n_steps": args.n_steps, "batch_size": 64}
    common = {
        "env": "stump-tracks",
        "student": "ppo",
        "preset": "fast",
        "n_envs": 4,
        "steps": args.steps,
        "env_kwargs": {"max_episode_steps": args.max_episode_steps},
        "test_set": "uniform",
        "nb_test_episodes": 4,
        "tensorboard": False,
        "progress_bar": False,
        "student_params": rollout,
    }
    # from Python ...
    result = train(teacher="easy-first", teacher_params={"start": 0.3}, out=args.out, **common)
    print(f"train(): {result.steps} steps, final evaluation {result.final_eval}")
    # ... and through the command line's entry point (same process, so the registration holds)
    rc = acl3d_main(
        ["train", "--teacher", "easy-first", "--teacher-param", "window=10", "--env",
         "stump-tracks", "--student", "ppo", "--preset", "fast", "--n-envs", "4", "--steps",
         str(args.steps), "--env-kwarg", f"max_episode_steps={args.max_episode_steps}",
         "--test-set", "uniform", "--nb-test-episodes", "4", "--no-tensorboard", "--no-progress",
         "--quiet", "--out", args.out + "_cli"]
        + [f"--student-param={k}={v}" for k, v in rollout.items()]
    )  # fmt: skip
    return result, rc


if __name__ == "__main__":
    main()
