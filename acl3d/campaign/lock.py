"""Exclusive locks that never outlive their holder: OS file locks (`flock`).

A `flock` is taken through a descriptor its holder keeps open; the kernel releases it when that
process exits, however it exits (SIGKILL included), so a crashed holder never leaves a stale
lock, and taking one is atomic: of any number of simultaneous attempts exactly one succeeds.
Lock files are never deleted (deleting one lets two processes lock two different files).

* the campaign directory: `DIR/.lock`, held by the campaign process (`exclusive`)
* a run's attempt: the run's `campaign.log`, held by the attempt writing it (`try_lock`)
* a run directory: the directory itself, held by the training process working in it
  (`acl3d.training`'s run directory lock); `directory_busy` looks without taking it
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import socket
import time
from collections.abc import Iterator
from contextlib import contextmanager


class LockBusy(ValueError):
    """The lock is held by another process."""


@contextmanager
def exclusive(path, what: str) -> Iterator[None]:
    """Hold the lock file `path` for the block (its directory must exist); `LockBusy` naming
    `what` and the holder (pid, host: the file says) if another process holds it."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:  # a read-only filesystem, a lock file that is a folder, ...
        raise ValueError(f"{what} cannot be locked: {exc.strerror} ({path})") from None
    try:
        if not try_lock(fd):
            raise LockBusy(f"{what} is in use by {_holder(fd)}")
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps({"pid": os.getpid(), "host": socket.gethostname()}).encode(), 0)
        yield
    finally:
        os.close(fd)  # releases the lock


def try_lock(fd: int) -> bool:
    """Take the exclusive lock of open file `fd` without waiting; False if another holds it.
    Kept until `fd` (and every descriptor duplicated from it) is closed."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        if exc.errno in (errno.EWOULDBLOCK, errno.EACCES):
            return False
        raise
    return True


def directory_busy(path) -> bool:
    """Whether a process holds the lock of directory `path` (released at once if free)."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except FileNotFoundError:
        return False
    try:
        return not try_lock(fd)
    finally:
        os.close(fd)


def _holder(fd: int, patience_s: float = 1.0) -> str:
    """Who holds the lock, as its holder wrote it. A holder writes just after taking the lock,
    so a file still empty or half-written is read again for up to `patience_s`."""
    deadline = time.monotonic() + patience_s
    while True:
        try:
            info = json.loads(os.pread(fd, 4096, 0).decode())
            return f"pid {int(info['pid'])} on {info['host']}"
        except (OSError, ValueError, KeyError, TypeError):  # not written yet, or being written
            if time.monotonic() > deadline:
                return "another process"
            time.sleep(0.01)
