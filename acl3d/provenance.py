"""Where and with what a run was produced: one segment per start or resume, in provenance.json.

Two runs of the same code on two CPU models may diverge within 50k steps (floating-point
reductions differ), by more than the gaps between teachers; results are comparable only with
their machine and versions beside them. Each time a run starts or resumes, `record` appends a
segment (acl3d version and commit, whether the tree was dirty, CPU model and count, host,
platform, Python / torch / MuJoCo / NumPy versions, the device asked for, the step it starts
from); `close` writes how the segment ended (finished, interrupted, crashed). A segment
without an end was killed. Versions are read from the installed packages' metadata, so this
module imports neither torch nor MuJoCo.
"""

from __future__ import annotations

import os
import platform
import socket
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path

from acl3d.run_format.documents import read_provenance, write_provenance

EVENTS = ("start", "resume")
ENDS = ("finished", "interrupted", "crashed")
PACKAGES = {"acl3d": "acl3d", "torch": "torch", "mujoco": "mujoco", "numpy": "numpy"}
# what must match for two runs to be expected to agree step for step
COMPARED = ("cpu_model", "python", "acl3d", "torch", "mujoco", "numpy")


def _version(package: str) -> str | None:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


def _git(*args: str) -> str | None:
    here = Path(__file__).resolve().parent
    try:
        out = subprocess.run(["git", *args], cwd=here, capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout if out.returncode == 0 else None


def cpu_model() -> str:
    """The CPU's model name (Linux: /proc/cpuinfo), else what the platform reports."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.partition(":")[2].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def collect(device: str | None = None) -> dict:
    """The facts of this process and machine (no run-specific field)."""
    commit = _git("rev-parse", "HEAD")
    status = _git("status", "--porcelain", "--untracked-files=no") if commit else None
    return {
        "acl3d": _version("acl3d"),
        "commit": commit.strip() if commit else None,
        "dirty": None if status is None else bool(status.strip()),
        "cpu_model": cpu_model(),
        "cpus": os.cpu_count(),
        "host": socket.gethostname(),
        "platform": platform.platform(),
        "python": sys.version.split()[0],
        **{name: _version(pkg) for name, pkg in PACKAGES.items() if name != "acl3d"},
        "device": device,
    }


def load(run_dir) -> list[dict] | None:
    """The segments of a run, oldest first; None for a run without provenance (shipped v1)."""
    return read_provenance(Path(run_dir))


def record(run_dir, event: str, step: int = 0, device: str | None = None) -> dict:
    """Append this process's segment to the run's provenance ("start" begins a new list)."""
    if event not in EVENTS:
        raise ValueError(f"event must be one of {list(EVENTS)}, got {event!r}")
    if isinstance(step, bool) or not isinstance(step, int) or step < 0:
        raise ValueError(f"step must be an integer >= 0, got {step!r}")
    previous = (load(run_dir) or []) if event == "resume" else []
    segment = {"event": event, "step": step, "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
               **collect(device)}  # fmt: skip
    write_provenance(Path(run_dir), [*previous, segment])
    return segment


def close(run_dir, end: str, step: int) -> None:
    """Write how the last segment ended (`end` in ENDS) and at which step."""
    if end not in ENDS:
        raise ValueError(f"end must be one of {list(ENDS)}, got {end!r}")
    segments = load(run_dir)
    if not segments:
        return
    segments[-1].update(end=end, end_step=int(step), ended=time.strftime("%Y-%m-%dT%H:%M:%S%z"))
    write_provenance(Path(run_dir), segments)


def interruptions(segments: list[dict]) -> int:
    """How many segments ended other than finished and were followed by a resume."""
    return sum(1 for s in segments[:-1] if s.get("end") != "finished")


def differences(new: list[dict] | None, reference: list[dict] | None) -> list[str]:
    """What differs between two runs' machines and versions (first segments), in words; a side
    without provenance makes every field 'unknown'."""
    if not new or not reference:
        side = "the new run" if not new else "the reference run"
        return [f"{side} records no provenance: CPU model and versions unknown"]
    a, b = new[0], reference[0]
    return [f"{k}: {a.get(k)!r} (new) vs {b.get(k)!r} (reference)" for k in COMPARED
            if a.get(k) != b.get(k)]  # fmt: skip
