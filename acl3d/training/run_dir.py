"""`RunDir`: the training side of a run directory (format: `acl3d.run_format`).

Crash safety: every file other than the append-only CSVs is replaced atomically
(`acl3d.atomic_files`). A checkpoint is written into `checkpoints/.partial_step_N/`, sealed by a
manifest of its files' hashes, renamed to `step_N/` and only then named in LATEST; a kill at any
moment leaves LATEST on a complete checkpoint. CSV rows are flushed as written; a resume drops
rows logged after its checkpoint (and torn rows).

One process at a time: a training process holds an exclusive OS lock (flock) on the run
directory for as long as it works in it; the OS releases it when the process ends, however it
ends, so a killed run can be resumed at once and a running one cannot be entered by a second.
Temporary files a killed process leaves behind are removed by the next one that takes the lock.
"""

from __future__ import annotations

import errno
import fcntl
import os
import platform
import shutil
import subprocess
import sys
import traceback
from collections.abc import Callable
from importlib import metadata
from pathlib import Path

from acl3d.atomic_files import (
    atomic_write,
    check_creatable_dir,
    fsync_path,
    is_disk_full,
    is_temp_name,
    removed_if_created,
)
from acl3d.run_format import documents, layout
from acl3d.run_format.checkpoints import (
    DamagedCheckpoint,
    checkpoint_name,
    latest_name,
    resume_candidates,
    verify_manifest,
    write_manifest,
)
from acl3d.run_format.status import read_status, write_status
from acl3d.teachers.state_files import load_state

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


class RunInUseError(ValueError):
    """Another process holds the run directory's lock."""


class RunDir:
    """A run directory as training uses it: its files, its lock, its config and status, and
    its checkpoints."""

    def __init__(self, path):
        self.path = Path(path)
        self._lock_fd: int | None = None

    # ------------------------------------------------------------------ layout
    @property
    def config_yaml(self) -> Path:
        return self.path / layout.CONFIG_YAML

    @property
    def evals_csv(self) -> Path:
        return self.path / layout.EVALS

    @property
    def evals_tasks_csv(self) -> Path:
        return self.path / layout.EVALS_TASKS

    @property
    def episodes_csv(self) -> Path:
        return self.path / layout.EPISODES

    @property
    def tb(self) -> Path:
        return self.path / layout.TENSORBOARD

    @property
    def teacher_prefix(self) -> Path:
        return self.path / layout.TEACHER

    @property
    def final_model(self) -> Path:
        return self.path / layout.FINAL_MODEL

    @property
    def checkpoints(self) -> Path:
        return self.path / layout.CHECKPOINTS

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
        status = read_status(self.path)
        pid = status.fields.get("pid") if status is not None else None
        who = f"process {pid}" if pid else "another process"
        return (
            f"run directory {str(self.path)!r} is in use by {who} (it holds the run's lock); "
            "wait for it to end or stop it, then try again"
        )

    def remove_temp_files(self) -> None:
        """Temporary files of a writer that was killed (only call with the lock held)."""
        for folder in (self.path, self.checkpoints):
            for path in folder.iterdir() if folder.is_dir() else ():
                if is_temp_name(path.name) and path.is_file():
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
            with removed_if_created(self.path, self._forget):
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

    def _forget(self) -> None:
        """Undo a start that failed in a folder it made: its files, then its lock."""
        self.clear()
        self.remove_temp_files()
        self.unlock()

    def clear(self) -> None:
        """Delete the run's own files (nothing else that may be in the folder)."""
        for name in layout.RUN_ENTRIES:
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
        doc = documents.read_doc(self.path)
        doc.update({"config": config, **sections})
        doc["resumed"] = [*doc.get("resumed", []), environment_info()]
        self._write_doc(doc)

    def _write_doc(self, doc: dict) -> None:
        documents.write_doc(self.path, doc)

    def read_config(self) -> dict:
        config = self.read_section("config")
        if not isinstance(config, dict):
            raise ValueError(f"{self.config_yaml}: its 'config' section is not a mapping")
        return config

    def read_section(self, name: str):
        return documents.read_section(self.path, name)

    def status(self) -> str | None:
        """running | finished | interrupted | crashed (also a "running" whose process is gone)
        | unknown (status.json unreadable), or None before the first start."""
        status = read_status(self.path)
        return None if status is None else status.status

    def set_status(self, status: str, **extra) -> None:
        write_status(self.path, status, **extra)

    def set_crashed(self, exc: BaseException) -> None:
        tb = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
        self.set_status(
            "crashed", error=str(exc), traceback=tb, latest_checkpoint=self.latest_checkpoint_name()
        )

    # ------------------------------------------------------------------ checkpoints
    def write_checkpoint(self, step: int, write: Callable[[Path], None]) -> Path:
        """Let `write(folder)` fill a fresh folder, seal it with the manifest of its files'
        hashes, then publish it as `step_N` and name it in LATEST, each move atomic: a crash at
        any point leaves LATEST on a complete checkpoint."""
        final = self.checkpoints / checkpoint_name(step)
        if final.name == self.latest_checkpoint_name():
            raise ValueError(f"checkpoint {final.name} is already published")
        partial = self.checkpoints / f".partial_{final.name}"
        shutil.rmtree(partial, ignore_errors=True)
        partial.mkdir(parents=True)
        write(partial)
        write_manifest(partial)
        for file in partial.iterdir():
            fsync_path(file)
        fsync_path(partial)
        shutil.rmtree(final, ignore_errors=True)  # left by a crash between rename and LATEST
        os.replace(partial, final)
        fsync_path(self.checkpoints)
        atomic_write(self.checkpoints / layout.LATEST, final.name)
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
        return latest_name(self.checkpoints)

    def latest_checkpoint(self) -> Path:
        """The checkpoint LATEST names (ValueError when there is none)."""
        name = self.latest_checkpoint_name()
        if not name or not (self.checkpoints / name).is_dir():
            raise ValueError(self._no_checkpoint_message())
        return self.checkpoints / name

    def _no_checkpoint_message(self, why: str = "") -> str:
        return (
            f"run directory {str(self.path)!r} has no complete checkpoint to resume{why}; start "
            f"it again with acl3d train --overwrite --out {self.path} (same options), or delete it"
        )

    def resume_point(self, verify: Callable[[Path], None]) -> Path:
        """The newest checkpoint that `verify(folder)` accepts (it raises DamagedCheckpoint for
        a damaged one; other errors stop the search): LATEST's, else the previous one the run
        keeps; each one skipped is said on stderr."""
        return self._newest_intact(verify)

    def _newest_intact(self, verify: Callable[[Path], None]) -> Path:
        folders, note = resume_candidates(self.checkpoints)
        rejected = []
        for folder in folders:
            try:
                verify(folder)
            except DamagedCheckpoint as exc:
                rejected.append(f"{folder.name}: {exc}")
                continue
            said = [note] if note else []
            for line in said + [f"skipping damaged checkpoint {why}" for why in rejected]:
                print(f"[acl3d] {line}", file=sys.stderr)
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
        atomic_write(self.checkpoints / layout.LATEST, folder.name)
        fsync_path(self.checkpoints)

    # ------------------------------------------------------------------ reading back
    def best_model(self) -> Path:
        """final_model.zip, or for a run still going or crashed the model of its newest
        checkpoint whose model files match their hashes (a skipped one is said on stderr)."""
        if self.final_model.exists():
            return self.final_model
        folder = self._newest_intact(lambda f: verify_manifest(f, prefix="model"))
        return folder / "model.zip"

    def test_tasks(self):
        """The test set the run evaluated on (from its teacher dump), or None."""
        if not self.teacher_prefix.with_suffix(".json").exists():
            return None
        return read_state(self.teacher_prefix).get("test_tasks")
