"""What the CLI tests share: a mistake must print one line naming it, never a traceback."""

from __future__ import annotations


def one_line_error(capsys, *words) -> str:
    """The command's stderr, checked to be one line holding every word and no traceback."""
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for word in words:
        assert word in err, err
    return err
