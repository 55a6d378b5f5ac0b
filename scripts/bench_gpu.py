"""The many-world simulation's speed: env steps/s through `ManyWorlds` against raw physics.

    python scripts/bench_gpu.py --device cuda --sizes 1024 4096 16384
    python scripts/bench_gpu.py --device cpu --sizes 4 --steps 20      # Warp's CPU device
    python scripts/bench_gpu.py --first-step                           # a new process's start

    python scripts/bench_gpu.py --env terrain3d --body big_quadru      # another family
    python scripts/bench_gpu.py --env terrain3d --env-kwarg grid_spacing=[0.2,0.2]
    python scripts/bench_gpu.py --env terrain3d --body big_quadru --constraint-rows 0 384 256
    python scripts/bench_gpu.py --env terrain3d --body big_quadru --contact-slots 0 24 16

Per world count, in one run on one device (random actions in [-1, 1], the env's default body):
* raw physics: `WarpSimulation.step` alone (random controls, no rules, no resets, the worlds'
  own terrain and caps) — what MuJoCo Warp gives;
* env: `ManyWorlds.step` (servo caps, physics, rules, episode statistics, batched resets with
  their terrain), on a task with obstacles everywhere (Stump Tracks h=1, spacing 3; 3D Terrain
  with roughness and blocks), and its ratio to raw physics;
* resets' host share: the fraction of the env's time spent in the batched resets (terrain
  generation and upload included), timed with device synchronisation in a separate pass.
Each cell runs `--warmup` steps first (graph capture, kernel loading). `--first-step` times a
new process from import to its first env step (the kernel cache's effect). `--constraint-rows`
repeats every size with each number of constraint rows reserved per world (0: MuJoCo Warp's
estimate), in rounds, and counts the worlds that needed more ("overflows"); `--contact-slots`
does the same with the contact slots reserved per world (the shared pool's size over N), and
says whether a step had more candidate pairs or contacts than the pool holds ("pool full").
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections.abc import Callable

import torch

from acl3d.cli.option_values import key_values
from acl3d.envs.many_worlds import ManyWorlds, many_worlds

# a task with obstacles everywhere, per env
TASKS = {
    "stump-tracks": {"stump_height": 1.0, "obstacle_spacing": 3.0},
    # slopes are in degrees: these hills and twist are nearly level (kept so that the figures of
    # every session compare); the roughness and full-width blocks are the obstacles
    "terrain3d": {"hill_slope": 0.2, "cross_slope": 0.15, "roughness": 0.1, "block_height": 0.3},
    # water half way up and creepers: the walker swims, a climber has something to grasp
    "parkour": {"water_level": 0.5, "creepers_height": 2.0, "creepers_spacing": 1.0},
}


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def make_env(
    n: int, device: str, name: str, body: str | None, rows: int | None = None,
    slots: int | None = None, env_kwargs: dict | None = None,
) -> ManyWorlds:  # fmt: skip
    kwargs = dict(env_kwargs or {}, **({} if body is None else {"body": body}))
    env = many_worlds(name, n, device, constraint_rows=rows, contact_slots=slots, **kwargs)
    if name in TASKS:
        env.tasks[:] = env.task_space.to_vector(TASKS[name])
    env.reset(seed=0)
    return env


def add_env_arguments(p: argparse.ArgumentParser, env: str, body: str = "the env's") -> None:
    """--env (default `env`), --body (default described by `body`) and --env-kwarg K=V."""
    p.add_argument("--env", default=env, help="stump-tracks, hexagon-tracks, parkour, terrain3d")
    p.add_argument("--body", help=f"default: {body}")
    p.add_argument(
        "--env-kwarg", action="append", metavar="K=V", default=[],
        help="an env keyword argument, its value in YAML (repeatable), e.g. grid_spacing=[0.2,0.2]",
    )  # fmt: skip


def raw_rate(sim, steps: int, warmup: int) -> float:
    """Env steps/s of `sim` (a `WarpSimulation`) alone: random controls, no rules or resets."""
    g = torch.Generator(device=sim.device).manual_seed(1)
    ctrl = sim.field("ctrl")
    for k in range(warmup + steps):
        if k == warmup:
            _sync(sim.device)
            t0 = time.perf_counter()
        ctrl.copy_(torch.rand(ctrl.shape, generator=g, device=sim.device) * 2 - 1)
        sim.step()
    _sync(sim.device)
    return sim.nworld * steps / (time.perf_counter() - t0)


def env_rate(env: ManyWorlds, steps: int, warmup: int) -> tuple[float, float]:
    """(env steps/s, episodes finished per env step)."""
    g = torch.Generator(device=env.device).manual_seed(2)
    shape, finished = (env.num_envs, env.action_size), 0
    for k in range(warmup + steps):
        if k == warmup:
            _sync(env.device)
            t0 = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(
            torch.rand(shape, generator=g, device=env.device) * 2 - 1
        )
        if k >= warmup:
            finished += int((terminated | truncated).sum())
    _sync(env.device)
    return env.num_envs * steps / (time.perf_counter() - t0), finished / steps


def time_calls(obj, name: str, device, spent: dict, key) -> Callable[[], None]:
    """Add the time of every call of obj.name (device synchronised around it) to spent[key];
    returns the function that puts the original back."""
    original, shadowed = getattr(obj, name), name in vars(obj)

    def timed(*args, **kwargs):
        _sync(device)
        t0 = time.perf_counter()
        out = original(*args, **kwargs)
        _sync(device)
        spent[key] = spent.get(key, 0.0) + time.perf_counter() - t0
        return out

    setattr(obj, name, timed)
    return (lambda: setattr(obj, name, original)) if shadowed else (lambda: delattr(obj, name))


def reset_share(env: ManyWorlds, steps: int) -> float:
    """Share of the env's step time spent in batched resets (synchronised timing)."""
    spent: dict = {}
    restore = time_calls(env, "_reset_worlds", env.device, spent, "resets")
    total = random_steps(env, steps, torch.Generator(device=env.device).manual_seed(3)) * steps
    restore()
    return spent.get("resets", 0.0) / total


def random_steps(env: ManyWorlds, steps: int, g: torch.Generator) -> float:
    """Seconds a step over `steps` env steps on random actions drawn from `g` (synchronised)."""
    _sync(env.device)
    t0 = time.perf_counter()
    for _ in range(steps):
        env.step(
            torch.rand((env.num_envs, env.action_size), generator=g, device=env.device) * 2 - 1
        )
    _sync(env.device)
    return (time.perf_counter() - t0) / steps


def first_step_seconds(device: str, n: int, name: str) -> float:
    code = (
        "import time; t0 = time.perf_counter(); import torch;"
        "from acl3d.envs.many_worlds import many_worlds;"
        f"env = many_worlds({name!r}, {n}, {device!r}); env.reset(seed=0);"
        "env.step(torch.zeros((env.num_envs, env.action_size), device=env.device));"
        f"torch.cuda.synchronize() if {device!r}.startswith('cuda') else None;"
        "print(time.perf_counter() - t0)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cuda")
    p.add_argument("--sizes", type=int, nargs="+", default=[1024, 4096, 16384])
    p.add_argument("--steps", type=int, default=200)
    p.add_argument("--warmup", type=int, default=20)
    add_env_arguments(p, "stump-tracks")
    p.add_argument(
        "--constraint-rows", type=int, nargs="+", default=[0], metavar="ROWS",
        help="constraint rows reserved per world, each measured in turn (0: MuJoCo Warp's estimate)",
    )  # fmt: skip
    p.add_argument(
        "--contact-slots", type=int, nargs="+", default=[0], metavar="SLOTS",
        help="contact slots reserved per world, each measured in turn (0: MuJoCo Warp's estimate)",
    )  # fmt: skip
    p.add_argument("--rounds", type=int, default=1, help="repeat the cells in interleaved rounds")
    p.add_argument("--first-step", action="store_true", help="also time a new process's start")
    p.add_argument("--json", help="write the rows to this file too")
    a = p.parse_args()
    env_kwargs = key_values(a.env_kwarg, "--env-kwarg")
    rows = []
    options = "".join(f", {k}={v}" for k, v in env_kwargs.items())
    print(f"{a.env}, {a.body or 'its default body'}{options}, device {a.device}, {a.steps} "
          "timed steps")  # fmt: skip
    print(f"{'worlds':>8} {'rows':>5} {'slots':>5} {'raw physics/s':>14} {'env steps/s':>12} "
          f"{'ratio':>6} {'resets/step':>11} {'reset share':>11} {'overflows':>9} "
          f"{'pool full':>9}")  # fmt: skip
    cells = [
        (n, rows_, slots) for n in a.sizes for rows_ in a.constraint_rows
        for slots in a.contact_slots
    ]  # fmt: skip
    for _ in range(a.rounds):
        for n, reserved, slots in cells:
            t0 = time.perf_counter()
            env = make_env(n, a.device, a.env, a.body, reserved or None, slots or None, env_kwargs)
            build = time.perf_counter() - t0
            raw = raw_rate(env.sim, a.steps, a.warmup)
            env.reset(seed=0)
            rate, resets = env_rate(env, a.steps, a.warmup)
            share = reset_share(env, max(a.steps // 4, 10))
            overflows = int(env.sim.constraint_overflows().sum())
            full = env.sim.contact_overflows()
            row = dict(worlds=n, constraint_rows=env.sim.constraint_rows,
                       contact_slots=env.sim.contact_slots, pool_full=full, raw=raw, env=rate,
                       ratio=rate / raw, resets_per_step=resets, reset_share=share,
                       overflows=overflows, build_s=build, device=a.device, env_name=a.env,
                       env_kwargs=env_kwargs)  # fmt: skip
            rows.append(row)
            print(f"{n:>8} {row['constraint_rows']:>5} {row['contact_slots']:>5} {raw:>14,.0f} "
                  f"{rate:>12,.0f} {rate / raw:>6.2f} {resets:>11.1f} {share:>11.1%} "
                  f"{overflows:>9} {'yes' if full else 'no':>9}"
                  f"   (build + first reset {build:.1f} s)", flush=True)  # fmt: skip
            env.close()
            del env
    if a.first_step:
        seconds = first_step_seconds(a.device, a.sizes[0], a.env)
        rows.append({"first_step_s": seconds, "worlds": a.sizes[0], "device": a.device})
        print(f"a new process's first env step ({a.sizes[0]} worlds): {seconds:.1f} s")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
