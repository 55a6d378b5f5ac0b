"""`acl3d evaluate RUN_DIR|MODEL.zip`: % mastered and mean return of a policy on a test set.

On a run directory the defaults reproduce the run's own last evaluation exactly: its test set,
its evaluation seed, its number of evaluation envs and its deterministic/stochastic choice
(`--seed`, `--n-envs`, `--test-set`, `--stochastic/--deterministic` vary them).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from acl3d import validation as check
from acl3d.cli.test_set_options import add_test_set_arguments
from acl3d.cli.train import option_message
from acl3d.training.config import TrainConfig

BARE_ZIP_SEED = 0
BARE_ZIP_ENVS = 2


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "target", metavar="RUN_DIR|MODEL.zip", help="a run directory or an SB3 model zip"
    )
    add_test_set_arguments(
        p, "the run's test set, else the environment's default set", TrainConfig().nb_test_episodes
    )
    p.add_argument("--episodes", type=int, default=1, help="episodes per test task (default 1)")
    p.add_argument("--env", help="track (default: the run's; required for a bare model zip)")
    p.add_argument("--body", help="embodiment (default: the run's, else classic_bipedal)")
    p.add_argument(
        "--n-envs",
        type=int,
        help=f"parallel evaluation environments (default: the run's, else {BARE_ZIP_ENVS}); the "
        "split of test tasks over envs changes the environment noise each task sees",
    )
    mode = p.add_mutually_exclusive_group()
    mode.add_argument(
        "--stochastic",
        dest="deterministic",
        action="store_false",
        default=None,
        help="sample actions (default: as the run evaluated, else the mean action)",
    )
    mode.add_argument(
        "--deterministic", dest="deterministic", action="store_true", help="use the mean action"
    )
    p.add_argument(
        "--seed",
        type=int,
        help=f"seed of the evaluation envs (default: the run's evaluation seed, else {BARE_ZIP_SEED})",
    )
    p.add_argument("--out", help="write one CSV row per test episode here")
    p.add_argument(
        "--raw-observations",
        action="store_true",
        help="evaluate a PPO model whose normalisation statistics (MODEL_vecnormalize.json/.npz) "
        "are missing on raw observations, with a warning, instead of refusing",
    )


@dataclass
class Target:
    """What to evaluate and the settings the run itself evaluated with (None for a bare zip)."""

    model: Path
    env: str
    body: str
    env_kwargs: dict
    tasks: np.ndarray | None
    seed: int
    n_envs: int
    deterministic: bool
    run_dir: Path | None = None


def resolve_target(target, env: str | None, body: str | None) -> Target:
    """The model, env and the run's own evaluation settings for a run dir or a bare zip."""
    from acl3d.training import TrainConfig
    from acl3d.training.run_dir import RunDir

    path = Path(target)
    if path.is_dir():
        run = RunDir(path)
        config = TrainConfig.recorded(run.read_section("config"), str(run.config_yaml))
        run.read_section("resolved")  # as resume: a config.yaml cut short is refused
        return Target(
            run.best_model(),
            env or config.env,
            body or config.body,
            dict(config.env_kwargs),
            run.test_tasks(),
            config.eval_seed,
            config.effective_eval_envs,
            not config.eval_stochastic,
            run.path,
        )
    if path.suffix != ".zip" or not path.exists():
        raise ValueError(f"{target!r} is neither a run directory nor an existing model .zip")
    if env is None:
        raise ValueError("--env is required when evaluating a bare model zip")
    return Target(
        path, env, body or "classic_bipedal", {}, None, BARE_ZIP_SEED, BARE_ZIP_ENVS, True
    )


def check_normalization(model: Path, raw_observations: bool) -> None:
    """A PPO model trained by acl3d sees normalised observations: without the statistics saved
    beside it, its scores mean little, so it is refused unless `raw_observations` is asked."""
    from acl3d.training import checkpoint, students

    if checkpoint.observation_normalizer(model) is not None:
        return
    student = students.detect(model)
    if not students.uses_vecnormalize(student):
        return
    stats = checkpoint.normalization_path(model).name + ".json/.npz"
    if not raw_observations:
        raise ValueError(
            f"{model}: no normalisation statistics ({stats} beside it) for this "
            f"{student.upper()} model, which was trained on normalised observations; copy them "
            "beside the model, or pass --raw-observations to evaluate on raw observations"
        )
    print(
        f"acl3d evaluate: warning: {model} has no {stats}; evaluating on raw observations "
        "(the scores will differ from the run's)",
        file=sys.stderr,
    )


def model_step(path: Path) -> int | None:
    """The training step an SB3 zip was saved at (from its own metadata)."""
    try:
        with zipfile.ZipFile(path) as z:
            return int(json.loads(z.read("data"))["num_timesteps"])
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return None


def run_evaluation_at(run_dir: Path, step: int | None) -> dict | None:
    """The run's own evals.csv row for `step`, if it evaluated there."""
    from acl3d.run_format.tables import read_csv
    from acl3d.training.run_dir import RunDir

    evals = RunDir(run_dir).evals_csv
    cols = read_csv(evals) if evals.exists() else {}
    steps = cols.get("step") or []
    if step is None or float(step) not in steps:
        return None
    i = len(steps) - 1 - steps[::-1].index(float(step))
    return {k: v[i] for k, v in cols.items()}


def check_args(args) -> None:
    """Bounds of the counts (memory, processes) and a writable --out, before any evaluation."""
    from acl3d.atomic_files import check_writable_file
    from acl3d.envs.batched import MAX_ENVS
    from acl3d.training.config import MAX_SEED, MAX_TEST_EPISODES

    for name, high in (
        ("episodes", MAX_TEST_EPISODES),
        ("n_envs", MAX_ENVS),
        ("nb_test_episodes", MAX_TEST_EPISODES),
        ("seed", MAX_SEED),
    ):
        value = getattr(args, name)
        if value is not None:
            check.integer(f"--{name.replace('_', '-')}", value, 0 if name == "seed" else 1, high)
    if args.out:
        check_writable_file(Path(args.out), "--out")


def check_episodes(episodes: int, n_tasks: int) -> None:
    """All the test episodes together within the bound of a test pass (memory, time)."""
    from acl3d.training.config import MAX_TEST_EPISODES

    most = max(1, MAX_TEST_EPISODES // n_tasks)
    if episodes > most:
        raise check.fail(
            "--episodes",
            episodes,
            f"an integer in [1, {most}]: {n_tasks} test tasks x --episodes must be <= "
            f"{MAX_TEST_EPISODES} episodes",
        )


def run(args) -> int:
    from acl3d.run_format.checkpoints import check_zip
    from acl3d.teachers import test_sets
    from acl3d.training.checkpoint import MODEL_MEMBERS
    from acl3d.training.evaluation import evaluate_saved_model
    from acl3d.training.workers import make_env

    check_args(args)
    t = resolve_target(args.target, args.env, args.body)
    check_zip(t.model, MODEL_MEMBERS)
    probe = make_env(t.env, t.body, t.env_kwargs)  # also checks the env and body names
    try:
        space = probe.unwrapped.task_space
        profile = getattr(probe.unwrapped, "curriculum_profile", None)
    finally:
        probe.close()
    if args.test_set is None and t.tasks is not None:
        tasks, test_set = t.tasks, "the run's test set"
    else:
        try:
            tasks = test_sets.resolve(args.test_set, space, args.nb_test_episodes, profile)
        except ValueError as exc:
            raise ValueError(option_message(str(exc))) from None
        test_set = f"test set {args.test_set or 'default'}"
    check_episodes(args.episodes, len(tasks))
    seed = t.seed if args.seed is None else args.seed
    n_envs = t.n_envs if args.n_envs is None else args.n_envs
    deterministic = t.deterministic if args.deterministic is None else args.deterministic
    check_normalization(t.model, args.raw_observations)
    step = model_step(t.model)
    print(
        f"evaluating {t.model} (step {step}) on {test_set} ({len(tasks)} tasks x {args.episodes}), "
        f"seed {seed}, {n_envs} envs, {'deterministic' if deterministic else 'stochastic'} actions"
    )
    names = space.flat_names() if space.dim == tasks.shape[1] else range(tasks.shape[1])
    result = evaluate_saved_model(
        t.model,
        t.env,
        t.body,
        tasks,
        env_kwargs=t.env_kwargs,
        n_envs=n_envs,
        deterministic=deterministic,
        seed=seed,
        episodes_per_task=args.episodes,
    )
    if args.out:
        with open(args.out, "w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(["task_index", "return", "length", "success", *names])
            for i, (task, ret, length, ok) in enumerate(
                zip(result.tasks, result.returns, result.lengths, result.successes)
            ):
                writer.writerow(
                    [i, f"{ret:.6g}", int(length), int(ok), *(f"{v:.6g}" for v in task)]
                )
    s = result.summary()
    print(
        f"{t.model}: {s['n_tasks']} test episodes on {t.env} ({t.body}): "
        f"{s['mastered_pct']:.1f}% mastered (return > {result.success_return:g}), mean return {s['mean_return']:.1f} "
        f"+- {s['std_return']:.1f}, mean length {s['mean_length']:.0f}"
    )
    own = run_evaluation_at(t.run_dir, step) if t.run_dir is not None else None
    if own is not None:
        print(
            f"the run's own evaluation at step {step}: {own['mastered_pct']:.1f}% mastered, "
            f"mean return {own['mean_return']:.1f} (the same when every setting above is the run's)"
        )
    return 0
