"""How far two runs of the same settings agree: their episode logs row by row, and their
evaluations, e.g. a run against its repeat or against itself killed and resumed.

    python scripts/compare_runs.py RUN_A RUN_B

On the CPU a repeat and a resumed run agree bit for bit; on a GPU the physics' floating-point
atomics may part them, and this says where: the first episode that differs and how the
evaluations compare.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path


def _rows(path: Path, drop: tuple[str, ...] = ()) -> list[list[str]]:
    with path.open() as f:
        table = list(csv.reader(f))
    keep = [i for i, name in enumerate(table[0]) if name not in drop]
    return [[row[i] for i in keep] for row in table[1:]]


def compare(a: Path, b: Path) -> str:
    episodes_a, episodes_b = _rows(a / "episodes.csv"), _rows(b / "episodes.csv")
    same = next(
        (i for i, (x, y) in enumerate(zip(episodes_a, episodes_b)) if x != y),
        min(len(episodes_a), len(episodes_b)),
    )
    lines = [f"{a.name} vs {b.name}: episodes {len(episodes_a)} vs {len(episodes_b)}, "
             f"the first {same} identical"]  # fmt: skip
    if same < min(len(episodes_a), len(episodes_b)):
        lines.append(f"  first difference (step, worker, return, ...): {episodes_a[same][:4]} vs "
                     f"{episodes_b[same][:4]}")  # fmt: skip
    evals_a = _rows(a / "evals.csv", drop=("wall_time_s",))
    evals_b = _rows(b / "evals.csv", drop=("wall_time_s",))
    for x, y in zip(evals_a, evals_b):
        mark = "identical" if x == y else "differ"
        lines.append(f"  eval at step {x[0]}: mastered {x[2]} vs {y[2]}, mean return {x[3]} vs "
                     f"{y[3]} ({mark})")  # fmt: skip
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_a", type=Path)
    parser.add_argument("run_b", type=Path)
    args = parser.parse_args()
    print(compare(args.run_a, args.run_b))


if __name__ == "__main__":
    main()
