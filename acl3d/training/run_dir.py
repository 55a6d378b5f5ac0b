"""The run directory: everything a run leaves behind, in open formats.

    RUN/config.yaml, config.json    the full config + versions, seeds, git commit, command line
    RUN/status.json                 running | finished | crashed (with the traceback)
    RUN/evals.csv                   one row per evaluation (% mastered, mean return, ...)
    RUN/evals_tasks.csv             one row per test episode (task, return, length, success)
    RUN/episodes.csv                one row per training episode (task, return, length, ...)
    RUN/teacher.json / .npz         the controller's dump (tasks, returns, teacher book-keeping)
    RUN/tb/                         TensorBoard (SB3 scalars + curriculum/* + eval/*)
    RUN/checkpoints/LATEST          name of the newest complete checkpoint folder
    RUN/checkpoints/step_N/         model.zip, model_vecnormalize.*, controller.*, runtime.*
                                    (envs, curriculum queues, SB3 and VecNormalize runtime state),
                                    replay_buffer.npz, rng.*, progress.json
    RUN/final_model.zip (+ final_vecnormalize.*)

Crash safety: every file other than the append-only CSVs is written to a temporary name, fsynced
and renamed over its target, so a reader sees the old or the new file, never a mix. A checkpoint
is written into `checkpoints/.partial_step_N/`, renamed to `step_N/` once complete and only then
named in LATEST; a kill at any moment leaves LATEST on a complete checkpoint. CSV rows are
flushed as written; a resume drops rows logged after its checkpoint (and a torn last row).
"""

from __future__ import annotations

import csv
import json
import os
import platform
import shutil
import subprocess
import sys
import traceback
from collections.abc import Callable
from importlib import metadata
from pathlib import Path

import yaml

from acl3d.teachers.base import load_state

KEEP_CHECKPOINTS = 2
_PACKAGES = ("acl3d", "stable-baselines3", "torch", "gymnasium", "mujoco", "numpy", "scikit-learn")


def environment_info() -> dict:
    """Versions and machine facts needed to reproduce a run."""
    versions = {}
    for pkg in _PACKAGES:
        try:
            versions[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            versions[pkg] = None
    return {
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "packages": versions,
        "git_commit": _git_commit(),
        "command": sys.argv,
    }


def _git_commit() -> str | None:
    here = Path(__file__).resolve().parent
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None if out.returncode == 0 else None


def fsync_path(path: Path) -> None:
    """Flush a written file (or a folder's entries) to disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def atomic_replace(tmp: Path, path: Path) -> None:
    """Move the complete file `tmp` over `path` (fsynced first: never an empty file after a crash)."""
    fsync_path(tmp)
    os.replace(tmp, path)


def atomic_write(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    atomic_replace(tmp, path)


def atomic_state_files(prefix: Path, write: Callable[[Path], None]) -> None:
    """`write(tmp)` writes TMP.json + TMP.npz (acl3d's state format); both then replace
    PREFIX.json/.npz, the .npz first so the .json never names arrays that are not there yet."""
    tmp = prefix.with_name(f"_{prefix.name}_{os.getpid()}_tmp")
    write(tmp)
    for suffix in (".npz", ".json"):
        atomic_replace(tmp.with_suffix(suffix), prefix.with_suffix(suffix))


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


def truncate_csv(path: Path, step_column: str, max_step: int) -> None:
    """Drop rows logged after `max_step` (they are redone when a run resumes)."""
    if not path.exists():
        return
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        return
    col = rows[0].index(step_column)
    kept = [rows[0]] + [r for r in rows[1:] if _complete(r, rows[0]) and _step(r[col]) <= max_step]
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with tmp.open("w", newline="") as f:
        csv.writer(f).writerows(kept)
    atomic_replace(tmp, path)


def _complete(row: list[str], header: list[str]) -> bool:
    return len(row) == len(header)


def _step(cell: str) -> float:
    try:
        return float(cell)
    except ValueError:  # a row torn by a kill
        return float("inf")


def read_csv(path: Path) -> dict[str, list[float]]:
    """Columns of a numeric CSV (non-numeric cells become NaN)."""
    with Path(path).open(newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        return {}
    cols: dict[str, list[float]] = {name: [] for name in rows[0]}
    for r in rows[1:]:
        for name, cell in zip(rows[0], r):
            try:
                cols[name].append(float(cell))
            except ValueError:
                cols[name].append(float("nan"))
    return cols


class RunDir:
    def __init__(self, path):
        self.path = Path(path)

    # ------------------------------------------------------------------ layout
    @property
    def config_yaml(self) -> Path:
        return self.path / "config.yaml"

    @property
    def evals_csv(self) -> Path:
        return self.path / "evals.csv"

    @property
    def evals_tasks_csv(self) -> Path:
        return self.path / "evals_tasks.csv"

    @property
    def episodes_csv(self) -> Path:
        return self.path / "episodes.csv"

    @property
    def tb(self) -> Path:
        return self.path / "tb"

    @property
    def teacher_prefix(self) -> Path:
        return self.path / "teacher"

    @property
    def final_model(self) -> Path:
        return self.path / "final_model.zip"

    @property
    def checkpoints(self) -> Path:
        return self.path / "checkpoints"

    def exists(self) -> bool:
        return self.config_yaml.exists()

    # ------------------------------------------------------------------ config and status
    def check_new(self) -> None:
        if self.exists():
            raise ValueError(
                f"run directory {str(self.path)!r} already holds a run; use --resume to continue "
                "it or choose another --out"
            )

    def create(self, config: dict, **sections) -> None:
        self.check_new()
        self.path.mkdir(parents=True, exist_ok=True)
        self.write_config(config, **sections)

    def write_config(self, config: dict, **sections) -> None:
        """`config` is what `read_config` returns; `sections` are derived facts, for people."""
        self._write_doc({"config": config, **sections, "environment": environment_info()})

    def update_config(self, config: dict, **sections) -> None:
        """On resume: the new config and sections; the original environment (command line,
        versions) is kept and this session's is appended to `resumed`."""
        doc = yaml.safe_load(self.config_yaml.read_text())
        doc.update({"config": config, **sections})
        doc["resumed"] = [*doc.get("resumed", []), environment_info()]
        self._write_doc(doc)

    def _write_doc(self, doc: dict) -> None:
        atomic_write(self.config_yaml, yaml.safe_dump(doc, sort_keys=False))
        atomic_write(self.path / "config.json", json.dumps(doc, indent=2))

    def read_config(self) -> dict:
        return self.read_section("config")

    def read_section(self, name: str):
        if not self.exists():
            raise ValueError(f"{str(self.path)!r} is not a run directory (no config.yaml)")
        return yaml.safe_load(self.config_yaml.read_text())[name]

    def status(self) -> str | None:
        """running | finished | interrupted | crashed, or None before the first start."""
        path = self.path / "status.json"
        return json.loads(path.read_text())["status"] if path.exists() else None

    def set_status(self, status: str, **extra) -> None:
        atomic_write(self.path / "status.json", json.dumps({"status": status, **extra}, indent=2))

    def set_crashed(self, exc: BaseException) -> None:
        tb = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
        self.set_status(
            "crashed", error=str(exc), traceback=tb, latest_checkpoint=self.latest_checkpoint_name()
        )

    # ------------------------------------------------------------------ checkpoints
    def write_checkpoint(self, step: int, write: Callable[[Path], None]) -> Path:
        """Let `write(folder)` fill a fresh folder, then publish it as `step_N` and name it in
        LATEST, each move atomic: a crash at any point leaves LATEST on a complete checkpoint."""
        final = self.checkpoints / f"step_{step:012d}"
        if final.name == self.latest_checkpoint_name():
            raise ValueError(f"checkpoint {final.name} is already published")
        partial = self.checkpoints / f".partial_{final.name}"
        shutil.rmtree(partial, ignore_errors=True)
        partial.mkdir(parents=True)
        write(partial)
        for file in partial.iterdir():
            fsync_path(file)
        fsync_path(partial)
        shutil.rmtree(final, ignore_errors=True)  # left by a crash between rename and LATEST
        os.replace(partial, final)
        fsync_path(self.checkpoints)
        atomic_write(self.checkpoints / "LATEST", final.name)
        fsync_path(self.checkpoints)
        self._prune(final.name)
        return final

    def _prune(self, latest: str) -> None:
        """Keep the newest KEEP_CHECKPOINTS; drop leftovers of interrupted saves."""
        older = sorted(p for p in self.checkpoints.glob("step_*") if p.name < latest)
        for old in older[: max(0, len(older) - (KEEP_CHECKPOINTS - 1))]:
            shutil.rmtree(old, ignore_errors=True)
        for stale in self.checkpoints.glob("step_*"):
            if stale.name > latest:
                shutil.rmtree(stale, ignore_errors=True)
        for partial in self.checkpoints.glob(".partial_*"):
            shutil.rmtree(partial, ignore_errors=True)

    def latest_checkpoint_name(self) -> str | None:
        pointer = self.checkpoints / "LATEST"
        return pointer.read_text().strip() if pointer.exists() else None

    def latest_checkpoint(self) -> Path:
        name = self.latest_checkpoint_name()
        if name is None or not (self.checkpoints / name / "progress.json").exists():
            raise ValueError(
                f"run directory {str(self.path)!r} has no complete checkpoint to resume"
            )
        return self.checkpoints / name

    # ------------------------------------------------------------------ reading back
    def best_model(self) -> Path:
        """final_model.zip, or the newest checkpoint's model for a run still going or crashed."""
        if self.final_model.exists():
            return self.final_model
        return self.latest_checkpoint() / "model.zip"

    def test_tasks(self):
        """The test set the run evaluated on (from its teacher dump), or None."""
        if not self.teacher_prefix.with_suffix(".json").exists():
            return None
        return load_state(self.teacher_prefix).get("test_tasks")
