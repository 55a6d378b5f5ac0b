"""What a campaign knows about one of its runs, read from the run directory alone.

The run directory is the single source of truth (status.json, checkpoints/LATEST, episodes.csv,
evals.csv), so `campaign status` works from another shell and a restarted campaign picks up
exactly where the killed one stopped. The campaign adds two things to each run directory:
`campaign.log` (the run's output over all attempts) and `failures/attempt_K.txt` (the traceback
of each failed attempt).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

LOG_NAME = "campaign.log"
FAILURES = "failures"


@dataclass
class RunState:
    name: str
    status: str  # pending | running | finished | interrupted | crashed
    steps: int
    total_steps: int
    failures: int
    checkpoint_step: int | None  # newest complete checkpoint: where a resume starts
    last_mastered_pct: float | None
    mean_rate: float | None = None  # steps/s over the run's training wall time, at its last eval
    error: str | None = None

    @property
    def finished(self) -> bool:
        return self.status == "finished"

    @property
    def resumable(self) -> bool:
        return self.checkpoint_step is not None


def read_state(run_dir: Path, total_steps: int) -> RunState:
    run_dir = Path(run_dir)
    status: dict = {}
    if (run_dir / "status.json").exists():
        try:
            status = json.loads((run_dir / "status.json").read_text())
        except (OSError, json.JSONDecodeError):  # being replaced right now
            status = {"status": "running"}
    name = status.get("status", "pending") if (run_dir / "config.yaml").exists() else "pending"
    checkpoint = _checkpoint_step(run_dir)
    last = _last_eval(run_dir / "evals.csv")
    steps = max(_last_step(run_dir / "episodes.csv"), checkpoint or 0)
    if name == "finished":
        steps = int(status.get("steps", steps))
    return RunState(
        name=run_dir.name,
        status=name,
        steps=steps,
        total_steps=total_steps,
        failures=failure_count(run_dir),
        checkpoint_step=checkpoint,
        last_mastered_pct=last.get("mastered_pct"),
        mean_rate=last["step"] / last["wall_time_s"] if last.get("wall_time_s") else None,
        error=status.get("error"),
    )


def failure_count(run_dir: Path) -> int:
    folder = Path(run_dir) / FAILURES
    return len(list(folder.glob("attempt_*.txt"))) if folder.exists() else 0


def record_failure(run_dir: Path, text: str) -> Path:
    folder = Path(run_dir) / FAILURES
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"attempt_{failure_count(run_dir) + 1}.txt"
    path.write_text(text)
    return path


def _checkpoint_step(run_dir: Path) -> int | None:
    """Step of the newest complete checkpoint, or None."""
    pointer = run_dir / "checkpoints" / "LATEST"
    try:
        name = pointer.read_text().strip()
    except OSError:
        return None
    if not (run_dir / "checkpoints" / name / "progress.json").exists():
        return None
    try:
        return int(name.rsplit("_", 1)[-1])
    except ValueError:
        return None


def _tail_line(path: Path) -> str | None:
    """Last complete line of a text file, read from its end (episode logs grow large)."""
    try:
        with path.open("rb") as f:
            f.seek(0, os.SEEK_END)
            size = f.tell()
            f.seek(max(0, size - 4096))
            lines = f.read().decode(errors="replace").splitlines()
    except OSError:
        return None
    return lines[-1] if len(lines) > 1 else None


def _last_step(csv_path: Path) -> int:
    line = _tail_line(csv_path)
    try:
        return int(float(line.split(",", 1)[0])) if line else 0
    except ValueError:
        return 0


def _last_eval(evals_csv: Path) -> dict[str, float]:
    """The numeric cells of the newest evaluation row (empty when there is none)."""
    try:
        with evals_csv.open() as f:
            header = f.readline().strip().split(",")
    except OSError:
        return {}
    line = _tail_line(evals_csv)
    out = {}
    for name, cell in zip(header, line.split(",") if line else ()):
        try:
            out[name] = float(cell)
        except ValueError:
            pass
    return out
