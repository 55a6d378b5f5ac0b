"""The run's CSV logs (evals.csv, evals_tasks.csv, episodes.csv): append-only, numeric, one
header line. A kill can tear the last row; a hand edit can tear any. Readers that make results
(`read_csv(strict=True)`) refuse a torn row naming the file and line; readers that only show
progress skip it.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path

from acl3d.atomic_files import atomic_replace, removed_on_failure, temp_path


class TornTable(ValueError):
    """A row of a run's CSV log has the wrong number of fields or a cell that is not a number."""


class CsvLog:
    """Append-only CSV with a fixed header; each write opens, appends and closes, so nothing
    written is lost to a crash and there is no file handle to manage."""

    def __init__(self, path: Path, header: list[str]):
        self.path = path
        self.header = list(header)
        if not (path.exists() and path.stat().st_size > 0):
            self.write_rows([self.header])

    def write(self, row) -> None:
        self.write_rows([row])

    def write_rows(self, rows) -> None:
        with self.path.open("a", newline="") as f:
            csv.writer(f).writerows(rows)


def _numbers(row: list[str], header: list[str]) -> list[float] | None:
    """The row's cells as numbers, or None for a torn row."""
    if len(row) != len(header):
        return None
    try:
        return [float(cell) for cell in row]
    except ValueError:
        return None


def read_csv(path: Path, strict: bool = False) -> dict[str, list[float]]:
    """Columns of a run's numeric CSV log. A torn row is skipped, or with `strict` a
    `TornTable` naming the file, the line and what is wrong."""
    path = Path(path)
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        return {}
    header = rows[0]
    cols: dict[str, list[float]] = {name: [] for name in header}
    for line, row in enumerate(rows[1:], start=2):
        values = _numbers(row, header)
        if values is None:
            if strict:
                raise TornTable(
                    f"{path} line {line} is torn: {','.join(row)!r} ({len(row)} fields, "
                    f"{len(header)} in the header, numbers only)"
                )
            continue
        for name, value in zip(header, values):
            cols[name].append(value)
    return cols


def truncate_csv(path: Path, step_column: str, max_step: int) -> None:
    """Drop rows logged after `max_step` and torn rows (redone when a run resumes)."""
    if not path.exists():
        return
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        return
    col = rows[0].index(step_column)
    kept = [rows[0]]
    for row in rows[1:]:
        values = _numbers(row, rows[0])
        if values is not None and values[col] <= max_step:
            kept.append(row)
    tmp = temp_path(path)
    with removed_on_failure(tmp):
        with tmp.open("w", newline="") as f:
            csv.writer(f).writerows(kept)
        atomic_replace(tmp, path)


def last_row(path: Path) -> dict[str, float]:
    """The last complete row, read from the file's end (episode logs grow large); empty when
    there is none or it is torn (progress display only)."""
    try:
        with Path(path).open("rb") as f:
            header = f.readline().decode(errors="replace").strip().split(",")
            f.seek(0, os.SEEK_END)
            size = f.tell()
            f.seek(max(0, size - 4096))
            lines = f.read().decode(errors="replace").splitlines()
    except OSError:
        return {}
    if len(lines) < 2:  # the header alone, or nothing
        return {}
    values = _numbers(lines[-1].split(","), header)
    return {} if values is None else dict(zip(header, values))
