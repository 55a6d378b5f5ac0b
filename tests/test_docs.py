"""Every code block of the README and the docs works as shown.

Python blocks run, each in a fresh namespace inside an empty directory. A block that trains for
minutes may be skipped by putting, on the line right before its fence,
`<!-- snippet: skip (why, and which test covers it instead) -->`; keep those few. Bash blocks:
every `acl3d ...` command they show must parse (its options exist and take the values shown).
YAML blocks must load.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml

from acl3d.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
SKIP = re.compile(r"<!--\s*snippet:\s*skip\s*\((.+)\)\s*-->")
FENCE = re.compile(r"^(\s*)```(\w*)\s*$")


@dataclass
class Block:
    page: Path
    line: int  # of the opening fence, 1-based
    language: str
    code: str
    skip: str | None  # the reason given by a skip marker

    @property
    def id(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def code_blocks(page: Path) -> list[Block]:
    lines = page.read_text().splitlines()
    blocks, i = [], 0
    while i < len(lines):
        opening = FENCE.match(lines[i])
        if not opening:
            i += 1
            continue
        indent, language = opening.groups()
        end = next(j for j in range(i + 1, len(lines)) if lines[j].strip() == "```")
        body = [line[len(indent) :] for line in lines[i + 1 : end]]
        marker = SKIP.search(lines[i - 1]) if i else None
        blocks.append(Block(page, i + 1, language, "\n".join(body), marker and marker.group(1)))
        i = end + 1
    return blocks


BLOCKS = [block for page in PAGES for block in code_blocks(page)]


def _of(language: str) -> list:
    return [pytest.param(b, id=b.id) for b in BLOCKS if b.language == language]


@pytest.mark.parametrize("block", _of("python"))
def test_python_blocks_run(block, tmp_path, monkeypatch):
    if block.skip:
        pytest.skip(f"marked in the page: {block.skip}")
    monkeypatch.chdir(tmp_path)
    exec(compile(block.code, block.id, "exec"), {"__name__": "__main__"})


def acl3d_commands(script: str) -> list[list[str]]:
    """The argument lists of the `acl3d` commands of a shell script (chains, comments, `\\`)."""
    commands = []
    for line in script.replace("\\\n", " ").splitlines():
        words = shlex.split(line, comments=True)
        command: list[str] = []
        for word in [*words, "&&"]:
            if word in ("&&", "||", ";", "|"):
                if command and command[0] == "acl3d":
                    commands.append(command[1:])
                command = []
            else:
                command.append(word)
    return commands


@pytest.mark.parametrize("block", _of("bash"))
def test_bash_blocks_show_valid_acl3d_commands(block):
    parser = build_parser()
    for argv in acl3d_commands(block.code):
        try:
            parser.parse_args(argv)
        except SystemExit as exc:
            assert exc.code == 0, f"{block.id}: acl3d {shlex.join(argv)} does not parse"


@pytest.mark.parametrize("block", _of("yaml"))
def test_yaml_blocks_load(block):
    assert isinstance(yaml.safe_load(block.code), dict)


def test_skip_markers_are_few_and_say_why():
    skipped = [b for b in BLOCKS if b.skip]
    assert len(skipped) <= 5, [b.id for b in skipped]
    assert all(len(b.skip) > 20 for b in skipped)


def test_the_reader_finds_commands_in_chains_and_comments():
    script = "pip install . && acl3d train --out runs/x && acl3d report runs/x  # comment\n"
    script += "acl3d campaign run quick \\\n  --out runs/q\npython -m pytest"
    assert acl3d_commands(script) == [
        ["train", "--out", "runs/x"],
        ["report", "runs/x"],
        ["campaign", "run", "quick", "--out", "runs/q"],
    ]


def test_the_readme_test_command_is_what_ci_runs():
    readme = (ROOT / "README.md").read_text()
    ci = (ROOT / ".ci" / "run").read_text()
    command = 'python -m pip install -q torch==2.13.0 ".[dev]" && python -m pytest -q -n 2'
    assert command in readme and command in ci


def _nav_pages(entries) -> set[str]:
    pages = set()
    for entry in entries:
        for value in entry.values() if isinstance(entry, dict) else [entry]:
            pages |= _nav_pages(value) if isinstance(value, list) else {value}
    return pages


def test_every_docs_page_is_in_the_site_navigation():
    """A page missing from mkdocs.yml's nav fails `mkdocs build --strict` in CI: say it here."""
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    pages = {str(p.relative_to(ROOT / "docs")) for p in (ROOT / "docs").rglob("*.md")}
    missing = sorted(pages - _nav_pages(config["nav"]))
    assert not missing, f"add these pages to the nav of mkdocs.yml: {missing}"


def test_the_readme_stays_a_front_door():
    """What acl3d is, the two commands, a minimal example, the headline, links: the rest lives in
    docs/ (one topic per page)."""
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 300, f"README.md has {len(lines)} lines; move details to a docs/ page"


def test_the_readme_links_to_files_that_exist():
    text = (ROOT / "README.md").read_text()
    targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    local = [t for t in targets if not re.match(r"[a-z]+://", t)]
    assert local and all((ROOT / t).exists() for t in local), [
        t for t in local if not (ROOT / t).exists()
    ]
