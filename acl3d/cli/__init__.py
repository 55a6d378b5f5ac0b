"""`acl3d` command line: one module per subcommand, each with `add_arguments(parser)` and `run(args)`."""

from __future__ import annotations

import argparse
import importlib
import sys

from acl3d.extras import MissingExtraError, optional_dependency
from acl3d.version import __version__

# subcommand -> (module, one-line help, the extra it needs: None = the core install). Modules
# are imported only when their command runs.
COMMANDS: dict[str, tuple[str, str, str | None]] = {
    "train": ("acl3d.cli.train", "train a student with a teacher's curriculum on a track", "train"),
    "evaluate": ("acl3d.cli.evaluate", "evaluate a trained policy on a test set", "train"),
    "report": ("acl3d.cli.report", "write plots and a video for a run directory", "train"),
    "render": (
        "acl3d.cli.render",
        "videos (mp4/gif) or PNG strips of a trained, compared or random policy, labelled",
        "train",
    ),
    "view": (
        "acl3d.cli.view",
        "watch a policy in MuJoCo's interactive viewer (needs a display)",
        None,
    ),
    "toy": ("acl3d.cli.toy", "run a teacher on teachDeepRL's toy environment", None),
    "campaign": (
        "acl3d.cli.campaign",
        "benchmark campaigns: many runs on Ray or local processes",
        "campaign",
    ),
    "analyze": (
        "acl3d.cli.analyze",
        "statistics, figures and a report for a campaign's runs",
        "train",
    ),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="acl3d", description="Automatic curriculum learning on 3D MuJoCo tracks."
    )
    parser.add_argument("--version", action="version", version=f"acl3d {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text, extra) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module, _extra=extra, _parser=p)
        try:
            importlib.import_module(module).add_arguments(p)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
            p.set_defaults(_missing=True)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    if unknown:  # the command's own usage, not the top level's
        getattr(args, "_parser", parser).error(f"unrecognized arguments: {' '.join(unknown)}")
    if args.command is None:
        parser.print_help()
        return 2
    if getattr(args, "_missing", False):
        parser.error(f"command {args.command!r} is not available in this build")
    try:
        with optional_dependency(f"acl3d {args.command}", args._extra):
            return int(importlib.import_module(args._module).run(args) or 0)
    except MissingExtraError as exc:  # an install without the extra: say which one
        print(f"acl3d {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except ValueError as exc:  # bad user input: one clear line, no traceback
        print(f"acl3d {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
