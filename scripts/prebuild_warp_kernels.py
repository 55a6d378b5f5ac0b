"""Build MuJoCo Warp's CUDA kernels for acl3d's models ahead of time, on a machine without a GPU,
into Warp's kernel cache: a GPU machine that gets the cache skips the first start's compile
(about 2 minutes for Stump Tracks on an H200's host, more for each other family).

    python scripts/prebuild_warp_kernels.py --arch 90                       # H100 / H200
    python scripts/prebuild_warp_kernels.py --arch 90 --env stump-tracks --env terrain3d:big_quadru \
        --env parkour:classic_bipedal --cache /tmp/warp-cache

Then copy the cache folder (`--cache`, default Warp's own, `~/.cache/warp/<version>`) to the GPU
machine's Warp cache (or point `WARP_CACHE_PATH` at it). Warp and MuJoCo Warp must be the same
versions on both machines.

How: each env's many-world simulation steps a few times on Warp's CPU device, which builds every
kernel module its step uses. Warp runs CPU kernels with one thread per block, so the block size a
CUDA launch will ask for (which names the module's variant in the cache) is read from the launch
calls themselves, recorded here; each (module, block size) is then compiled for each `--arch`
with NVRTC (`warp.compile_aot_module`), which needs no GPU or driver. Kernels MuJoCo Warp only
launches on a GPU (its all-pairs broadphase) are not built here and still compile on first use:
about 5 of the 115 seconds of a Stump Tracks start measured on an H200's host.
"""

from __future__ import annotations

import argparse
import os
import time
from contextlib import contextmanager
from pathlib import Path

import torch


def parse_env(text: str) -> tuple[str, dict]:
    """ "ENV" or "ENV:BODY" -> (env, its keyword arguments)."""
    env, _, body = text.partition(":")
    return env, ({"body": body} if body else {})


@contextmanager
def launches_through(wp, wrap):
    """Within the block, every kernel launch (`wp.launch`, `wp.launch_tiled`) goes through
    `wrap(launch)`, a function taking the launch's arguments; the originals are back afterwards."""
    originals = {name: getattr(wp, name) for name in ("launch", "launch_tiled")}
    for name, launch in originals.items():
        setattr(wp, name, wrap(launch))
    try:
        yield
    finally:
        for name, launch in originals.items():
            setattr(wp, name, launch)


class LaunchLog:
    """The (module, block size) pairs of every kernel launch, CUDA's block size as requested
    (`launches_through(wp, log.recording)`)."""

    def __init__(self):
        self.variants = {}

    def recording(self, launch):
        def recorded(kernel, *args, **kwargs):
            module = kernel.module
            block_dim = kwargs.get("block_dim") or module.options["block_dim"]
            self.variants.setdefault((module.name, block_dim), module)
            return launch(kernel, *args, **kwargs)

        return recorded


def exercise(env: str, kwargs: dict, steps: int) -> None:
    """A few steps (with resets) of `env`'s many-world simulation on Warp's CPU device."""
    from acl3d.envs.many_worlds import many_worlds

    worlds = many_worlds(env, 2, "cpu", **kwargs)
    try:
        worlds.reset(seed=0)
        generator = torch.Generator().manual_seed(0)
        for _ in range(steps):
            actions = 2.0 * torch.rand((2, worlds.action_size), generator=generator) - 1.0
            worlds.step(actions)
        worlds.reset(seed=1)
    finally:
        worlds.close()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--arch", type=int, action="append", required=True, help="e.g. 90 (sm_90)")
    p.add_argument("--env", action="append", help="ENV or ENV:BODY (default: stump-tracks)")
    p.add_argument("--steps", type=int, default=5)
    p.add_argument("--cache", type=Path, help="the kernel cache to fill (default: Warp's)")
    args = p.parse_args()
    for arch in args.arch:
        if not 50 <= arch <= 200:
            p.error(f"--arch: {arch} (allowed: a CUDA compute capability as an integer, e.g. 90)")
    if args.steps < 1:
        p.error(f"--steps: {args.steps} (allowed: >= 1)")
    if args.cache is not None:
        os.environ["WARP_CACHE_PATH"] = str(args.cache)  # read when Warp initialises
    from acl3d.sim.warp_backend import import_warp

    wp, _ = import_warp()
    wp.init()
    log = LaunchLog()
    try:
        with launches_through(wp, log.recording):
            for text in args.env or ["stump-tracks"]:
                env, kwargs = parse_env(text)
                exercise(env, kwargs, args.steps)
    except ValueError as exc:  # an env or body the many-world simulation does not run
        p.error(f"--env {text}: {exc}")

    start, built = time.perf_counter(), []
    for (_name, block_dim), module in sorted(log.variants.items(), key=lambda kv: kv[0]):
        default = module.options["block_dim"]
        module.options["block_dim"] = block_dim  # the variant the CUDA launch will load
        try:
            built += wp.compile_aot_module(module, arch=args.arch)
        finally:
            module.options["block_dim"] = default
    size = sum(path.stat().st_size for path in built if path.exists())
    print(
        f"{len(log.variants)} kernel module variants x {len(args.arch)} arch(s): {len(built)} "
        f"binaries, {size / 2**20:.1f} MiB, in {time.perf_counter() - start:.0f} s, under "
        f"{wp.config.kernel_cache_dir}"
    )


if __name__ == "__main__":
    main()
