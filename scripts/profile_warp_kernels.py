"""Where a many-world physics step's time goes, kernel by kernel (MuJoCo Warp).

    python scripts/profile_warp_kernels.py --env terrain3d --body big_quadru
    python scripts/profile_warp_kernels.py --env-kwarg grid_spacing=[0.2,0.2]   # another grid
    python scripts/profile_warp_kernels.py --device cuda --env terrain3d --body big_quadru \
        --worlds 16384 --constraint-rows 192 --contact-slots 24

Builds the family's many-world env as `bench_gpu.py` does (every world on its task with
obstacles, its own terrain), then runs `--steps` raw physics steps (random controls, no rules)
eagerly rather than as a captured graph, so that each kernel launch can be timed: on a GPU by
Warp's CUDA activity timing (device time of each kernel), on Warp's CPU device by the wall time
of each launch (a CPU kernel runs on the calling thread before the launch returns). Prints the
kernels by their share of the total, the heightfield collision's share, and the time per step.
Only the shares are comparable between the two devices: why a family's raw physics is slower
on a GPU than another's is a question about the GPU's shares. On the CPU each launch's own cost
(Python packing ~80 arguments) is timed with its kernel: at 64 worlds an eager step takes 3.7x
a captured one, at 1,024 worlds 1.2x, so profile 1,024 worlds or more there. The warm-up steps
let random controls fold the bodies onto the ground (before, 3D Terrain's quadruped touches it
with its feet alone, or not at all, and steps are cheaper).
"""

from __future__ import annotations

import argparse
import contextlib
import time
from collections import defaultdict

import torch
from bench_gpu import add_env_arguments, make_env
from prebuild_warp_kernels import launches_through

from acl3d.cli.option_values import key_values
from acl3d.sim.warp_backend import import_warp

HFIELD_KERNEL = "ccd_hfield"  # MuJoCo Warp's heightfield-against-convex collision kernels


def timing_each_launch(times: dict[str, float]):
    """A `launches_through` wrapper adding each launch's wall time (seconds) to
    `times[kernel name]`."""

    def timed(launch):
        def run(kernel, *args, **kwargs):
            t0 = time.perf_counter()
            out = launch(kernel, *args, **kwargs)
            times[kernel.key] += time.perf_counter() - t0
            return out

        return run

    return timed


def kernel_times(sim, steps: int) -> dict[str, float]:
    """Seconds per kernel name over `steps` eager raw physics steps of `sim` (a
    `WarpSimulation`), random controls."""
    warp, mjw = import_warp()
    ctrl = sim.field("ctrl")
    g = torch.Generator(device=sim.device).manual_seed(1)
    times: dict[str, float] = defaultdict(float)
    cuda = sim.device.type == "cuda"
    with warp.ScopedDevice(sim._wp_device):
        if cuda:
            warp.timing_begin(cuda_filter=warp.TIMING_KERNEL)
        with (
            contextlib.nullcontext() if cuda else launches_through(warp, timing_each_launch(times))
        ):
            for _ in range(steps):
                ctrl.copy_(torch.rand(ctrl.shape, generator=g, device=sim.device) * 2 - 1)
                if cuda:  # Warp's stream reads the controls torch's stream wrote
                    torch.cuda.synchronize(sim.device)
                for _ in range(sim.nstep):
                    mjw.step(sim.m, sim.d)
        if cuda:
            for result in warp.timing_end():
                times[result.name] += result.elapsed / 1000.0
    return times


def short_name(name: str) -> str:
    """A kernel's key: Warp's CUDA timing names a launch "forward kernel KEY_HASH", HASH the
    first 8 hex digits of the kernel variant's hash; the CPU timing uses the key itself."""
    name = name.removeprefix("forward kernel ")
    stem, _, tail = name.rpartition("_")
    variant = len(tail) == 8 and all(c in "0123456789abcdef" for c in tail)
    return stem if stem and variant else name


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--device", default="cpu")
    add_env_arguments(p, "terrain3d")
    p.add_argument("--worlds", type=int, default=1024)
    p.add_argument("--steps", type=int, default=10)
    p.add_argument("--warmup", type=int, default=40)
    p.add_argument("--constraint-rows", type=int, default=0, help="0: MuJoCo Warp's estimate")
    p.add_argument("--contact-slots", type=int, default=0, help="0: MuJoCo Warp's estimate")
    p.add_argument("--top", type=int, default=15, help="kernels listed")
    p.add_argument(
        "--ccd-tolerance", type=float, help="MuJoCo's opt.ccd_tolerance for the timed steps"
    )
    a = p.parse_args()
    env_kwargs = key_values(a.env_kwarg, "--env-kwarg")
    env = make_env(
        a.worlds, a.device, a.env, a.body, a.constraint_rows or None, a.contact_slots or None,
        env_kwargs,
    )  # fmt: skip
    kernel_times(env.sim, a.warmup)  # loads every kernel module; the bodies fold to the ground
    if a.ccd_tolerance is not None:  # after the warm-up: the same states, timed at another value
        env.sim.m.opt.ccd_tolerance.fill_(a.ccd_tolerance)
    times = kernel_times(env.sim, a.steps)
    by_name: dict[str, float] = defaultdict(float)
    for name, seconds in times.items():
        by_name[short_name(name)] += seconds
    total = sum(by_name.values())
    hfield = sum(s for n, s in by_name.items() if HFIELD_KERNEL in n)
    options = "".join(f", {k}={v}" for k, v in env_kwargs.items())
    print(
        f"{a.env}, {a.body or 'its default body'}{options}, {a.worlds} worlds on {a.device}, "
        f"{env.sim.constraint_rows} constraint rows and {env.sim.contact_slots} contact slots "
        f"a world, ccd_tolerance {env.sim.m.opt.ccd_tolerance.numpy()[0]:g}, {a.steps} steps of "
        f"{env.sim.nstep} substeps after {a.warmup}"
    )
    print(f"kernel time per step {1000 * total / a.steps:.2f} ms ({len(by_name)} kernels)")
    print(f"heightfield collision ({HFIELD_KERNEL}*): {hfield / total:.1%}")
    print(f"{'share':>7} {'ms/step':>8}  kernel")
    for name, seconds in sorted(by_name.items(), key=lambda kv: -kv[1])[: a.top]:
        print(f"{seconds / total:>7.1%} {1000 * seconds / a.steps:>8.3f}  {name}")


if __name__ == "__main__":
    main()
