"""`acl3d evaluate RUN_DIR|MODEL.zip`: % mastered and mean return of a policy on a test set.

On a run directory the defaults reproduce the run's own last evaluation exactly: its test set,
its evaluation seed, its number of evaluation envs and its deterministic/stochastic choice; a
model zip of a run (RUN/final_model.zip, RUN/checkpoints/step_N/model.zip) is evaluated with
the same settings
(`--seed`, `--n-envs`, `--test-set`, `--stochastic/--deterministic` vary them). A torch-native
student's policy file (`rsl-ppo`) is played as its run evaluated: one world per test task, task
k seeded seed + k, on the CPU batched env, or for a run trained on the many-world simulation on
that simulation, on the run's device (Warp's CPU device where that GPU is missing).
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
        "target",
        metavar="RUN_DIR|MODEL.zip",
        help="a run directory, an SB3 model zip or a torch-native student's policy file",
    )
    add_test_set_arguments(
        p,
        "the run's test set, else the environment's default set",
        TrainConfig().nb_test_episodes,
        unset_is_none=True,
        nb_default_text=f"{TrainConfig().nb_test_episodes}; given for a run, its kind of test set "
        "is drawn at this size instead of its own tasks",
    )
    p.add_argument("--episodes", type=int, default=1, help="episodes per test task (default 1)")
    p.add_argument("--env", help="track (default: the run's; required for a bare model zip)")
    p.add_argument("--body", help="embodiment (default: the run's, else classic_bipedal)")
    p.add_argument(
        "--n-envs",
        type=int,
        help=f"parallel evaluation environments (default: the run's, else {BARE_ZIP_ENVS}; a "
        "policy file: one per test task); for an SB3 model the split of test tasks over envs "
        "changes the environment noise each task sees",
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
    policy_file: bool = False  # a torch-native student's (else an SB3 zip)
    many_worlds_device: str | None = None  # where a policy file's run evaluated on many worlds
    test_set: str | None = None  # the run's --test-set (None: the default rule)


def enclosing_run(model: Path) -> Path | None:
    """The run directory a model zip belongs to (RUN/final_model.zip or
    RUN/checkpoints/step_N/model.zip, RUN holding a config.yaml), else None."""
    folders = [model.parent]
    if model.parent.parent.name == "checkpoints":
        folders.append(model.parent.parent.parent)
    return next((f for f in folders if (f / "config.yaml").is_file()), None)


def resolve_target(target, env: str | None, body: str | None) -> Target:
    """The model, env and the run's own evaluation settings for a run dir or a model zip of a
    run (its final model or a checkpoint's); a zip outside any run gets the bare defaults."""
    from acl3d.envs.batched import MAX_ENVS
    from acl3d.training.torch_student.policy_file import is_policy_file

    path = Path(target)
    if path.is_dir():
        return _run_target(path, None, env, body)
    if path.suffix != ".zip" or not path.exists():
        raise ValueError(f"{target!r} is neither a run directory nor an existing model .zip")
    run = enclosing_run(path)
    if run is not None:
        return _run_target(run, path, env, body)
    if env is None:
        raise ValueError(
            f"--env is required for a model zip outside a run directory ({target!r}: no "
            "config.yaml of a run beside it or above its checkpoint folder)"
        )
    policy = is_policy_file(path)
    n_envs = MAX_ENVS if policy else BARE_ZIP_ENVS
    return Target(
        path, env, body or "classic_bipedal", {}, None, BARE_ZIP_SEED, n_envs, True, None, policy
    )


def _run_target(path: Path, model: Path | None, env: str | None, body: str | None) -> Target:
    """`model` (default: the run's best) with the settings run `path` evaluated with."""
    from acl3d.envs.batched import MAX_ENVS
    from acl3d.training import TrainConfig
    from acl3d.training.config import uses_many_worlds
    from acl3d.training.run_dir import RunDir
    from acl3d.training.torch_student.policy_file import is_policy_file

    run = RunDir(path)
    config = TrainConfig.recorded(run.read_section("config"), str(run.config_yaml))
    run.read_section("resolved")  # as resume: a config.yaml cut short is refused
    model = model or run.best_model()
    policy = is_policy_file(model)
    # another env than the run's: its own default tasks, not the run's (another task space)
    own_env = env is None or _same_env(env, config.env)
    return Target(
        model,
        env or config.env,
        body or config.body,
        dict(config.env_kwargs) if own_env else {},
        run.test_tasks() if own_env else None,
        config.eval_seed,
        (config.eval_envs or MAX_ENVS) if policy else config.effective_eval_envs,
        not config.eval_stochastic,
        run.path,
        policy,
        _many_worlds_device(config) if policy and uses_many_worlds(config) else None,
        config.test_set if own_env else None,
    )


def _same_env(a: str, b: str) -> bool:
    """Whether two env names (short names or Gymnasium ids) are one environment."""
    from acl3d.envs import env_id

    try:
        return env_id(a) == env_id(b)
    except ValueError:  # a Gymnasium id outside acl3d
        return a == b


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


def model_step(t: Target) -> int | None:
    """The training step the model was saved at: an SB3 zip's own metadata; a policy file's
    checkpoint folder (step_N), or for a run's final model the steps its status records."""
    from acl3d.run_format.checkpoints import checkpoint_step
    from acl3d.run_format.status import read_status

    if not t.policy_file:
        try:
            with zipfile.ZipFile(t.model) as z:
                return int(json.loads(z.read("data"))["num_timesteps"])
        except (OSError, KeyError, ValueError, zipfile.BadZipFile):
            return None
    step = checkpoint_step(t.model.parent.name)
    if step is None and t.run_dir is not None and t.model.parent == t.run_dir:
        status = read_status(t.run_dir)
        step = status.fields.get("steps") if status is not None else None
    return None if step is None else int(step)


def _many_worlds_device(config) -> str:
    """The run's device for its many worlds, or Warp's CPU device where that GPU is missing."""
    import torch

    device = "cpu" if config.device == "auto" else str(config.device)
    if device.startswith("cuda") and not torch.cuda.is_available():
        print(f"acl3d evaluate: the run evaluated on {device}, which this machine lacks: playing "
              "its worlds on Warp's CPU device (slower; float results may differ)", file=sys.stderr)  # fmt: skip
        return "cpu"
    return device


def evaluate_policy_file(
    t: Target, tasks, n_envs: int, deterministic: bool, seed: int, episodes: int
):
    """A torch-native student's policy file, played as its run's evaluations play (the test set
    repeated `episodes` times)."""
    from acl3d.training.torch_student.evaluation import ManyWorldEvaluator, WorldEvaluator
    from acl3d.training.torch_student.rsl_ppo import PolicySnapshot, SavedPolicy

    policy = SavedPolicy(t.model)
    repeated = np.repeat(np.atleast_2d(tasks), episodes, axis=0)
    where = (t.env, t.body, t.env_kwargs, repeated, seed, n_envs)
    snapshot = policy.snapshot
    if t.many_worlds_device is None:
        evaluator = WorldEvaluator(*where)
    else:
        evaluator = ManyWorldEvaluator(*where, t.many_worlds_device)
        actor = snapshot.actor.to(evaluator.device)
        snapshot = PolicySnapshot(policy.spec, actor, snapshot.low, snapshot.high)
    try:
        if evaluator.observation_shape != (policy.observation_size,):
            raise ValueError(
                f"model {str(t.model)!r} expects observations of shape "
                f"{(policy.observation_size,)}; env {t.env!r} with body {t.body!r} gives "
                f"{evaluator.observation_shape}"
            )
        return evaluator.run([snapshot], stochastic=not deterministic)[0]
    finally:
        evaluator.close()


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
    from acl3d.envs.task_env import task_env
    from acl3d.run_format.checkpoints import check_zip
    from acl3d.teachers import test_sets
    from acl3d.training.checkpoint import MODEL_MEMBERS
    from acl3d.training.evaluation import evaluate_saved_model
    from acl3d.training.torch_student.policy_file import POLICY_MEMBERS
    from acl3d.training.workers import make_env

    check_args(args)
    t = resolve_target(args.target, args.env, args.body)
    check_zip(t.model, POLICY_MEMBERS if t.policy_file else MODEL_MEMBERS)
    probe = make_env(t.env, t.body, t.env_kwargs)  # also checks the env and body names
    try:
        inner = task_env(probe)
        space, profile = inner.task_space, inner.curriculum_profile
    finally:
        probe.close()
    if args.test_set is None and args.nb_test_episodes is None and t.tasks is not None:
        tasks, test_set = t.tasks, "the run's test set"
    else:  # the one asked for, else the run's kind of test set drawn at the size asked for
        chosen = t.test_set if args.test_set is None else args.test_set
        nb = args.nb_test_episodes
        if nb is not None and not test_sets.generated(chosen):
            raise check.fail(
                "--nb-test-episodes", nb, f"with a test set drawn at a size: {chosen} is a file"
            )
        nb = TrainConfig().nb_test_episodes if nb is None else nb
        try:
            tasks = test_sets.resolve(chosen, space, nb, profile)
        except ValueError as exc:
            raise ValueError(option_message(str(exc))) from None
        test_set = f"test set {chosen or 'default'}"
    check_episodes(args.episodes, len(tasks))
    seed = t.seed if args.seed is None else args.seed
    n_envs = t.n_envs if args.n_envs is None else args.n_envs
    if t.policy_file:  # one world per test episode, up to n_envs
        n_envs = min(n_envs, len(tasks) * args.episodes)
    deterministic = t.deterministic if args.deterministic is None else args.deterministic
    if not t.policy_file:  # a policy file holds its observation normaliser
        check_normalization(t.model, args.raw_observations)
    step = model_step(t)
    print(
        f"evaluating {t.model} (step {step}) on {test_set} ({len(tasks)} tasks x {args.episodes}), "
        f"seed {seed}, {n_envs} envs, {'deterministic' if deterministic else 'stochastic'} actions"
    )
    names = space.flat_names() if space.dim == tasks.shape[1] else range(tasks.shape[1])
    if t.policy_file:
        result = evaluate_policy_file(t, tasks, n_envs, deterministic, seed, args.episodes)
    else:
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
