"""`acl3d view`: watch a body (random actions or a trained model) in MuJoCo's interactive viewer.

Needs a display. Enter: restart with a new random task; an episode that ends restarts on the
same task; closing the window ends the command.
"""

from __future__ import annotations

import argparse

import numpy as np


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--env", help="environment (default: the run's, else stump-tracks)")
    p.add_argument("--body", help="body name (default: the run's, else classic_bipedal)")
    p.add_argument(
        "--planar", choices=("yes", "no", "default"), default="default", help="planar or 3D body"
    )
    p.add_argument("--model", metavar="RUN_DIR|MODEL.zip", help="a trained policy to watch")
    p.add_argument("--policy", choices=("random", "zero"), default="random", help="without --model")
    p.add_argument("--task", default="", help='e.g. "stump_height=1.5" (default: a random task)')
    p.add_argument("--stochastic", action="store_true", help="sample the model's actions")
    p.add_argument(
        "--seed", type=int, default=0, help="seed of the first reset and the random tasks (0)"
    )
    p.add_argument("--steps", type=int, help="stop after this many steps (default: never)")


def _random_task(space, rng, check) -> np.ndarray:
    """A uniform task the env can build (a few tries: some corners of a space are not)."""
    for _ in range(100):
        vector = rng.uniform(space.low, space.high).astype(np.float32)
        try:
            check(vector)
            return vector
        except ValueError:
            continue
    raise ValueError("no buildable task found in 100 uniform draws of the task space")


def run(args: argparse.Namespace) -> int:
    from acl3d import validation as check
    from acl3d.cli.option_values import seed_option
    from acl3d.cli.render import make_policy, make_source_env, resolve_source
    from acl3d.viewer import HumanViewer, check_display

    if args.steps is not None:
        check.integer("--steps", args.steps, 1)
    seed_option(args.seed)
    try:
        check_display()
    except RuntimeError as exc:  # a headless machine is a usage problem: one line, exit 2
        raise ValueError(str(exc)) from None
    source = resolve_source(args.model, args)
    env = make_source_env(source, args)
    try:
        core = env.unwrapped
        rng = np.random.default_rng(args.seed)
        task = (
            core.task_space.to_vector(core.task_space.parse(args.task))
            if args.task
            else _random_task(core.task_space, rng, core.set_task)
        )
        policy, _ = make_policy(source.model, env, args)
        obs, _ = env.reset(seed=args.seed, options={"task": task})
        viewer = HumanViewer(core.model, core.data, core.arena.camera, env.metadata["render_fps"])
        print("Enter: a new random task; close the window to quit", flush=True)
        steps = 0
        try:
            while viewer.is_running() and (args.steps is None or steps < args.steps):
                obs, _, terminated, truncated, _ = env.step(policy(obs))
                steps += 1
                new_task = viewer.new_task_requested
                if new_task:
                    viewer.new_task_requested = False
                    task = _random_task(core.task_space, rng, core.set_task)
                    print(f"new task: {core.task_space.to_dict(task)}", flush=True)
                if terminated or truncated or new_task:
                    obs, _ = env.reset(options={"task": task})
                viewer.sync(core.arena.hfield_ids, core.arena.version)
        finally:
            viewer.close()
    finally:
        env.close()
    print(f"viewed {steps} steps")
    return 0
