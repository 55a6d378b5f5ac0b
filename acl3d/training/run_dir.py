"""The run directory: everything a run leaves behind, in open formats.

    RUN/config.yaml, config.json    the full config + versions, seeds, git commit, command line
    RUN/status.json                 running | finished | crashed (with the traceback)
    RUN/evals.csv                   one row per evaluation (% mastered, mean return, ...)
    RUN/evals_tasks.csv             one row per test episode (task, return, length, success)
    RUN/episodes.csv                one row per training episode (task, return, length, ...)
    RUN/teacher.json / .npz         the controller's dump (tasks, returns, teacher book-keeping)
    RUN/tb/                         TensorBoard (SB3 scalars + curriculum/* + eval/*)
    RUN/checkpoints/LATEST          name of the newest complete checkpoint folder
    RUN/checkpoints/step_N/         model.zip, controller.*, vecnormalize.*, replay_buffer.npz,
                                    rng.*, progress.json
    RUN/final_model.zip (+ final_vecnormalize.*)

Checkpoints are written into a fresh folder and published by atomically replacing LATEST, so a
crash while saving leaves the previous checkpoint usable. CSV rows are flushed as written.
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
from importlib import metadata
from pathlib import Path

import yaml

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


def _atomic_write(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


class CsvLog:
    """Append-only CSV with a fixed header; rows are flushed so a crash loses nothing written."""

    def __init__(self, path: Path, header: list[str]):
        self.path = path
        self.header = list(header)
        exists = path.exists() and path.stat().st_size > 0
        self._file = path.open("a", newline="")
        self._writer = csv.writer(self._file)
        if not exists:
            self._writer.writerow(self.header)
            self._file.flush()

    def write(self, row) -> None:
        self._writer.writerow(row)
        self._file.flush()

    def close(self) -> None:
        self._file.close()


def truncate_csv(path: Path, step_column: str, max_step: int) -> None:
    """Drop rows logged after `max_step` (they are redone when a run resumes)."""
    if not path.exists():
        return
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        return
    col = rows[0].index(step_column)
    kept = [rows[0]] + [r for r in rows[1:] if r and int(float(r[col])) <= max_step]
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("w", newline="") as f:
        csv.writer(f).writerows(kept)
    os.replace(tmp, path)


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
        doc = {"config": config, **sections, "environment": environment_info()}
        _atomic_write(self.config_yaml, yaml.safe_dump(doc, sort_keys=False))
        _atomic_write(self.path / "config.json", json.dumps(doc, indent=2))

    def read_config(self) -> dict:
        return self.read_section("config")

    def read_section(self, name: str):
        if not self.exists():
            raise ValueError(f"{str(self.path)!r} is not a run directory (no config.yaml)")
        return yaml.safe_load(self.config_yaml.read_text())[name]

    def set_status(self, status: str, **extra) -> None:
        _atomic_write(self.path / "status.json", json.dumps({"status": status, **extra}, indent=2))

    def set_crashed(self, exc: BaseException) -> None:
        tb = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
        self.set_status(
            "crashed", error=str(exc), traceback=tb, latest_checkpoint=self.latest_checkpoint_name()
        )

    # ------------------------------------------------------------------ checkpoints
    def new_checkpoint_dir(self, step: int) -> Path:
        folder = self.checkpoints / f"step_{step:012d}"
        if folder.exists():
            shutil.rmtree(folder)
        folder.mkdir(parents=True)
        return folder

    def publish_checkpoint(self, folder: Path) -> None:
        """Make `folder` the resume point, then prune older checkpoints."""
        _atomic_write(self.checkpoints / "LATEST", folder.name)
        older = sorted(p for p in self.checkpoints.glob("step_*") if p.name < folder.name)
        for old in older[: max(0, len(older) - (KEEP_CHECKPOINTS - 1))]:
            shutil.rmtree(old, ignore_errors=True)
        for stale in self.checkpoints.glob("step_*"):
            if stale.name > folder.name:  # left by a crash during an earlier save
                shutil.rmtree(stale, ignore_errors=True)

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
        from acl3d.teachers.base import load_state

        return load_state(self.teacher_prefix).get("test_tasks")
