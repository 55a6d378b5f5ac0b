"""Files that a crash, a full disk or an interrupt can never leave half written.

Every file other than an append-only log is written to a temporary name in its own folder,
fsynced and renamed over its target, so a reader sees the old or the new file, never a mix.
Temporary names are recognisable (`is_temp_name`) so the next writer can remove those a killed
one left. A small write is also shielded from SIGINT/SIGTERM: a second Ctrl-C (a campaign
stopping its children) cannot cut a status write in half; the signal is delivered right after.
"""

from __future__ import annotations

import errno
import os
import re
import signal
import threading
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

_HELD_SIGNALS = (signal.SIGINT, signal.SIGTERM)


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


def temp_path(path: Path) -> Path:
    """The temporary name `path` is written under before it replaces `path`."""
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def temp_prefix(prefix: Path) -> Path:
    """For files written as PREFIX + suffix(es): `_NAME_PID_tmp` + the same suffixes."""
    return prefix.with_name(f"_{prefix.name}_{os.getpid()}_tmp")


_TEMP_NAME = re.compile(r"^(\..+\.\d+\.tmp|_.+_\d+_tmp(\.\w+)?)$")  # what the two above make


def is_temp_name(name: str) -> bool:
    """Whether `name` is one `temp_path` or `temp_prefix` makes (a user's `.notes.tmp` is not)."""
    return _TEMP_NAME.match(name) is not None


@contextmanager
def removed_on_failure(*paths: Path):
    """Temporary files that must not outlive a failed write (a full disk, an interrupt)."""
    try:
        yield
    except BaseException:
        for path in paths:
            path.unlink(missing_ok=True)
        raise


@contextmanager
def signals_held():
    """Hold SIGINT and SIGTERM until the block ends, then deliver them to their handlers. Only
    the main thread receives signals; elsewhere, or where a handler was not installed from
    Python, the block runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.getsignal(sig) for sig in _HELD_SIGNALS}
    if any(handler is None for handler in previous.values()):
        yield
        return
    pending: list[int] = []
    for sig in _HELD_SIGNALS:
        signal.signal(sig, lambda signum, frame: pending.append(signum))
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        for sig in dict.fromkeys(pending):
            signal.raise_signal(sig)


def atomic_write(path: Path, text: str) -> None:
    """Replace `path` by `text`, whole or not at all, even if interrupted meanwhile."""
    tmp = temp_path(path)
    with signals_held(), removed_on_failure(tmp):
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


@contextmanager
def removed_if_created(path: Path, empty: Callable[[], None]):
    """Make the folder `path` (and missing parents) for the block. If the block fails and the
    folder was made here, `empty()` removes what the block wrote and the folders made are
    removed again: a failed start leaves no empty directory behind."""
    path = Path(path)
    made = []
    missing = path
    while not missing.exists() and missing != missing.parent:
        made.append(missing)
        missing = missing.parent
    path.mkdir(parents=True, exist_ok=True)
    try:
        yield
    except BaseException:
        if made:
            empty()
        for folder in made:
            try:
                folder.rmdir()
            except OSError:  # not empty: something else lives there now
                break
        raise
