"""Soak test (not CI): long runs that would show leaks as resident-memory growth.

Three phases, RSS printed at intervals and the growth of each phase at its end:
1. env steps with random actions and a new random task (uniform in the task space) at every
   reset, with a get_state()/set_state() round trip every `--state-every` resets;
2. env create/reset/step/close cycles, alternating Stump Tracks, Hexagon Tracks and Parkour;
3. offscreen renders (needs a GL backend: EGL or OSMesa, see docs/rendering.md).

    python scripts/soak.py                                 # 1M steps, 2,000 cycles, 500 renders
    python scripts/soak.py --steps 300000 --cycles 500 --renders 100   # shorter
"""

from __future__ import annotations

import argparse
import time

import acl3d  # noqa: F401  (first: picks the headless GL backend before mujoco loads)

# isort: split
import gymnasium as gym
import numpy as np

ENV_IDS = ("acl3d/StumpTracks-v0", "acl3d/HexagonTracks-v0", "acl3d/Parkour-v0")


def rss_mb() -> float:
    """Current resident set size of this process (Linux /proc), in MB."""
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS in /proc/self/status")


class Report:
    """Prints RSS at intervals and the growth of a phase from its first reading."""

    def __init__(self, phase: str, total: int, every: int):
        self.phase, self.total, self.every = phase, total, max(1, every)
        self.start = time.perf_counter()
        self.first: float | None = None
        self.readings: list[float] = []

    def tick(self, done: int) -> None:
        if done % self.every and done != self.total:
            return
        rss = rss_mb()
        if self.first is None:
            self.first = rss
        self.readings.append(rss)
        elapsed = time.perf_counter() - self.start
        print(
            f"[{self.phase}] {done:>9,}/{self.total:,}  RSS {rss:7.1f} MB  {elapsed:7.1f} s",
            flush=True,
        )

    def summary(self) -> str:
        if not self.readings:
            return f"{self.phase}: nothing run"
        # growth after warm-up: from the reading at 10% of the phase to the last one
        warm = self.readings[min(len(self.readings) - 1, max(1, len(self.readings) // 10))]
        last = self.readings[-1]
        return (
            f"{self.phase}: RSS {self.first:.1f} -> {last:.1f} MB "
            f"(+{last - self.first:.1f} MB; +{last - warm:.1f} MB after the first 10%)"
        )


def random_task(space, rng: np.random.Generator) -> np.ndarray:
    return rng.uniform(space.low, space.high)


def soak_steps(env_id: str, steps: int, every: int, state_every: int, seed: int) -> str:
    env = gym.make(env_id)
    space = env.unwrapped.task_space
    rng = np.random.default_rng(seed)
    report = Report(f"steps {env_id}", steps, every)
    env.reset(seed=seed, options={"task": random_task(space, rng)})
    episodes = 0
    for done in range(1, steps + 1):
        _, _, terminated, truncated, _ = env.step(rng.uniform(-1, 1, env.action_space.shape))
        if terminated or truncated:
            episodes += 1
            env.reset(options={"task": random_task(space, rng)})
            if state_every and episodes % state_every == 0:
                env.unwrapped.set_state(env.unwrapped.get_state())
        report.tick(done)
    env.close()
    return f"{report.summary()}, {episodes:,} episodes"


def soak_cycles(cycles: int, every: int, seed: int) -> str:
    report = Report("create/close", cycles, every)
    for done in range(1, cycles + 1):
        env = gym.make(ENV_IDS[done % len(ENV_IDS)])
        env.reset(seed=seed + done)
        for _ in range(5):
            env.step(env.action_space.sample())
        env.close()
        report.tick(done)
    return report.summary()


def soak_renders(renders: int, every: int, seed: int) -> str:
    env = gym.make("acl3d/StumpTracks-v0", render_mode="rgb_array", width=320, height=240)
    space = env.unwrapped.task_space
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    report = Report("renders", renders, every)
    for done in range(1, renders + 1):
        if done % 50 == 0:  # a new terrain: the heightfield is re-uploaded
            env.reset(options={"task": random_task(space, rng)})
        env.step(rng.uniform(-1, 1, env.action_space.shape))
        frame = env.render()
        assert frame.shape == (240, 320, 3)
        report.tick(done)
    env.close()
    return report.summary()


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="acl3d/StumpTracks-v0", help="env id of the step phase")
    parser.add_argument("--steps", type=int, default=1_000_000)
    parser.add_argument("--cycles", type=int, default=2_000)
    parser.add_argument("--renders", type=int, default=500)
    parser.add_argument(
        "--state-every", type=int, default=10, help="resets between state round trips (0: never)"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--reports", type=int, default=20, help="RSS readings per phase")
    args = parser.parse_args(argv)
    summaries = []
    if args.steps:
        summaries.append(
            soak_steps(
                args.env, args.steps, args.steps // args.reports, args.state_every, args.seed
            )
        )
    if args.cycles:
        summaries.append(soak_cycles(args.cycles, args.cycles // args.reports, args.seed))
    if args.renders:
        summaries.append(soak_renders(args.renders, args.renders // args.reports, args.seed))
    print("\n".join(["", "Summary:", *summaries]))


if __name__ == "__main__":
    main()
