"""What a campaign knows about one of its runs, read from the run directory alone.

The run directory is the single source of truth (status.json, checkpoints/, episodes.csv and
evals.csv, read through `acl3d.run_format`), so `campaign status` works from another shell and a
restarted campaign picks up exactly where the killed one stopped. The campaign adds two things to each run directory:
`campaign.log` (the run's output over all attempts) and `failures/attempt_K.txt` (the traceback
of each failed attempt).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from acl3d.run_format import layout
from acl3d.run_format.checkpoints import checkpoint_step, resume_candidates
from acl3d.run_format.status import read_status
from acl3d.run_format.tables import last_row

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
    status = read_status(run_dir) if (run_dir / layout.CONFIG_YAML).exists() else None
    name = "pending" if status is None else status.status
    checkpoint = _checkpoint_step(run_dir)
    last = last_row(run_dir / layout.EVALS)
    steps = max(int(last_row(run_dir / layout.EPISODES).get("step", 0)), checkpoint or 0)
    if name == "finished":
        steps = int(status.fields.get("steps", steps))
    return RunState(
        name=run_dir.name,
        status=name,
        steps=steps,
        total_steps=total_steps,
        failures=failure_count(run_dir),
        checkpoint_step=checkpoint,
        last_mastered_pct=last.get("mastered_pct"),
        mean_rate=last["step"] / last["wall_time_s"] if last.get("wall_time_s") else None,
        error=None if status is None else status.error,
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
    """Step of the newest checkpoint a resume would start from, or None."""
    folders, _ = resume_candidates(run_dir / layout.CHECKPOINTS)
    return checkpoint_step(folders[0].name) if folders else None
