"""Environment speed: env.step vs raw physics, reset with a new task, rendering; all bodies.

Every number is measured in this run on this machine, with Gymnasium's Walker2d-v5 as the
in-run reference, so the ratios are comparable across machines. Run on an idle machine:

    python scripts/bench_env.py                 # classic biped on Stump Tracks (+ Walker2d-v5)
    python scripts/bench_env.py --bodies all    # every body, planar and 3D where offered
    python scripts/bench_env.py --parkour       # + Parkour: biped, climber, fish, water cost
    python scripts/bench_env.py --batched       # + batched env (scripts/bench_batched.py)
"""

from __future__ import annotations

import argparse
import runpy
import sys
import time
from pathlib import Path

import acl3d  # noqa: F401  (first: picks the headless GL backend before mujoco loads)

# isort: split
import gymnasium as gym
import mujoco
import numpy as np

from acl3d.bodies import BODIES

ORIGINAL_BOX2D_STEPS = 8900  # 2D Box2D Stump Tracks, classic biped, h=1 sp=3, same machine class
TASK = {"stump_height": 1.0, "obstacle_spacing": 3.0}


class PhysicsClock:
    """Wraps mujoco.mj_step to time the physics inside env.step on exactly the same states."""

    def __init__(self):
        self.seconds = 0.0
        self._mj_step = mujoco.mj_step

    def __enter__(self):
        def timed(*args, **kwargs):
            t0 = time.perf_counter()
            self._mj_step(*args, **kwargs)
            self.seconds += time.perf_counter() - t0

        mujoco.mj_step = timed
        return self

    def __exit__(self, *exc):
        mujoco.mj_step = self._mj_step


def env_rates(env, steps: int, seed: int = 0) -> tuple[float, float]:
    """(env.step steps/s, raw physics steps/s) with uniform random actions; resets not timed."""
    rng = np.random.default_rng(seed)
    actions = rng.uniform(
        env.action_space.low, env.action_space.high, (steps, *env.action_space.shape)
    )
    env.reset(seed=seed)
    elapsed, physics_in_resets = 0.0, 0.0
    i = 0
    with PhysicsClock() as clock:
        while i < steps:
            t0 = time.perf_counter()
            while i < steps:
                _, _, terminated, truncated, _ = env.step(actions[i])
                i += 1
                if terminated or truncated:
                    break
            elapsed += time.perf_counter() - t0
            before = clock.seconds
            env.reset()
            physics_in_resets += clock.seconds - before
    return steps / elapsed, steps / (clock.seconds - physics_in_resets)


def track_body_rates(body: str, planar: bool | None, steps: int) -> dict:
    env = gym.make("acl3d/StumpTracks-v0", body=body, planar=planar)
    env.unwrapped.set_task(TASK)
    rate, raw = env_rates(env, steps)
    u = env.unwrapped
    return {
        "env": rate,
        "raw": raw,
        "obs": u.observation_space.shape[0],
        "act": u.action_space.shape[0],
        "planar": u.body.planar,
    }


def reset_ms(n: int = 300) -> float:
    env = gym.make("acl3d/StumpTracks-v0").unwrapped
    rng = np.random.default_rng(0)
    tasks = np.stack([rng.uniform(0, 3, n), rng.uniform(0, 6, n)], axis=1)
    env.reset(seed=0)
    t0 = time.perf_counter()
    for t in tasks:
        env.reset(options={"task": {"stump_height": t[0], "obstacle_spacing": t[1]}})
    return (time.perf_counter() - t0) / n * 1e3


def render_fps(frames: int = 200, quality: str = "fast") -> float:
    env = gym.make(
        "acl3d/StumpTracks-v0", render_mode="rgb_array", width=640, height=480, quality=quality
    )
    env.reset(seed=0, options={"task": TASK})
    env.render()  # renderer creation and first upload are not part of the frame rate
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    for _ in range(frames):
        _, _, terminated, _, _ = env.step(rng.uniform(-1, 1, 4))
        env.render()
        if terminated:
            env.reset()
    fps = frames / (time.perf_counter() - t0)
    env.close()
    return fps


def walker2d_rates(steps: int) -> tuple[float, float] | None:
    try:
        env = gym.make("Walker2d-v5")
    except Exception as exc:  # gymnasium[mujoco] missing
        print(f"(Walker2d-v5 unavailable: {exc})")
        return None
    return env_rates(env, steps)


def main() -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--steps", type=int, default=20000)
    p.add_argument("--bodies", default="classic_bipedal", help="comma-separated names, or 'all'")
    p.add_argument("--no-render", action="store_true")
    p.add_argument("--parkour", action="store_true", help="also run scripts/bench_parkour.py")
    p.add_argument("--batched", action="store_true", help="also run scripts/bench_batched.py")
    args = p.parse_args()
    bodies = list(BODIES) if args.bodies == "all" else args.bodies.split(",")

    rates = walker2d_rates(args.steps)
    ref = rates[0] if rates else None
    if rates:
        print(
            f"Gymnasium Walker2d-v5 (in-run reference): env.step {rates[0]:,.0f} steps/s, raw physics {rates[1]:,.0f} steps/s, env/raw time {rates[1] / rates[0]:.2f}x"
        )
    print(
        "\n| body | mode | obs | act | env steps/s | raw physics steps/s | env/raw time | vs Walker2d-v5 | vs Box2D original |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for body in bodies:
        modes = [True, False] if body in BODIES else [None]
        for planar in modes:
            try:
                r = track_body_rates(body, planar, args.steps)
            except Exception as exc:
                print(f"| {body} | {'planar' if planar else '3D'} | failed: {exc} |")
                continue
            vs_ref = f"{r['env'] / ref:.2f}" if ref else "-"
            print(
                f"| {body} | {'planar' if r['planar'] else '3D'} | {r['obs']} | {r['act']} | {r['env']:,.0f} | {r['raw']:,.0f} "
                f"| {r['raw'] / r['env']:.2f}x | {vs_ref} | {r['env'] / ORIGINAL_BOX2D_STEPS:.2f} |"
            )
    print(f"\nreset with a new task (classic biped, Stump Tracks): {reset_ms():.3f} ms")
    if not args.no_render:
        print(f"render 640x480, default (fast) settings: {render_fps():.0f} fps (step + render)")
        print(f"render 640x480, quality='high': {render_fps(60, 'high'):.0f} fps")
    for flag, script, title in (
        (args.parkour, "bench_parkour.py", "Parkour"),
        (args.batched, "bench_batched.py", "Batched env"),
    ):
        if flag:
            print(f"\n{title}:")
            sys.argv = [str(Path(__file__).with_name(script))]
            runpy.run_path(sys.argv[0], run_name="__main__")


if __name__ == "__main__":
    main()
