"""`acl3d train`: train a student on a teacher's curriculum (or `--resume RUN_DIR`).

Options come from TrainConfig defaults, then a YAML/TOML `--config` file, then the command line.
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import sys
from pathlib import Path

from acl3d.bodies import BODIES
from acl3d.cli.option_values import (
    MAPPING_OPTIONS,
    count,
    key_values,
    load_config_file,
    parse_bounds,
)
from acl3d.cli.test_set_options import add_test_set_arguments
from acl3d.envs import ENV_NAMES
from acl3d.teachers import TEACHERS
from acl3d.teachers.expert_knowledge import LEVELS as EXPERT_KNOWLEDGE
from acl3d.training.config import (
    BENCHMARK,
    DEFAULT_CPU_WORLDS,
    DEFAULT_GPU_WORLDS,
    DEFAULT_N_ENVS,
    TrainConfig,
)

_DEFAULTS = TrainConfig()

_FLAGS = {  # store_true options: config field -> help
    "shuffle_dimensions": "cut each task dimension in 4 and shuffle the pieces (rugged difficulty)",
    "scale_reward": "give the teacher returns scaled to [0, 1] with the env's reward bounds",
    "eval_stochastic": "evaluate with sampled actions (TeachMyAgent's PPO) instead of the mean",
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", help="YAML or TOML file holding any option below (CLI wins)")
    p.add_argument("--resume", metavar="RUN_DIR", help="continue this run from its last checkpoint")
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="start the run in --out afresh, deleting the run already there (not while it runs)",
    )
    g = p.add_argument_group(
        "what to train",
        "With no option: an ALP-GMM curriculum (expert knowledge high) for rsl_rl's PPO with the "
        "fast preset on 64 worlds of Stump Tracks, 2M steps, 25 test tasks; minutes on a laptop.",
    )
    g.add_argument(
        "--benchmark",
        choices=tuple(BENCHMARK),
        help="TeachMyAgent's protocol for this student: benchmark preset, 20M steps, 100 test "
        "tasks, expert knowledge low (options given with it win)",
    )
    g.add_argument(
        "--env",
        help=f"environment: {', '.join(ENV_NAMES)} or a Gymnasium id (default {_DEFAULTS.env})",
    )
    g.add_argument("--body", help=f"embodiment: {', '.join(BODIES)} (default {_DEFAULTS.body})")
    g.add_argument(
        "--teacher", help=f"curriculum teacher: {', '.join(TEACHERS)} (default {_DEFAULTS.teacher})"
    )
    g.add_argument(
        "--student",
        help=f"sac, ppo or any Stable-Baselines3 algorithm: sb3:TD3, sb3:A2C, pkg.mod:Class; "
        f"rsl-ppo: rsl_rl's PPO on torch tensors (default {_DEFAULTS.student})",
    )
    g.add_argument(
        "--preset",
        help="student hyperparameters: fast (small networks for CPUs) or benchmark "
        f"(TeachMyAgent's) (default {_DEFAULTS.preset})",
    )
    g.add_argument(
        "--steps",
        type=count,
        help=f"training environment steps (default {_DEFAULTS.steps:.0e})".replace("e+0", "e"),
    )
    g.add_argument(
        "--n-envs",
        type=int,
        help=f"parallel training environments (default: {DEFAULT_N_ENVS} for an SB3 student; "
        f"rsl-ppo: {DEFAULT_CPU_WORLDS} worlds on the CPU, {DEFAULT_GPU_WORLDS} on a GPU)",
    )
    g.add_argument("--seed", type=int, help="seed of teacher, student and environments (default 0)")
    g.add_argument(
        "--out", help="run directory to create (default: a new runs/TEACHER-STUDENT-seedN)"
    )
    g = p.add_argument_group("curriculum profile")
    g.add_argument(
        "--expert-knowledge",
        choices=EXPERT_KNOWLEDGE,
        help=f"what the teacher may know about the task space (default {_DEFAULTS.expert_knowledge})",
    )
    g.add_argument(
        "--reset-student-every",
        type=count,
        metavar="N",
        help="re-initialise the student every N steps",
    )
    g.add_argument(
        "--bounds",
        action="append",
        metavar="NAME=MIN,MAX",
        help="teacher bounds of a task parameter (repeatable), e.g. stump_height=0,9",
    )
    g.add_argument(
        "--teacher-param",
        action="append",
        metavar="K=V",
        help="teacher keyword argument (repeatable)",
    )
    g.add_argument(
        "--student-param",
        action="append",
        metavar="K=V",
        help="SB3 hyperparameter override (repeatable)",
    )
    g.add_argument("--buffer-size", type=count, help="SAC replay buffer size (benchmark: 2e6)")
    g.add_argument(
        "--exclude-exploratory",
        choices=tuple(_EXCLUDE_EXPLORATORY),
        help="leave Robust PLR / ACCEL's new and edited levels out of the student's updates "
        "(default auto: on with robust-plr and accel)",
    )
    g.add_argument(
        "--env-kwarg",
        action="append",
        metavar="K=V",
        help="environment keyword argument (repeatable)",
    )
    for name, text in _FLAGS.items():
        g.add_argument("--" + name.replace("_", "-"), action="store_true", default=None, help=text)
    g = p.add_argument_group("evaluation and checkpoints")
    g.add_argument(
        "--eval-every",
        type=count,
        help="steps between evaluations (default min(5e5, max(5e4, steps/5)): 5 per run from "
        "250k to 2.5M steps)",
    )
    g.add_argument(
        "--eval-envs", type=int, help="parallel evaluation environments (default n-envs)"
    )
    g.add_argument(
        "--eval-together",
        type=int,
        help="torch-native students: evaluations played side by side in one pass, their results "
        "written then (default 1; on the many-world simulation 10, i.e. a default run's all at "
        "its end)",
    )
    add_test_set_arguments(
        g, "the environment's default set", _DEFAULTS.nb_test_episodes, unset_is_none=True
    )
    g.add_argument(
        "--checkpoint-every", type=count, help="steps between checkpoints (default eval-every)"
    )
    g.add_argument(
        "--periodical-samples-every",
        type=count,
        help="steps between teacher snapshots for plots (0 = never; drawn from the teacher's "
        "generator, so they change the tasks that follow)",
    )
    g = p.add_argument_group("runtime")
    g.add_argument(
        "--vec-env",
        help="auto (default: batched for acl3d envs; warp for rsl-ppo on a GPU), batched, dummy, "
        "subproc or warp (MuJoCo Warp's many-world simulation; rsl-ppo only)",
    )
    g.add_argument(
        "--envs-per-worker",
        type=int,
        metavar="N",
        help="batched env: N envs per worker process (default: all envs in this process)",
    )
    g.add_argument("--start-method", help="worker processes: forkserver (default) or spawn")
    g.add_argument("--torch-threads", type=int, help="torch threads in this process (default 1)")
    g.add_argument("--device", help="torch device (default cpu)")
    g.add_argument(
        "--no-progress",
        dest="progress_bar",
        action="store_false",
        default=None,
        help="hide the progress bar",
    )
    g.add_argument(
        "--no-tensorboard",
        dest="tensorboard",
        action="store_false",
        default=None,
        help="write no TensorBoard logs (RUN/tb); the CSV logs are written either way",
    )
    g.add_argument(
        "--no-replay-buffer-save",
        dest="save_replay_buffer",
        action="store_false",
        default=None,
        help="do not store the SAC replay buffer in checkpoints (resume then starts with an empty buffer)",
    )
    g.add_argument(
        "--quiet",
        dest="verbose",
        action="store_const",
        const=0,
        default=None,
        help="print only warnings and the final line (SB3 verbose 0)",
    )


_EXCLUDE_EXPLORATORY = {"auto": "auto", "on": True, "off": False}


def options_from_args(args) -> dict:
    """Config file values, overridden by every option given on the command line."""
    options = dict(BENCHMARK[args.benchmark]) if args.benchmark else {}
    options.update(load_config_file(args.config) if args.config else {})
    simple = (
        "env", "body", "teacher", "student", "preset", "steps", "n_envs", "seed", "out",
        "expert_knowledge", "reset_student_every", "buffer_size", "eval_every", "eval_envs",
        "eval_together", "test_set", "nb_test_episodes", "checkpoint_every", "periodical_samples_every", "vec_env",
        "envs_per_worker", "start_method", "torch_threads", "device", "progress_bar",
        "save_replay_buffer", "tensorboard", "verbose",
        *_FLAGS,
    )  # fmt: skip
    for name in simple:
        value = getattr(args, name)
        if value is not None:
            options[name] = value
    if args.exclude_exploratory is not None:
        options["exclude_exploratory"] = _EXCLUDE_EXPLORATORY[args.exclude_exploratory]
    for name, items, parse in (
        ("bounds", args.bounds, parse_bounds),
        ("teacher_params", args.teacher_param, lambda x: key_values(x, "--teacher-param")),
        ("student_params", args.student_param, lambda x: key_values(x, "--student-param")),
        ("env_kwargs", args.env_kwarg, lambda x: key_values(x, "--env-kwarg")),
    ):
        if items:
            options[name] = {**options.get(name, {}), **parse(items)}
    return options


def default_run_dir(options: dict) -> str:
    """runs/TEACHER-STUDENT-seedN, or the first of its -2, -3, ... variants not yet taken."""
    config = TrainConfig.from_dict({k: v for k, v in options.items() if k != "out"})
    base = Path("runs") / f"{config.teacher}-{config.student}-seed{config.seed}"
    path, k = base, 1
    while path.exists():
        k += 1
        path = base.with_name(f"{base.name}-{k}")
    return str(path)


_FIELD_MESSAGE = re.compile(r"^(\w+)(?:\['([^']*)'\])?=")


def _how_to_continue(run) -> str:
    """What a stopped run can do next: resume if it has a checkpoint, else start again."""
    if run.latest_checkpoint_name() is not None:
        return f"continue with: acl3d train --resume {run.path}"
    if run.exists():
        return f"no checkpoint yet: start again with --overwrite --out {run.path}"
    return "nothing was written"


# options whose flag is not --FIELD-NAME (switches that turn a default off)
_SPELLED_OFF = {
    "progress_bar": "--no-progress",
    "tensorboard": "--no-tensorboard",
    "save_replay_buffer": "--no-replay-buffer-save",
    "verbose": "--quiet",
}


def _flag(field: str) -> str:
    return _SPELLED_OFF.get(field, f"--{field.replace('_', '-')}")


def option_message(message: str) -> str:
    """A config check's message with the option's command-line spelling: `n_envs=0; ...` reads
    `--n-envs=0; ...`, `student_params['gamma']=2; ...` reads `--student-param gamma=2; ...`,
    `cannot change ['n_envs'] ...` reads `cannot change [--n-envs] ...`."""
    message = " ".join(message.split())  # one line
    fields = {f.name for f in dataclasses.fields(TrainConfig)}
    if message.startswith("cannot change ["):  # a resume's fixed options, as typed
        return re.sub(r"'(\w+)'", lambda m: _flag(m[1]) if m[1] in fields else m[0], message)
    match = _FIELD_MESSAGE.match(message)
    if match is None or match[1] not in fields:
        return message
    field, key = match[1], match[2]
    if field in MAPPING_OPTIONS and key is not None:
        return f"{MAPPING_OPTIONS[field]} {key}={message[match.end() :]}"
    return f"{_flag(field)}={message[match.end() :]}"


def run(args) -> int:
    from acl3d.atomic_files import check_creatable_dir, is_disk_full
    from acl3d.training import train
    from acl3d.training.run_dir import RunDir

    options = options_from_args(args)
    if not args.resume and not options.get("out"):
        options["out"] = default_run_dir(options)
        print(f"[acl3d] writing the run to {options['out']} (--out to choose)")
    where = args.resume or options.get("out")
    if args.resume:  # a read-only mount: refused before anything is built
        check_creatable_dir(Path(args.resume), "--resume")
    try:
        result = (
            train(resume=args.resume, overwrite=args.overwrite, **options)
            if args.resume
            else train(options, overwrite=args.overwrite)
        )
    except ValueError as exc:
        raise ValueError(option_message(str(exc))) from None
    except OSError as exc:
        if not is_disk_full(exc):
            raise
        name = f" writing {exc.filename}" if exc.filename else ""
        how = _how_to_continue(RunDir(where)) if where else ""
        print(
            f"acl3d train: error: no space left on device{name}; free some space, then {how}",
            file=sys.stderr,
        )
        return 1
    except KeyboardInterrupt:
        how = _how_to_continue(RunDir(where)) if where else "nothing was written"
        print(f"acl3d train: interrupted; {how}")
        return 130
    final = result.final_eval or {}
    print(
        f"run {result.run_dir}: {result.steps} steps, "
        f"{final.get('mastered_pct', float('nan')):.1f}% mastered, "
        f"mean test return {final.get('mean_return', float('nan')):.1f}"
    )
    return 0
