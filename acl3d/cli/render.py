"""`acl3d render`: write an mp4/gif of rollouts on a track (random or zero actions)."""

from __future__ import annotations

import argparse

import numpy as np


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--env", default="stump-tracks", help="environment (stump-tracks, hexagon-tracks, ...)"
    )
    p.add_argument("--body", default="classic_bipedal", help="body name (see acl3d.bodies.BODIES)")
    p.add_argument(
        "--planar",
        choices=("yes", "no", "default"),
        default="default",
        help="sagittal-plane or free 3D body",
    )
    p.add_argument(
        "--task", default="", help='task, e.g. "stump_height=1.5,obstacle_spacing=3" or a JSON dict'
    )
    p.add_argument("--episodes", type=int, default=1)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--policy", choices=("random", "zero"), default="random", help="actions to play")
    p.add_argument("--max-steps", type=int, default=2000, help="steps per episode at most")
    p.add_argument("--every", type=int, default=1, help="keep every N-th frame (smaller GIFs)")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument(
        "--quality",
        choices=("fast", "high"),
        default="fast",
        help="high: MSAA + shadows for publication",
    )
    p.add_argument("--out", default="rollout.mp4", help="output .mp4 or .gif")
    p.add_argument("--no-progress", action="store_true")


def run(args: argparse.Namespace) -> int:
    from acl3d.envs import make
    from acl3d.video import record_rollouts

    if args.episodes < 1:
        raise ValueError(f"--episodes={args.episodes}: must be >= 1")
    planar = {"yes": True, "no": False, "default": None}[args.planar]
    env = make(
        args.env,
        body=args.body,
        planar=planar,
        render_mode="rgb_array",
        width=args.width,
        height=args.height,
        quality=args.quality,
    )
    try:
        task = env.unwrapped.task_space.parse(args.task) if args.task else {}
        rng = np.random.default_rng(args.seed)
        space = env.action_space
        if args.policy == "random":

            def policy(obs):
                return rng.uniform(space.low, space.high)
        else:

            def policy(obs):
                return np.zeros(space.shape)

        summaries = record_rollouts(
            env,
            policy,
            args.out,
            tasks=[task] * args.episodes,
            seed=args.seed,
            max_steps=args.max_steps,
            every=args.every,
            progress=not args.no_progress,
        )
    finally:
        env.close()
    for i, s in enumerate(summaries):
        print(
            f"episode {i}: return {s['return']:.1f}, length {s['length']}, success {s['success']}"
        )
    print(f"wrote {args.out}")
    return 0
