"""Learning curves of training runs from their episodes.csv (a run directory's, or the
CleanRL-style example's, which writes the same layout), side by side.

    python scripts/compare_episodes.py runs/ppo_flat16 runs/cleanrl_flat --window 50

For each run: the first step at which the last `window` training episodes succeeded in at least
25%, 50% and 75% of cases, and the success rate and mean return of the last `window` episodes.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

LEVELS = (0.25, 0.5, 0.75)


def curve(run: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(step, success, return) per training episode, in the order they finished."""
    with open(run / "episodes.csv") as f:
        rows = list(csv.DictReader(f))
    step = np.array([int(float(r["step"])) for r in rows])
    success = np.array([float(r["success"]) for r in rows])
    ret = np.array([float(r["return"]) for r in rows])
    return step, success, ret


def first_step(step: np.ndarray, success: np.ndarray, window: int, level: float):
    rate = np.convolve(success, np.ones(window) / window, mode="valid")
    hit = np.flatnonzero(rate >= level)
    return int(step[hit[0] + window - 1]) if len(hit) else None


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("runs", nargs="+", type=Path)
    p.add_argument("--window", type=int, default=50, help="episodes in the rolling success rate")
    args = p.parse_args(argv)
    levels = " | ".join(f"first step at {int(100 * v)}%" for v in LEVELS)
    print(f"| run | episodes | steps | {levels} | last {args.window}: success, mean return |")
    print("|---" * (5 + len(LEVELS)) + "|")
    for run in args.runs:
        step, success, ret = curve(run)
        firsts = " | ".join(str(first_step(step, success, args.window, v)) for v in LEVELS)
        last = slice(-args.window, None)
        print(
            f"| {run.name} | {len(step)} | {step[-1]} | {firsts} | "
            f"{100 * success[last].mean():.0f}%, {ret[last].mean():.0f} |"
        )


if __name__ == "__main__":
    main()
