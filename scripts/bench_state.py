"""Cost of exact env snapshots: per-step overhead of remembering each step's start state, and
the time of get_state() / set_state(). Ratios are measured in this run (interleaved repeats).

    python scripts/bench_state.py
    python scripts/bench_state.py --steps 2000 --repeats 9
"""

from __future__ import annotations

import argparse
import time

import acl3d  # noqa: F401

# isort: split
import gymnasium as gym
import mujoco
import numpy as np

from acl3d.envs.env_state import PhysicsState

CASES = (
    ("acl3d/StumpTracks-v0", {}, {"stump_height": 0.5}),
    ("acl3d/Parkour-v0", {"body": "fish"}, {"water_level": 0.8}),
)


def plain_step(self: PhysicsState) -> None:
    """What the envs did before snapshots: mj_step only."""
    mujoco.mj_step(self.model, self.data, nstep=self.nstep)
    self.stepped = True


def time_steps(env, actions, task) -> float:
    env.reset(seed=0, options={"task": task})
    start = time.perf_counter()
    for a in actions:
        if env.step(a)[2]:
            env.reset(seed=0)
    return time.perf_counter() - start


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args(argv)
    snapshot_step = PhysicsState.step
    for env_id, kwargs, task in CASES:
        env = gym.make(env_id, **kwargs).unwrapped
        rng = np.random.default_rng(0)
        actions = rng.uniform(-0.3, 0.3, (args.steps, env.action_space.shape[0]))
        times = {"with snapshots": [], "mj_step only": []}
        for _ in range(args.repeats):
            for name, step in (("with snapshots", snapshot_step), ("mj_step only", plain_step)):
                PhysicsState.step = step
                times[name].append(time_steps(env, actions, task))
        PhysicsState.step = snapshot_step
        best = {name: min(t) / args.steps * 1e6 for name, t in times.items()}
        env.reset(seed=0, options={"task": task})
        start = time.perf_counter()
        for _ in range(200):
            state = env.get_state()
        get_ms = (time.perf_counter() - start) / 200 * 1e3
        start = time.perf_counter()
        for _ in range(200):
            env.set_state(state)
        set_ms = (time.perf_counter() - start) / 200 * 1e3
        print(
            f"{env_id} {kwargs}: step {best['with snapshots']:.1f} us with snapshots, "
            f"{best['mj_step only']:.1f} us without (speed ratio "
            f"{best['mj_step only'] / best['with snapshots']:.3f}); "
            f"get_state {get_ms:.2f} ms, set_state {set_ms:.2f} ms"
        )


if __name__ == "__main__":
    main()
