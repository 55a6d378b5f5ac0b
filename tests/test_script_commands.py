"""The `acl3d` command lines of the shell scripts under scripts/ parse with today's CLI: a
renamed or lost option fails here, not on a lent GPU machine."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from acl3d.cli import build_parser

SCRIPTS = sorted((Path(__file__).resolve().parents[1] / "scripts").glob("*.sh"))
ENDS = {"&&", "||", ";", "|", "&", ">", ">>", "2>&1", "<"}


def acl3d_argvs(script: str) -> list[list[str]]:
    """Each `python3 -m acl3d ...` command's arguments, shell values replaced by "1" and array
    expansions ("${a[@]}", "$@") dropped."""
    text = re.sub(r"\$\(\([^)]*\)\)", "1", script.replace("\\\n", " "))
    argvs = []
    for line in text.splitlines():
        words = shlex.split(line, comments=True)
        for start in (
            i for i in range(len(words) - 2) if words[i : i + 3] == ["python3", "-m", "acl3d"]
        ):
            argv = []
            for word in words[start + 3 :]:
                if word in ENDS or word.startswith((">", "2>")):
                    break
                if "[@]" in word or word == "$@":
                    continue
                argv.append("1" if "$" in word else word)
            argvs.append(argv)
    return argvs


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_acl3d_commands_of_scripts_parse(script):
    argvs = acl3d_argvs(script.read_text())
    assert argvs, f"{script.name}: no acl3d command found"
    for argv in argvs:
        try:
            build_parser().parse_args(argv)
        except SystemExit as exc:
            assert exc.code == 0, f"{script.name}: acl3d {shlex.join(argv)} does not parse"


def test_a_lost_option_is_caught():
    argv = acl3d_argvs('python3 -m acl3d train --no-such-option "$x" --steps $((n / 2)) > log\n')
    assert argv == [["train", "--no-such-option", "1", "--steps", "1"]]
    with pytest.raises(SystemExit):
        build_parser().parse_args(argv[0])
