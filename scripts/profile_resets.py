"""Where the many-world env's step goes, its batched resets stage by stage (synchronised timers).

    python scripts/profile_resets.py --device cuda --worlds 16384 --env-kwarg grid_spacing=[0.1,0.5]
    python scripts/profile_resets.py --device cpu --worlds 64 --steps 10   # Warp's CPU device

On a GPU the resets run after the step's one host sync, while the GPU waits: their small torch
operations cost host time, not device time. This times each stage of `ManyWorlds._reset_worlds`
(and the step's own parts) with a device synchronisation around it, so the stages' sum exceeds an
untimed step; then it counts the torch operations and kernel launches of one reset of `--resets`
worlds (torch's profiler). The env runs the bench task of `bench_gpu.py`, random actions.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from bench_gpu import _sync, add_env_arguments, make_env, random_steps, time_calls
from torch.profiler import ProfilerActivity, profile

from acl3d.cli.option_values import key_values


def stages(env) -> list[tuple[object, str, str]]:
    """(object, method, label) of every stage timed; indented labels are parts of the one above."""
    return [
        (env.rules, "before_physics", "rules before physics"),
        (env.rules, "servo", "servo caps"),
        (env.sim, "step", "physics"),
        (env.rules, "outcome", "rules after physics"),
        (env.stats, "step", "episode statistics"),
        (env, "_reset_worlds", "resets"),
        (env, "_next_tasks", "  next tasks"),
        (env.family, "terrain", "  terrain"),
        (env.family, "push", "  push"),
        (env.sim, "reset_worlds", "  state written"),
        (env, "_first_observations", "  first observations"),
        (env.starts, "forward", "    start worlds' forward"),
        (env, "_observe_starts", "    their observation"),
        (env.stats, "begin", "  statistics begun"),
    ]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_env_arguments(p, "terrain3d", "big_quadru")
    p.add_argument("--device", default="cuda")
    p.add_argument("--worlds", type=int, default=16384)
    p.add_argument("--steps", type=int, default=30, help="timed steps (after as many untimed)")
    p.add_argument("--resets", type=int, default=147, help="worlds in the profiled reset")
    a = p.parse_args()
    body = a.body or ("big_quadru" if a.env == "terrain3d" else None)
    env = make_env(
        a.worlds, a.device, a.env, body, env_kwargs=key_values(a.env_kwarg, "--env-kwarg")
    )
    g = torch.Generator(device=env.device).manual_seed(2)
    random_steps(env, a.steps, g)
    plain = random_steps(env, a.steps, g)
    print(f"{a.env}, {a.worlds} worlds on {a.device}: a step {plain * 1e3:.2f} ms untimed "
          f"({a.worlds / plain:,.0f} env steps/s)")  # fmt: skip
    spent: dict = {}
    restores = [time_calls(obj, n, env.device, spent, (n, id(obj))) for obj, n, _ in stages(env)]
    total = random_steps(env, a.steps, g)
    print(f"a step with every stage timed: {total * 1e3:.2f} ms; per step:")
    for obj, name, label in stages(env):
        print(f"  {label:28s} {spent.get((name, id(obj)), 0.0) / a.steps * 1e3:7.3f} ms")
    for restore in reversed(restores):
        restore()
    ids = np.sort(np.random.default_rng(0).choice(a.worlds, min(a.resets, a.worlds), replace=False))
    activities = [ProfilerActivity.CPU] + (
        [ProfilerActivity.CUDA] if env.device.type == "cuda" else []
    )
    env._reset_worlds(ids, env.tasks[ids], env.obs)
    with profile(activities=activities) as prof:
        env._reset_worlds(ids, env.tasks[ids], env.obs)
        _sync(env.device)
    events = prof.key_averages()
    ops = sum(e.count for e in events if e.key.startswith("aten::"))
    launches = sum(e.count for e in events if e.key in ("cudaLaunchKernel", "cudaGraphLaunch"))
    print(f"one reset of {len(ids)} worlds: {ops} torch operations, {launches} launches")


if __name__ == "__main__":
    main()
