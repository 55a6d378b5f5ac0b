"""`acl3d render`: videos (mp4, gif) or PNG strips of rollouts, labelled with task, step and return.

Actions come from a trained model (`--model RUN_DIR|MODEL.zip`, with its VecNormalize
statistics), from several models side by side (`--compare A B ...`, one labelled cell each), or
are random/zero (`--policy`). `--curriculum RUN_DIR` animates a run's curriculum instead. Tasks: `--task` (repeatable), a test set (`--test-set`, the
`--episodes` tasks spread from easy to hard), the run's own test set, or the env's default task.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np


def add_arguments(p: argparse.ArgumentParser) -> None:
    what = p.add_mutually_exclusive_group()
    what.add_argument(
        "--model", metavar="RUN_DIR|MODEL.zip", help="play a trained policy (a run or a model zip)"
    )
    what.add_argument(
        "--compare",
        nargs="+",
        metavar="RUN",
        help="play the same tasks with several runs/models side by side (one cell each)",
    )
    what.add_argument(
        "--policy", choices=("random", "zero"), help="untrained actions (default: random)"
    )
    what.add_argument(
        "--curriculum",
        metavar="RUN_DIR",
        help="animate a run's curriculum: sampled tasks over training, with the teacher's state",
    )
    p.add_argument("--env", help="environment (default: the run's, else stump-tracks)")
    p.add_argument("--body", help="body name (default: the run's, else classic_bipedal)")
    p.add_argument(
        "--planar",
        choices=("yes", "no", "default"),
        default="default",
        help="sagittal-plane or free 3D body",
    )
    p.add_argument(
        "--task",
        action="append",
        default=[],
        help='a task, e.g. "stump_height=1.5,obstacle_spacing=3" or a JSON dict (repeatable)',
    )
    p.add_argument(
        "--test-set",
        help="play --episodes tasks of a test set (grid, uniform, a named set, .json/.csv)",
    )
    p.add_argument(
        "--episodes",
        type=int,
        default=1,
        help="episodes (one --task repeated, or tasks picked from the test set, easy to hard)",
    )
    p.add_argument(
        "--seed",
        type=int,
        help="seed of the first reset, as `acl3d evaluate` seeds its envs (default: the run's "
        "evaluation seed, as evaluate; 0 without a model)",
    )
    p.add_argument("--stochastic", action="store_true", help="sample the model's actions")
    p.add_argument("--max-steps", type=int, default=2000, help="steps per episode at most")
    p.add_argument("--every", type=int, default=1, help="keep every N-th frame (smaller GIFs)")
    p.add_argument("--width", type=int, default=640, help="frame (or grid cell) width")
    p.add_argument("--height", type=int, default=480, help="frame (or grid cell) height")
    p.add_argument("--cols", type=int, help="grid columns for --compare (default: near-square)")
    p.add_argument(
        "--quality",
        choices=("fast", "high"),
        default="fast",
        help="high: MSAA + shadows for publication",
    )
    p.add_argument("--no-overlay", action="store_true", help="no task/step/return label")
    p.add_argument("--format", choices=("mp4", "gif", "png"), help="default: from --out")
    p.add_argument("--strip-frames", type=int, default=6, help="frames per episode in a PNG strip")
    p.add_argument("--frames", type=int, default=40, help="frames of a --curriculum animation")
    p.add_argument(
        "--fps", type=int, help="frames per second (default: real time / --every; curriculum 4)"
    )
    p.add_argument("--out", default="rollout.mp4", help="output .mp4, .gif or .png (strip)")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")


# Upper bounds of the counts (memory: the tasks and a grid's frames are held at once).
_MOST = {
    "episodes": 1_000,
    "max_steps": 100_000,
    "every": 100_000,
    "width": 4_096,
    "height": 4_096,
    "strip_frames": 100,
    "frames": 10_000,
    "cols": 64,
    "fps": 1_000,
}


def _check_counts(args) -> None:
    from acl3d import validation as check
    from acl3d.cli.option_values import seed_option

    for name, most in _MOST.items():
        value = getattr(args, name)
        if value is not None:
            check.integer(f"--{name.replace('_', '-')}", value, 1, most)
    seed_option(args.seed)
    if len(args.task) > 1 and args.episodes != 1:
        raise ValueError("--episodes repeats a single --task; with several --task leave it at 1")
    if args.task and args.test_set:
        raise ValueError("--task and --test-set are exclusive: give tasks one way")


def _check_out(out: str, fmt: str | None) -> None:
    """A known format, and a file path whose folder can be made (a file on the way would
    otherwise fail only when the video is written, after every episode was played)."""
    from acl3d import validation as check
    from acl3d.atomic_files import check_creatable_dir
    from acl3d.video import output_format

    output_format(out, fmt)
    if Path(out).is_dir():
        raise check.fail("--out", out, "a file path, not a folder")
    check_creatable_dir(Path(out).parent, "--out's folder")


@dataclass
class Source:
    """What one video cell plays: a model (or None), its env, the run's test tasks and seed."""

    model: Path | None
    env: str
    body: str
    env_kwargs: dict
    tasks: np.ndarray | None
    seed: int
    title: str


def check_offscreen() -> None:
    """Make and free an offscreen GL context before anything is loaded, played or written: a
    machine that cannot render fails at once with one line naming the backend and the package
    to install, not with a traceback after the first outputs."""
    from acl3d.rendering import TrackRenderer

    try:
        import mujoco  # loads the backend's library: its failure is worded as a renderer's

        TrackRenderer(mujoco.MjModel.from_xml_string("<mujoco/>"), 64, 64).close()
    except RuntimeError as exc:  # the backend's failure, as acl3d.rendering words it
        raise ValueError(str(exc)) from None


def resolve_source(target, args) -> Source:
    from acl3d.cli.evaluate import resolve_target

    if target is None:
        return Source(
            None, args.env or "stump-tracks", args.body or "classic_bipedal", {}, None, 0, ""
        )
    t = resolve_target(target, args.env, args.body)
    title = Path(t.run_dir).name if t.run_dir else Path(target).stem
    if t.run_dir:
        from acl3d.training.run_dir import RunDir

        title += f" ({RunDir(t.run_dir).read_config().get('teacher', '?')})"
    return Source(t.model, t.env, t.body, dict(t.env_kwargs), t.tasks, t.seed, title)


def make_source_env(source: Source, args, **render_kwargs):
    """The env of `source`, built as the evaluation builds it when a model is played."""
    kwargs = dict(source.env_kwargs, **render_kwargs)
    if args.planar != "default":
        kwargs["planar"] = args.planar == "yes"
    if source.model is None:  # untrained actions: no training import (torch, SB3)
        from acl3d.envs import make

        return make(source.env, body=source.body, **kwargs)
    from acl3d.training.workers import make_env

    return make_env(source.env, source.body, kwargs)


def _tasks(env, args, run_tasks) -> list:
    """Tasks to play, as flat vectors (the env's task space checks them)."""
    from acl3d.envs.task_env import task_env
    from acl3d.teachers import test_sets
    from acl3d.training.report import pick_video_tasks

    inner = task_env(env)
    space = inner.task_space
    if args.task:
        tasks = [space.to_vector(space.parse(t)) for t in args.task]
        return tasks * args.episodes
    if args.test_set is not None:
        pool = test_sets.resolve(
            args.test_set, space, max(100, args.episodes), inner.curriculum_profile
        )
        return list(pick_video_tasks(pool, args.episodes))
    if run_tasks is not None:
        return list(pick_video_tasks(np.asarray(run_tasks), args.episodes))
    return [space.to_vector({})] * args.episodes


def make_policy(model, env, args):
    """(obs -> action, label): the model's policy, or random/zero actions without a model."""
    if model is None:
        rng = np.random.default_rng(args.seed or 0)
        space = env.action_space

        def zero(obs):
            return np.zeros(space.shape, dtype=space.dtype)

        def uniform(obs):
            return rng.uniform(space.low, space.high).astype(space.dtype)

        return (zero, "zero actions") if args.policy == "zero" else (uniform, "random actions")
    from acl3d.training.trained_policy import TrainedPolicy  # torch and SB3: only for a model

    policy = TrainedPolicy(model, deterministic=not args.stochastic)
    policy.check_env(env)
    return policy, None


def run(args: argparse.Namespace) -> int:
    from acl3d.envs.task_env import task_env
    from acl3d.playback import EpisodePlayer, record_grid

    _check_counts(args)
    _check_out(args.out, args.format)  # a bad --out fails before any env is built
    if args.curriculum:
        from acl3d.training.curriculum_animation import write_curriculum_animation

        write_curriculum_animation(
            args.curriculum, args.out, frames=args.frames, fps=args.fps or 4, fmt=args.format
        )
        print(f"wrote {args.out}")
        return 0
    check_offscreen()
    targets = args.compare or [args.model]
    players, tasks, seed = [], None, args.seed
    try:
        for target in targets:
            source = resolve_source(target, args)
            env = make_source_env(
                source,
                args,
                render_mode="rgb_array",
                width=args.width,
                height=args.height,
                quality=args.quality,
            )
            policy, label = make_policy(source.model, env, args)
            players.append(EpisodePlayer(env, policy, source.title or label, not args.no_overlay))
            if tasks is None:  # every cell plays the first source's tasks, with its seed
                tasks = _tasks(env, args, source.tasks)
                seed = source.seed if seed is None else seed
            inner = task_env(env)
            for task in tasks:  # an unbuildable task fails before anything is played
                inner.set_task(task)
        summaries = record_grid(
            players,
            args.out,
            tasks,
            seed=seed,
            max_steps=args.max_steps,
            every=args.every,
            fps=args.fps,
            progress=not args.no_progress,
            cols=args.cols if args.compare else 1,
            fmt=args.format,
            strip_frames=args.strip_frames,
        )
    finally:
        for player in players:
            player.env.close()
    for player, runs in zip(players, summaries):
        prefix = f"{player.title}: " if args.compare else ""
        for i, s in enumerate(runs):
            print(
                f"{prefix}episode {i}: return {s['return']:.1f}, length {s['length']}, "
                f"success {s['success']}"
            )
    print(f"wrote {args.out}")
    return 0
