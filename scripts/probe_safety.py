"""Replays the run-safety failure list as a careful user would and prints `ok` or `defect` per item.

Each item runs real `acl3d` commands (tiny PPO runs on Stump Tracks; item 8 a two-node Ray
cluster on this machine, scripts/ray_cluster_check.py) in a scratch folder and
checks what a user relies on: a refused command exits 2 with one line naming the option and
writes nothing; a run directory is used by one process at a time; a damaged checkpoint is
skipped for the previous one; no raw traceback for any mistake on the list. Item 11 damages
copies of a run as a crash or a hand edit would (a torn evals.csv, a stale LATEST, 'running'
left by a dead process, an edited rng.json, a truncated model.zip) and checks that analyze,
resume, campaign status and evaluate say so, carry on, and lose none of the run's other files.

    python scripts/probe_safety.py          # every item (a few minutes on 2 cores)
    python scripts/probe_safety.py 3 7      # some items

Add an item with `@item(N, "title")` (`safety_probe.kit`) on a function `(probe) ->
list[Check]` in one of `safety_probe`'s modules: `runs` (a single run's checks), `campaigns`,
`run_faults` (item 11). Each item is one user's story, read top to bottom.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

# imported for their @item functions, which fill ITEMS
from safety_probe import campaigns, run_faults, runs  # noqa: F401
from safety_probe.kit import ITEMS, Check, Probe


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("items", nargs="*", type=int, help="item numbers (default: all)")
    parser.add_argument("--keep", action="store_true", help="keep the scratch folder")
    args = parser.parse_args()
    numbers = args.items or sorted(ITEMS)
    root = Path(tempfile.mkdtemp(prefix="acl3d_probe_"))
    defects = 0
    try:
        probe = Probe(root)
        for number in numbers:
            title, run = ITEMS[number]
            started = time.perf_counter()
            try:
                checks = run(probe)
            except Exception as exc:  # a probe that cannot run is a defect too
                checks = [Check("the probe ran", False, f"{type(exc).__name__}: {exc}")]
            bad = [c for c in checks if not c.ok]
            defects += bool(bad)
            took = time.perf_counter() - started
            print(f"item {number}: {'defect' if bad else 'ok'} ({title}; {took:.0f} s)")
            for c in checks:
                print(
                    f"    {'ok    ' if c.ok else 'DEFECT'} {c.name}"
                    + (f": {c.detail}" if c.detail and not c.ok else "")
                )
    finally:
        if args.keep:
            print(f"scratch folder kept: {root}")
        else:
            shutil.rmtree(root, ignore_errors=True)
    return 1 if defects else 0


if __name__ == "__main__":
    sys.exit(main())
