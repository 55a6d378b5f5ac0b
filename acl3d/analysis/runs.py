"""Reading the runs of a campaign (or any folder of run directories) into tidy evaluations.

A run directory is any folder under the root holding `config.yaml` and `evals.csv`. Its labels
(teacher, env, body, student, expert knowledge, seed) come from the run's own config, completed
(criterion, variant) by the `campaign.yaml` of the campaign holding it, wherever it sits under
the root (several campaigns can be analysed together). Only files are read, through
`acl3d.run_format`: this package imports nothing from training or the environments.
"""

from __future__ import annotations

import csv
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from acl3d.run_format import documents, layout
from acl3d.run_format.status import read_status
from acl3d.run_format.tables import TornTable, read_csv

CONFIG_LABELS = ("teacher", "env", "body", "student", "expert_knowledge", "seed")
# Labels that tell conditions' cells apart (the teacher is the compared condition).
TASK_LABELS = ("env", "body", "student", "criterion", "expert_knowledge")
METRICS = ("mastered_pct", "mean_return")


@dataclass
class Run:
    name: str
    path: Path
    labels: dict
    status: str
    steps: np.ndarray  # evaluation steps
    metrics: dict[str, np.ndarray] = field(default_factory=dict)  # metric -> one value per eval

    @property
    def teacher(self) -> str:
        return str(self.labels.get("teacher"))

    def task_key(self, keys: tuple[str, ...]) -> tuple:
        return tuple(str(self.labels.get(k, "")) for k in keys)


def _read_evals(path: Path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Steps and metrics of an evals.csv; a torn row or a missing column is a ValueError naming
    the file (its values are never used)."""
    cols = read_csv(path, strict=True)
    if "step" not in cols:
        raise TornTable(f"{path} has no 'step' column")
    steps = np.array(cols["step"], dtype=np.int64)
    return steps, {m: np.array(cols[m]) for m in METRICS if m in cols}


def _manifest_labels(root: Path) -> dict[Path, dict]:
    """Run directory -> labels, from every campaign manifest under `root` (campaigns may nest)."""
    labels = {}
    for manifest in root.rglob("campaign.yaml"):
        doc = yaml.safe_load(manifest.read_text()) or {}
        for run in doc.get("runs", []):
            labels[(manifest.parent / "runs" / run["name"]).resolve()] = dict(run["labels"])
    return labels


def _status(path: Path) -> str:
    status = read_status(path)
    return "unknown" if status is None else status.status


def _read_run(path: Path, name: str, labels: dict) -> Run | None:
    """The run in `path`, None when it has no evaluation yet; ValueError naming a file that
    cannot be read."""
    evals = path / layout.EVALS
    if not evals.exists():
        raise ValueError(f"{evals} is missing")
    steps, metrics = _read_evals(evals)
    if steps.size == 0:
        return None
    saved = documents.read_doc(path).get("config") or {}
    if not isinstance(saved, dict):
        raise ValueError(f"{path / layout.CONFIG_YAML}: its 'config' section is not a mapping")
    own = {k: saved.get(k) for k in CONFIG_LABELS if k in saved}
    return Run(name, path, {**own, **labels}, _status(path), steps, metrics)


def load_runs(root) -> list[Run]:
    """Every run directory under `root` with at least one evaluation, sorted by name. A run
    whose files cannot be read (a torn or missing evals.csv, a broken config.yaml) is skipped
    with a warning on stderr naming it and the file."""
    root = Path(root)
    if not root.is_dir():
        raise ValueError(f"{str(root)!r} is not a directory")
    from_manifest = _manifest_labels(root)
    runs = []
    for config in sorted(root.rglob(layout.CONFIG_YAML)):
        path = config.parent
        name = str(path.relative_to(root)) if path != root else path.name
        try:
            run = _read_run(path, name, from_manifest.get(path.resolve(), {}))
        except (OSError, ValueError) as exc:
            print(f"[acl3d] skipping run {name}: {exc}", file=sys.stderr)
            continue
        if run is not None:
            runs.append(run)
    if not runs:
        raise ValueError(f"no run directory with evaluations (evals.csv) under {str(root)!r}")
    return runs


def task_keys(runs: list[Run]) -> tuple[str, ...]:
    """The task labels that vary across runs (constant ones name no distinct cell)."""
    return tuple(k for k in TASK_LABELS if len({str(r.labels.get(k, "")) for r in runs}) > 1)


def write_tidy_csv(runs: list[Run], path: Path) -> None:
    """One row per evaluation of every run: labels, step, metrics."""
    label_keys = sorted({k for r in runs for k in r.labels})
    metrics = [m for m in METRICS if any(m in r.metrics for r in runs)]
    with Path(path).open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["run", "status", *label_keys, "eval_index", "step", *metrics])
        for r in runs:
            for i, step in enumerate(r.steps):
                writer.writerow(
                    [
                        r.name,
                        r.status,
                        *(r.labels.get(k, "") for k in label_keys),
                        i,
                        int(step),
                        *(f"{r.metrics[m][i]:.6g}" if m in r.metrics else "" for m in metrics),
                    ]
                )
