"""`acl3d analyze DIR [--reference PROTOCOL]`: statistics, figures and a Markdown report of a
campaign's runs, alone or beside a reference protocol's committed runs."""

from __future__ import annotations

import argparse
from pathlib import Path

import acl3d
from acl3d import results


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("dir", help="campaign directory (or any folder holding run directories)")
    p.add_argument("--baseline", default="random", help="reference teacher (default random)")
    p.add_argument(
        "--out",
        help="report directory (default DIR/report; for the results shipped with acl3d, "
        "report_NAME in the current directory)",
    )
    p.add_argument(
        "--metric",
        default="mastered_pct",
        choices=("mastered_pct", "mean_return"),
        help="score of a run at an evaluation (default: %% mastered test tasks)",
    )
    p.add_argument("--reps", type=int, default=20_000, help="bootstrap replicates (default 20000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the bootstrap (default 0)")
    p.add_argument(
        "--reference",
        metavar="PROTOCOL",
        help="compare with a reference protocol's runs: a shipped one "
        f"({', '.join(results.protocols())}) or a folder of runs; runs of another protocol are "
        "refused",
    )


def default_out(root) -> Path | None:
    """Where the report goes without --out: None (the analysis' default, beside the runs), or
    for runs inside the acl3d package (its shipped results; read-only in an install, and not
    to be polluted) report_NAME in the current directory."""
    package = Path(acl3d.__file__).resolve().parent
    folder = Path(root).resolve()
    if folder == package or package in folder.parents:
        return Path.cwd() / f"report_{folder.name}"
    return None


def run(args) -> int:
    from acl3d import validation as check
    from acl3d.analysis.report import MAX_REPS
    from acl3d.atomic_files import check_creatable_dir

    check.integer("--reps", args.reps, 100, MAX_REPS)  # named as typed, before any run is read
    check.seed(args.seed, "--seed")
    if args.out is not None:
        check_creatable_dir(Path(args.out), "--out")
    out = args.out if args.out is not None else default_out(args.dir)
    if args.reference is not None:
        from acl3d.analysis.reference import analyze_against

        out = analyze_against(args.dir, args.reference, out, args.metric, args.reps, args.seed)
        print(f"report written to {out / 'report.md'}")
        return 0
    from acl3d.analysis import analyze

    out = analyze(args.dir, out, args.baseline, args.metric, args.reps, args.seed)
    print(f"report written to {out / 'report.md'}")
    return 0
