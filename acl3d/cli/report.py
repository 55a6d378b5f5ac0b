"""`acl3d report RUN_DIR`: PNG plots (% mastered, returns, curriculum) and a video of the policy."""

from __future__ import annotations

import argparse
from pathlib import Path


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


def check_inputs(run_dir, out, video: bool) -> None:
    """Read what the report needs (config, teacher dump, model), check `out` and, for the video,
    that this machine renders, before the first PNG is written: a damaged run or a missing GL
    library fails with one line and leaves no partial report."""
    from acl3d.atomic_files import check_creatable_dir
    from acl3d.cli.render import check_offscreen
    from acl3d.run_format.checkpoints import check_zip
    from acl3d.training.checkpoint import MODEL_MEMBERS
    from acl3d.training.run_dir import RunDir
    from acl3d.training.torch_student.policy_file import POLICY_MEMBERS, is_policy_file

    run = RunDir(run_dir)
    run.read_config()
    tasks = run.test_tasks()  # reads the teacher dump through
    check_creatable_dir(Path(out) if out else run.path / "report", "--out")
    if video:
        if tasks is None:
            raise ValueError(
                f"run directory {str(run.path)!r} has no teacher dump with test tasks yet "
                "(use --no-video for the plots)"
            )
        model = run.best_model()
        check_zip(model, POLICY_MEMBERS if is_policy_file(model) else MODEL_MEMBERS)
        check_offscreen()


def run(args) -> int:
    from acl3d.training.report import write_report

    for name in ("video_tasks", "video_steps", "video_every"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    check_inputs(args.run_dir, args.out, args.video)
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
