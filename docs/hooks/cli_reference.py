"""MkDocs hook: the command line page ends with every command's `--help`, generated at build time
from the parser itself, so the reference can never fall behind the options."""

from __future__ import annotations

import argparse
import os

PAGE = "cli.md"
WIDTH = "100"  # argparse wraps help to the terminal's width


def _subparsers(parser: argparse.ArgumentParser, name: str):
    yield name, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub, subparser in action.choices.items():
                yield from _subparsers(subparser, f"{name} {sub}")


def reference() -> str:
    from acl3d.cli import build_parser

    previous = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = WIDTH
    try:
        sections = [
            f"### `{name}`\n\n```text\n{parser.format_help().rstrip()}\n```"
            for name, parser in _subparsers(build_parser(), "acl3d")
        ]
    finally:
        if previous is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = previous
    return (
        "## Every option\n\nGenerated from the parser (`acl3d COMMAND --help`).\n\n"
        + "\n\n".join(sections)
    )


def on_page_markdown(markdown: str, page, **kwargs) -> str:
    if page.file.src_uri != PAGE:
        return markdown
    return markdown.rstrip() + "\n\n" + reference() + "\n"
