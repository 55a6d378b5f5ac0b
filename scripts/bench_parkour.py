"""Parkour speed: env.step for the biped, the climber and the fish; reset with a new task; water.

Also renders one docs image per body (--out DIR). Every number is measured in this run on
this machine; the original 2D Box2D Parkour runs ~6,200 steps/s with the biped and resets with a
new task in ~6.5 ms on this machine class (reference: mujoco-notes.md). Run on an idle machine:

    python scripts/bench_parkour.py --steps 3000 --out /tmp/parkour_images
    python scripts/bench_parkour.py --batched 16 --rounds 3   # the batched env vs one env

`--batched N` times, instead, N envs in one batched vector env (`gymnasium.make_vec(...,
vectorization_mode="vector_entry_point")`, physics on one thread per core, autoresets included)
against one `gymnasium.make` env (resets included) on the same task, for the biped in water and
the climber grasping creepers: steps/s (wall clock, best of interleaved rounds) and the ratio,
and the same ratio in process CPU time per env step (robust to other load on the machine).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import acl3d  # noqa: F401  (before mujoco: picks the headless GL backend)

ORIGINAL_STEPS, ORIGINAL_RESET_MS = 6200, 6.5
CASES = {  # body -> (task, kwargs): each body on the terrain it is meant for
    "classic_bipedal": ({"water_level": 0.0}, {}),
    "climbing_profile_chimpanzee": ({"creepers_height": 2.0, "creepers_spacing": 2.0}, {}),
    "fish": ({"water_level": 0.95}, {}),
}


def step_rate(env, steps: int, seed: int = 0) -> float:
    """env.step per second with uniform random actions (resets excluded)."""
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1, 1, (steps, env.action_space.shape[0]))
    env.reset(seed=seed)
    elapsed = 0.0
    for i in range(steps):
        t0 = time.perf_counter()
        _, _, terminated, _, _ = env.step(actions[i])
        elapsed += time.perf_counter() - t0
        if terminated:
            env.reset()
    return steps / elapsed


BATCHED_CASES = [  # the biped wading in deep water; the climber grasping creepers, dry and wet
    ("classic_bipedal", {"input_vector": [0.2, -0.3, 0.1], "water_level": 0.9}),
    ("climbing_profile_chimpanzee", {"creepers_height": 2.0, "creepers_spacing": 2.0}),
    ("climbing_profile_chimpanzee", {"water_level": 0.9, "creepers_height": 2.0}),
]


def timed(step, actions) -> tuple[float, float]:
    """(wall, process CPU) seconds of `step(a)` over the actions."""
    wall, cpu = time.perf_counter(), time.process_time()
    for a in actions:
        step(a)
    return time.perf_counter() - wall, time.process_time() - cpu


def single_times(body: str, task: dict, steps: int) -> tuple[float, float]:
    """Wall and CPU seconds per env step of one env, its resets included."""
    env = gym.make("acl3d/Parkour-v0", body=body)
    env.reset(seed=0, options={"task": task})
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, env.action_space.shape[0]))

    def step(a):
        _, _, terminated, truncated, _ = env.step(a)
        if terminated or truncated:
            env.reset()

    wall, cpu = timed(step, actions)
    env.close()
    return wall / steps, cpu / steps


def batched_times(body: str, task: dict, n: int, steps: int) -> tuple[float, float]:
    """Wall and CPU seconds per env step of N envs in the batched vector env."""
    vec = gym.make_vec(
        "acl3d/Parkour-v0", num_envs=n, vectorization_mode="vector_entry_point", body=body
    )
    vec.reset(seed=0, options={"task": task})
    shape = (max(1, steps // n), n, vec.single_action_space.shape[0])
    actions = np.random.default_rng(0).uniform(-1, 1, shape)
    wall, cpu = timed(vec.step, actions)
    vec.close()
    return wall / (shape[0] * n), cpu / (shape[0] * n)


def compare_batched(n: int, steps: int, rounds: int) -> None:
    print(f"Parkour, {n} batched envs vs one env ({steps} env steps per cell, best of {rounds})")
    print("| body, task | one env, steps/s | batched, steps/s | batched / one | in CPU time |")
    print("|---|---|---|---|---|")
    for body, task in BATCHED_CASES:
        best = {"single": (np.inf, np.inf), "batched": (np.inf, np.inf)}
        for _ in range(rounds):  # interleaved: load changes hit both alike
            best["single"] = min(best["single"], single_times(body, task, steps))
            best["batched"] = min(best["batched"], batched_times(body, task, n, steps))
        (sw, sc), (bw, bc) = best["single"], best["batched"]
        print(
            f"| {body} {task} | {1 / sw:,.0f} | {1 / bw:,.0f} | {sw / bw:.2f}x | {sc / bc:.2f}x |"
        )


def reset_ms(env, n: int, seed: int = 0) -> float:
    """Mean reset time with a new uniform task from the task space each time."""
    space = env.unwrapped.task_space
    tasks = np.random.default_rng(seed).uniform(space.low, space.high, (n, space.dim))
    t0 = time.perf_counter()
    for i, task in enumerate(tasks):
        env.reset(seed=i, options={"task": task})
    return (time.perf_counter() - t0) / n * 1e3


def water_us(env, wet: bool, n: int = 2000) -> float:
    """Cost of the water forces per control step, with the body under water or dry."""
    env.reset(seed=0, options={"task": {"water_level": 1.0 if wet else 0.0}})
    for _ in range(20):
        env.step(env.action_space.sample())
    water, data = env.unwrapped.water, env.unwrapped.data
    t0 = time.perf_counter()
    for _ in range(n):
        water.apply(data)
    return (time.perf_counter() - t0) / n * 1e6


def render(body: str, task: dict, kwargs: dict, out: Path, steps: int = 40) -> Path:
    import imageio.v3 as iio
    import mujoco

    env = gym.make("acl3d/Parkour-v0", body=body, render_mode="rgb_array", **kwargs)
    env.reset(seed=1, options={"task": task})
    u = env.unwrapped
    if not u.climbing:  # show some terrain: start further down the track
        x = 14.0
        u.bound.place(u.data, x, u.terrain.ground_at(x) + u.body.spawn_height)
        mujoco.mj_forward(u.model, u.data)
    rng = np.random.default_rng(1)
    for _ in range(steps):
        action = rng.uniform(-0.3, 0.3, env.action_space.shape)
        if env.unwrapped.climbing:
            action[-len(env.unwrapped.body.grasp_sensors) :] = 1.0
        env.step(action)
    path = out / f"parkour_{body}.png"
    iio.imwrite(path, env.render())
    env.close()
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=3000, help="env steps timed per body")
    parser.add_argument("--resets", type=int, default=50, help="resets with a new task timed")
    parser.add_argument(
        "--out", type=Path, default=None, help="write the docs images (docs/figures) here"
    )
    parser.add_argument(
        "--batched", type=int, default=0, metavar="N", help="time N batched envs vs one env"
    )
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds (--batched)")
    args = parser.parse_args()
    if args.batched:
        compare_batched(args.batched, args.steps, args.rounds)
        return

    print(f"original 2D Parkour (biped): ~{ORIGINAL_STEPS} steps/s, reset ~{ORIGINAL_RESET_MS} ms")
    for body, (task, kwargs) in CASES.items():
        env = gym.make("acl3d/Parkour-v0", body=body, **kwargs)
        env.unwrapped.set_task(task)
        rate = step_rate(env, args.steps)
        reset = reset_ms(env, args.resets)
        print(
            f"{body:30s} obs {env.observation_space.shape[0]:3d}  {rate:7.0f} steps/s "
            f"({rate / ORIGINAL_STEPS:.2f}x the original biped)  reset+new task {reset:5.2f} ms"
        )
    biped = gym.make("acl3d/Parkour-v0", body="classic_bipedal")
    fish = gym.make("acl3d/Parkour-v0", body="fish")
    print(
        f"water forces per step: biped dry {water_us(biped, False):.1f} us, "
        f"biped under water {water_us(biped, True):.1f} us, fish under water {water_us(fish, True):.1f} us"
    )
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        for body, (task, kwargs) in CASES.items():
            render_task = dict(task)
            if body == "classic_bipedal":
                render_task.update(input_vector=[-0.3, 0.7, 0.1], water_level=0.7)
            print("wrote", render(body, render_task, kwargs, args.out))


if __name__ == "__main__":
    main()
