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

One process at a time: a training process holds an exclusive OS lock (flock) on the run
directory for as long as it works in it; the OS releases it when the process ends, however it
ends, so a killed run can be resumed at once and a running one cannot be entered by a second.
Temporary files a killed process leaves behind are removed by the next one that takes the lock.
"""

from __future__ import annotations

import csv
import errno
import fcntl
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import traceback
import zipfile
import zlib
from collections.abc import Callable
from contextlib import contextmanager
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


# Temporary names of files being replaced (a killed writer leaves them; see remove_temp_files)
def temp_path(path: Path) -> Path:
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def temp_prefix(prefix: Path) -> Path:
    """For files written as PREFIX + suffix(es): `_NAME_PID_tmp` + the same suffixes."""
    return prefix.with_name(f"_{prefix.name}_{os.getpid()}_tmp")


_TEMP_NAME = re.compile(r"^(\..+\.\d+\.tmp|_.+_\d+_tmp(\.\w+)?)$")  # what the two above make


@contextmanager
def removed_on_failure(*paths: Path):
    """Temporary files that must not outlive a failed write (a full disk, an interrupt)."""
    try:
        yield
    except BaseException:
        for path in paths:
            path.unlink(missing_ok=True)
        raise


def atomic_write(path: Path, text: str) -> None:
    tmp = temp_path(path)
    with removed_on_failure(tmp):
        tmp.write_text(text)
        atomic_replace(tmp, path)


def atomic_state_files(prefix: Path, write: Callable[[Path], None]) -> None:
    """`write(tmp)` writes TMP.json + TMP.npz (acl3d's state format); both then replace
    PREFIX.json/.npz, the .npz first so the .json never names arrays that are not there yet."""
    tmp = temp_prefix(prefix)
    with removed_on_failure(tmp.with_suffix(".npz"), tmp.with_suffix(".json")):
        write(tmp)
        for suffix in (".npz", ".json"):
            atomic_replace(tmp.with_suffix(suffix), prefix.with_suffix(suffix))


def is_disk_full(exc: BaseException) -> bool:
    return isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)


def read_state(prefix: Path) -> dict:
    """`load_state` of a run's PREFIX.json/.npz; a missing, truncated or corrupt file is a
    ValueError naming it."""
    try:
        return load_state(prefix)
    except FileNotFoundError as exc:
        raise ValueError(f"{exc.filename} is missing") from None
    except Exception as exc:  # json, zip, zlib and numpy each raise their own kind
        raise ValueError(
            f"{prefix}.json/.npz cannot be read (truncated or corrupt): {type(exc).__name__}: {exc}"
        ) from None


def check_zip(path: Path, members: tuple[str, ...] = ()) -> None:
    """A complete zip holding `members` (every member's CRC checked): ValueError naming the
    file otherwise. Name the members: the half of a truncated SB3 zip can read as the zip
    stored inside it (its policy.pth)."""
    try:
        with zipfile.ZipFile(path) as z:
            missing = sorted(set(members) - set(z.namelist()))
            bad = z.testzip()
    except FileNotFoundError:
        raise ValueError(f"{path} is missing") from None
    except (OSError, zipfile.BadZipFile, EOFError, zlib.error) as exc:
        raise ValueError(f"{path} is truncated or corrupt: {exc}") from None
    if missing or bad is not None:
        why = f"member {bad!r} fails its CRC check" if bad else f"no {', '.join(missing)}"
        raise ValueError(f"{path} is truncated or corrupt: {why}")


def check_creatable_dir(path: Path, name: str) -> None:
    """That `path` is, or can be made, a folder this process writes in (checked before any
    work, so that a run or a report does not fail at its first write)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ValueError(f"{name}={str(path)!r} is a file; valid: a folder")
    existing = path
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise ValueError(f"{name}={str(path)!r} cannot be created: {str(existing)!r} is a file")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"{name}={str(path)!r} cannot be written: {str(existing)!r} is read-only")


def check_writable_file(path: Path, name: str) -> None:
    """That the file `path` can be written: its folder exists and is writable."""
    path = Path(path)
    folder = path.parent
    if path.is_dir():
        raise ValueError(f"{name}={str(path)!r} is a folder; valid: a file path")
    if not folder.is_dir():
        raise ValueError(f"{name}={str(path)!r}: folder {str(folder)!r} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise ValueError(f"{name}={str(path)!r} cannot be written (read-only)")


class DamagedCheckpoint(ValueError):
    """A checkpoint file is missing, truncated or corrupt (a resume falls back past it)."""


class RunInUseError(ValueError):
    """Another process holds the run directory's lock."""


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
    tmp = temp_path(path)
    with removed_on_failure(tmp):
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


# What `acl3d train` writes in a run directory (`clear` removes these and nothing else)
_RUN_ENTRIES = (
    "config.yaml", "config.json", "status.json", "evals.csv", "evals_tasks.csv", "episodes.csv",
    "teacher.json", "teacher.npz", "tb", "checkpoints", "final_model.zip",
    "final_model_vecnormalize.json", "final_model_vecnormalize.npz",
)  # fmt: skip


class RunDir:
    def __init__(self, path):
        self.path = Path(path)
        self._lock_fd: int | None = None

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

    # ------------------------------------------------------------------ one process at a time
    def lock(self) -> None:
        """Take the run directory's exclusive lock (RunInUseError if another process has it)."""
        if self._lock_fd is not None:
            return
        try:
            fd = os.open(self.path, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
        except OSError as exc:
            raise ValueError(f"run directory {str(self.path)!r}: {exc.strerror}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno not in (errno.EWOULDBLOCK, errno.EACCES):
                raise
            raise RunInUseError(self._in_use_message()) from None
        self._lock_fd = fd

    def unlock(self) -> None:
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None

    def _in_use_message(self) -> str:
        try:
            pid = json.loads((self.path / "status.json").read_text()).get("pid")
        except (OSError, ValueError):
            pid = None
        who = f"process {pid}" if pid else "another process"
        return (
            f"run directory {str(self.path)!r} is in use by {who} (it holds the run's lock); "
            "wait for it to end or stop it, then try again"
        )

    def remove_temp_files(self) -> None:
        """Temporary files of a writer that was killed (only call with the lock held)."""
        for folder in (self.path, self.checkpoints):
            for path in folder.iterdir() if folder.is_dir() else ():
                if _TEMP_NAME.match(path.name) and path.is_file():
                    path.unlink(missing_ok=True)

    # ------------------------------------------------------------------ config and status
    def check_new(self, overwrite: bool = False) -> None:
        """That a new run can be created here: no run already (unless `overwrite`), and a
        directory that can be created and written."""
        check_creatable_dir(self.path, "out")
        if self.exists() and not overwrite:
            raise ValueError(
                f"run directory {str(self.path)!r} already holds a run; use --resume to continue "
                "it, --overwrite to delete it and start again, or choose another --out"
            )

    def create(self, config: dict, overwrite: bool = False, **sections) -> None:
        """Make the directory and take its lock, then (with `overwrite`, deleting the run that
        is there) write the config: the run now exists."""
        self.check_new(overwrite)
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            self.lock()
            self.check_new(overwrite)  # again, with the lock: another process may have made it
            if overwrite:
                self.clear()
                self.remove_temp_files()
            self.write_config(config, **sections)
        except OSError as exc:
            if is_disk_full(exc):
                raise
            raise ValueError(f"out={str(self.path)!r} cannot be written: {exc.strerror}") from None

    def clear(self) -> None:
        """Delete the run's own files (nothing else that may be in the folder)."""
        for name in _RUN_ENTRIES:
            path = self.path / name
            if path.is_dir():
                shutil.rmtree(path)
            else:
                path.unlink(missing_ok=True)

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
        config = self.read_section("config")
        if not isinstance(config, dict):
            raise ValueError(f"{self.config_yaml}: its 'config' section is not a mapping")
        return config

    def read_section(self, name: str):
        if not self.exists():
            raise ValueError(f"{str(self.path)!r} is not a run directory (no config.yaml)")
        try:
            doc = yaml.safe_load(self.config_yaml.read_text())
        except (yaml.YAMLError, UnicodeDecodeError) as exc:
            where = " ".join(str(exc).split())
            raise ValueError(f"{self.config_yaml} is not valid YAML: {where}") from None
        if not isinstance(doc, dict) or name not in doc:
            raise ValueError(
                f"{self.config_yaml} has no {name!r} section (was it edited?); valid: the "
                f"config.yaml that acl3d train wrote (config.json holds a copy)"
            )
        return doc[name]

    def status(self) -> str | None:
        """running | finished | interrupted | crashed, or None before the first start (or when
        status.json cannot be read)."""
        try:
            return json.loads((self.path / "status.json").read_text())["status"]
        except (OSError, ValueError, KeyError, TypeError):  # none yet, or torn by a full disk
            return None

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
            raise ValueError(self._no_checkpoint_message())
        return self.checkpoints / name

    def _no_checkpoint_message(self, why: str = "") -> str:
        return (
            f"run directory {str(self.path)!r} has no complete checkpoint to resume{why}; start "
            f"it again with acl3d train --overwrite --out {self.path} (same options), or delete it"
        )

    def resume_point(self, verify: Callable[[Path], None]) -> Path:
        """The newest complete checkpoint that `verify(folder)` accepts (it raises
        DamagedCheckpoint for a damaged one; other errors stop the search): LATEST, else the
        previous one the run keeps, said on stderr."""
        latest = self.latest_checkpoint_name()
        folders = sorted(
            (p for p in self.checkpoints.glob("step_*") if latest is None or p.name <= latest),
            reverse=True,
        )
        rejected = []
        for folder in folders:
            if not (folder / "progress.json").exists():
                continue
            try:
                verify(folder)
            except DamagedCheckpoint as exc:
                rejected.append(f"{folder.name}: {exc}")
                continue
            for why in rejected:
                print(f"[acl3d] skipping damaged checkpoint {why}", file=sys.stderr)
            return folder
        if rejected:
            raise ValueError(self._no_checkpoint_message(f" (damaged: {'; '.join(rejected)})"))
        raise ValueError(self._no_checkpoint_message())

    def restart_from(self, folder: Path) -> None:
        """Make `folder` the run's LATEST checkpoint; newer (damaged) ones are set aside as
        `checkpoints/.damaged_step_N`, so the run writes its steps again."""
        if folder.name == self.latest_checkpoint_name():
            return
        for newer in self.checkpoints.glob("step_*"):
            if newer.name > folder.name:
                aside = self.checkpoints / f".damaged_{newer.name}"
                shutil.rmtree(aside, ignore_errors=True)
                os.replace(newer, aside)
        atomic_write(self.checkpoints / "LATEST", folder.name)
        fsync_path(self.checkpoints)

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
        return read_state(self.teacher_prefix).get("test_tasks")
