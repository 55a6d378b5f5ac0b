"""RUN/status.json: what the run is doing, as its writer last said, checked against the process.

A writer that dies without a word (SIGKILL, an out-of-memory kill, a full disk that refused its
last status) leaves "running" behind. `read_status` therefore checks the recorded process: a
"running" run whose process no longer exists on this host is reported as crashed. A status
written on another host (a cluster node) cannot be checked and is reported as written.
"""

from __future__ import annotations

import json
import os
import socket
from dataclasses import dataclass, field
from pathlib import Path

from acl3d.atomic_files import atomic_write
from acl3d.run_format.layout import STATUS

STATUSES = ("running", "finished", "interrupted", "crashed")


@dataclass(frozen=True)
class Status:
    status: str  # one of STATUSES, or "unknown" when status.json cannot be read
    error: str | None = None
    fields: dict = field(default_factory=dict)  # everything status.json holds, as written


def write_status(run: Path, status: str, **extra) -> None:
    """Replace RUN/status.json whole; the writer's pid and host are recorded with it."""
    if status not in STATUSES:
        raise ValueError(f"status={status!r}; valid: one of {', '.join(STATUSES)}")
    doc = {"status": status, "pid": os.getpid(), "host": socket.gethostname(), **extra}
    atomic_write(Path(run) / STATUS, json.dumps(doc, indent=2))


def read_status(run: Path) -> Status | None:
    """The run's status, None before its first start; "running" with a dead process is
    reported as "crashed" (see the module docstring)."""
    path = Path(run) / STATUS
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        return Status("unknown", f"{path} cannot be read: {exc}")
    if not isinstance(doc, dict) or doc.get("status") not in STATUSES:
        return Status("unknown", f"{path} holds no valid status (was it edited?)")
    if doc["status"] == "running" and _process_ended(doc.get("pid"), doc.get("host")):
        why = (
            f"process {doc['pid']} ended without recording how (killed, or its disk was full); "
            "resume the run to continue from its last checkpoint"
        )
        return Status("crashed", why, doc)
    return Status(doc["status"], doc.get("error"), doc)


def _process_ended(pid, host) -> bool:
    """Whether process `pid` of `host` (this host when not recorded) is known to have ended."""
    if not isinstance(pid, int) or pid <= 0 or (host is not None and host != socket.gethostname()):
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # alive, another user's
        return False
    return _zombie(pid)


def _zombie(pid: int) -> bool:
    """An ended child its parent has not reaped yet still answers kill(pid, 0)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[-1].split()[:1] == ["Z"]
