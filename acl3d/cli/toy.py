"""`acl3d toy`: run one teacher on teachDeepRL's toy environment, optionally writing a GIF."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from acl3d.extras import optional_dependency
from acl3d.teachers import TEACHERS, make
from acl3d.teachers.expert_knowledge import toy_teacher_params
from acl3d.teachers.presets import PRESETS, preset_params
from acl3d.toy import ToyEnv, run_teacher


def _param(text: str) -> tuple[str, object]:
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--teacher",
        default="alp-gmm",
        choices=TEACHERS,
        metavar="TEACHER",
        help=f"{', '.join(TEACHERS)} (default alp-gmm)",
    )
    parser.add_argument("--episodes", type=int, default=20000, help="episodes (default 20000)")
    parser.add_argument(
        "--seed", type=int, default=0, help="seeds both the teacher and the toy's reward noise"
    )
    parser.add_argument("--nb-dims", type=int, default=2, help="relevant task dimensions")
    parser.add_argument("--nb-cubes", type=int, default=10, help="cubes per dimension")
    parser.add_argument(
        "--irrelevant-dims", type=int, default=0, help="extra task dimensions the toy ignores"
    )
    parser.add_argument(
        "--noise", type=float, default=0.0, help="std of Gaussian noise added to rewards"
    )
    parser.add_argument(
        "--space-ratio",
        type=float,
        default=1.0,
        help="task space side / learnable side per relevant dimension (3: only 1/9 of a 2-D"
        " space can be learned)",
    )
    parser.add_argument(
        "--preset",
        default="teachdeeprl",
        choices=sorted(PRESETS),
        help="teacher hyper-parameters (default: teachDeepRL's, as in its toy demo)",
    )
    parser.add_argument(
        "--teacher-param",
        dest="param",
        type=_param,
        action="append",
        default=[],
        metavar="K=V",
        help="teacher keyword argument (JSON value), repeatable; as acl3d train --teacher-param",
    )
    parser.add_argument(
        "--score-every",
        type=int,
        default=1000,
        help="episodes between two prints of the %% of mastered cubes (default 1000)",
    )
    parser.add_argument("--gif", default=None, help="write the sampling dynamics to this GIF")
    parser.add_argument("--gif-every", type=int, default=250, help="episodes per GIF frame")


def check_args(args: argparse.Namespace) -> None:
    """The counts, the seed and the GIF's path, before any episode: a mistake is named with its
    option and range at once, not after the run (an unwritable or non-GIF --gif used to fail
    only when the GIF was written)."""
    from acl3d import validation as check
    from acl3d.atomic_files import check_creatable_dir
    from acl3d.cli.option_values import seed_option

    check.integer("--episodes", args.episodes, 0)
    seed_option(args.seed)
    for name in ("nb_dims", "nb_cubes", "score_every", "gif_every"):
        check.integer(f"--{name.replace('_', '-')}", getattr(args, name), 1)
    check.integer("--irrelevant-dims", args.irrelevant_dims, 0)
    if args.gif is not None:
        gif = Path(args.gif)
        if gif.suffix.lower() != ".gif" or gif.is_dir():
            raise check.fail("--gif", args.gif, "a file path ending in .gif")
        check_creatable_dir(gif.parent, "--gif's folder")
        with optional_dependency("acl3d toy --gif", "train"):  # drawn and written at the end
            import imageio  # noqa: F401
            import matplotlib  # noqa: F401


def run(args: argparse.Namespace) -> int:
    check_args(args)
    env = ToyEnv(
        args.nb_dims,
        args.nb_cubes,
        args.irrelevant_dims,
        args.noise,
        seed=args.seed,
        space_ratio=args.space_ratio,
    )
    params = (
        preset_params(args.preset, args.teacher)
        | toy_teacher_params(args.teacher, env.curriculum_profile, env.task_space())
        | dict(args.param)
    )
    teacher = make(args.teacher, env.task_space(), seed=args.seed, **params)
    recorder = None
    if args.gif:
        from acl3d.teachers.plots import SamplingRecorder

        recorder = SamplingRecorder(
            teacher,
            every=args.gif_every,
            background=env.competence_map,
            background_extent=(0.0, 1.0, 0.0, 1.0),  # the cubes cover the learnable box
        )

    def report(episode: int, score: float) -> None:
        print(f"episode {episode:>7d}: {score:5.1f}% mastered cubes", flush=True)

    result = run_teacher(
        teacher, env, args.episodes, args.score_every, observer=recorder, on_score=report
    )
    print(
        f"{args.teacher} ({args.preset}): {env.score():.1f}% mastered cubes after {args.episodes} episodes; teacher CPU {result.cpu_per_1000:.3f} s / 1000 episodes"
    )
    if recorder is not None:
        from acl3d.teachers.plots import write_gif

        space = env.task_space()
        path = write_gif(
            recorder.frames,
            args.gif,
            space.low,
            space.high,
            space.flat_names(),
            title=f"{args.teacher} | ",
        )
        print(f"wrote {path} ({len(recorder.frames)} frames)")
    return 0
