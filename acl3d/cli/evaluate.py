"""`acl3d evaluate RUN_DIR|MODEL.zip`: % mastered and mean return of a policy on a test set."""

from __future__ import annotations

import argparse
import csv
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "target", metavar="RUN_DIR|MODEL.zip", help="a run directory or an SB3 model zip"
    )
    p.add_argument(
        "--test-set",
        help="grid, uniform or a .json/.csv file (default: the run's test set, else the controller default)",
    )
    p.add_argument(
        "--nb-test-episodes",
        type=int,
        default=100,
        help="size of a generated test set (default 100)",
    )
    p.add_argument("--episodes", type=int, default=1, help="episodes per test task (default 1)")
    p.add_argument("--env", help="track (default: the run's; required for a bare model zip)")
    p.add_argument("--body", help="embodiment (default: the run's, else classic_bipedal)")
    p.add_argument(
        "--n-envs", type=int, default=2, help="parallel evaluation environments (default 2)"
    )
    p.add_argument(
        "--stochastic", action="store_true", help="sample actions instead of using the mean"
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", help="write one CSV row per test episode here")


def resolve_target(target, env: str | None, body: str | None):
    """(model path, env name, body, env kwargs, run's test tasks or None) for a run dir or zip."""
    from acl3d.training.run_dir import RunDir

    path = Path(target)
    if path.is_dir():
        run = RunDir(path)
        config = run.read_config()
        return (
            run.best_model(),
            env or config["env"],
            body or config["body"],
            config.get("env_kwargs") or {},
            run.test_tasks(),
        )
    if path.suffix != ".zip" or not path.exists():
        raise ValueError(f"{target!r} is neither a run directory nor an existing model .zip")
    if env is None:
        raise ValueError("--env is required when evaluating a bare model zip")
    return path, env, body or "classic_bipedal", {}, None


def run(args) -> int:
    from acl3d.teachers import test_sets
    from acl3d.training.evaluation import evaluate_saved_model
    from acl3d.training.workers import make_env

    for name in ("episodes", "n_envs", "nb_test_episodes"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    model, env_name, body, env_kwargs, run_tasks = resolve_target(args.target, args.env, args.body)
    probe = make_env(env_name, body, env_kwargs)  # also checks the env and body names
    try:
        space = probe.unwrapped.task_space
        profile = getattr(probe.unwrapped, "curriculum_profile", None)
    finally:
        probe.close()
    if args.test_set is None and run_tasks is not None:
        tasks = run_tasks
    else:
        tasks = test_sets.resolve(args.test_set, space, args.nb_test_episodes, profile)
    names = space.flat_names() if space.dim == tasks.shape[1] else range(tasks.shape[1])
    result = evaluate_saved_model(
        model,
        env_name,
        body,
        tasks,
        env_kwargs=env_kwargs,
        n_envs=args.n_envs,
        deterministic=not args.stochastic,
        seed=args.seed,
        episodes_per_task=args.episodes,
    )
    if args.out:
        with open(args.out, "w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(
                [
                    "task_index",
                    "return",
                    "length",
                    "success",
                    *names,
                ]
            )
            for i, (task, ret, length, ok) in enumerate(
                zip(result.tasks, result.returns, result.lengths, result.successes)
            ):
                writer.writerow(
                    [i, f"{ret:.6g}", int(length), int(ok), *(f"{v:.6g}" for v in task)]
                )
    s = result.summary()
    print(
        f"{model}: {s['n_tasks']} test episodes on {env_name} ({body}): "
        f"{s['mastered_pct']:.1f}% mastered (return > 230), mean return {s['mean_return']:.1f} "
        f"+- {s['std_return']:.1f}, mean length {s['mean_length']:.0f}"
    )
    return 0
