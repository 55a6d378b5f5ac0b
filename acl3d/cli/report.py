"""`acl3d report RUN_DIR`: PNG plots (% mastered, returns, curriculum) and a video of the policy."""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", metavar="RUN_DIR", help="a run directory written by acl3d train")
    p.add_argument("--out", help="output folder (default RUN_DIR/report)")
    p.add_argument("--no-video", dest="video", action="store_false", help="plots only")
    p.add_argument(
        "--video-tasks", type=int, default=3, help="test tasks shown in the video (default 3)"
    )
    p.add_argument(
        "--video-steps", type=int, default=1000, help="steps per task at most (default 1000)"
    )
    p.add_argument("--video-every", type=int, default=2, help="keep every N-th frame (default 2)")


def run(args) -> int:
    from acl3d.training.report import write_report

    for name in ("video_tasks", "video_steps", "video_every"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    written = write_report(
        args.run_dir,
        args.out,
        video=args.video,
        n_tasks=args.video_tasks,
        max_steps=args.video_steps,
        every=args.video_every,
    )
    for path in written:
        print(f"wrote {path}")
    return 0
