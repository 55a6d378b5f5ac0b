"""A finished campaign's runs in the compact form committed as reference results.

Per run (see `acl3d.results`): the config without local paths plus the task space, evaluations
overall and per test task, the test set once, the training episodes summarised in
`SUMMARY_WINDOWS` windows of the budget, and what lets others check the curriculum
(`acl3d.analysis.curriculum_files`: every episode in episodes.npz, the teacher's dump in
teacher.json/.npz, each within a byte budget) with the run's provenance.json; no models,
checkpoints or TensorBoard logs. `protocol.yaml` records the campaign spec, the hardware and
software versions of the runs, and the bytes shipped.
"""

from __future__ import annotations

import csv
import datetime
import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import yaml

from acl3d import provenance
from acl3d.analysis.curriculum_files import shipped_bytes, write_episodes, write_teacher
from acl3d.analysis.runs import load_runs
from acl3d.run_format import layout

SUMMARY_WINDOWS = 20
EVAL_TASK_COLUMNS = ("step", "task_index", "return", "length", "success")


def _read_csv(path: Path) -> tuple[list[str], list[dict]]:
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        return list(reader.fieldnames or []), list(reader)


def _write_rows(path: Path, columns, rows) -> None:
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(columns)
        writer.writerows(rows)


def task_columns(columns: list[str], known: tuple[str, ...]) -> list[str]:
    """The task-vector columns of a run CSV (every column that is not a known field)."""
    return [c for c in columns if c not in known]


def _config(run: Path) -> dict:
    doc = yaml.safe_load((run / "config.yaml").read_text()) or {}
    doc.get("config", {}).pop("out", None)
    doc.get("environment", {}).pop("command", None)
    teacher_file = run / "teacher.json"
    if teacher_file.exists():
        saved = json.loads(teacher_file.read_text())
        doc["task_space"] = saved.get("bounds")
    return doc


def _eval_tasks(run: Path, dest: Path) -> None:
    columns, rows = _read_csv(run / "evals_tasks.csv")
    tasks = task_columns(columns, EVAL_TASK_COLUMNS)
    _write_rows(
        dest / "evals_tasks.csv",
        EVAL_TASK_COLUMNS,
        ([r[c] for c in EVAL_TASK_COLUMNS] for r in rows),
    )
    first = {}
    for r in rows:
        first.setdefault(int(r["task_index"]), [r[c] for c in tasks])
    _write_rows(
        dest / "test_set.csv", ["task_index", *tasks], ([i, *v] for i, v in sorted(first.items()))
    )


def _episodes_summary(run: Path, steps: int, dest: Path) -> None:
    columns, rows = _read_csv(run / "episodes.csv")
    tasks = task_columns(columns, ("step", "worker", "return", "length", "success", "truncated"))
    header = ["step_end", "episodes", "mean_return", "std_return", "mean_length", "success_rate"]
    header += [f"mean_{c}" for c in tasks]
    edges = np.linspace(0, steps, SUMMARY_WINDOWS + 1)
    if rows:
        step = np.array([float(r["step"]) for r in rows])
        values = {k: np.array([float(r[k]) for r in rows]) for k in ("return", "length", "success")}
        task_values = np.array([[float(r[c]) for c in tasks] for r in rows]).reshape(len(rows), -1)
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        inside = (step > lo) & (step <= hi) if rows else np.zeros(0, dtype=bool)
        n = int(inside.sum())
        if n == 0:
            out.append([int(hi), 0, *[""] * (len(header) - 2)])
            continue
        r = values["return"][inside]
        out.append(
            [int(hi), n, f"{r.mean():.6g}", f"{r.std():.6g}", f"{values['length'][inside].mean():.6g}",
             f"{values['success'][inside].mean():.4g}",
             *(f"{v:.6g}" for v in task_values[inside].mean(axis=0))]
        )  # fmt: skip
    _write_rows(dest / "episodes_summary.csv", header, out)


def _curriculum_files(run: Path, dest: Path) -> dict[str, dict]:
    """Episodes, teacher dump and provenance of `run` into `dest`; {name: strides} where a
    budget thinned a file (every k-th episode kept; {path: k} of the teacher's histories)."""
    if (run / layout.PROVENANCE).exists():
        shutil.copyfile(run / layout.PROVENANCE, dest / layout.PROVENANCE)
    strides = {}
    episodes, teacher = write_episodes(run, dest), write_teacher(run, dest)
    if episodes is not None and episodes["every"] > 1:
        strides["episodes"] = episodes["every"]
    if teacher is not None and teacher["every"]:
        strides["teacher"] = teacher["every"]
    return {dest.name: strides} if strides else {}


def export_campaign(
    campaign_dir, out, protocol: str, planned_labels=None, add: bool = False, spec=None
) -> list[str]:
    """Write the finished runs under `campaign_dir` into `out` in the committed form; returns
    the exported run names. Unfinished runs are left out (named in protocol.yaml), and so are
    the runs it planned: `planned_labels` (every planned run's labels, e.g. the protocol's
    whole spec for a campaign run a few cells at a time), else its manifest's runs.

    `spec`: the campaign spec recorded (default: the manifest's). `add`: keep the runs already
    exported in `out` that this campaign did not finish, so a protocol grows across machines
    and sessions a few cells at a time; refused unless `out` is an export of `protocol`. The
    caller checks that both ran one spec and passes the spec of both (`acl3d campaign export
    --add` does, with `acl3d.campaign.runner.merged_spec`)."""
    if not isinstance(protocol, str) or not protocol or os.sep in protocol:
        raise ValueError(f"protocol must be a name like 'stump-v1', got {protocol!r}")
    root, out = Path(campaign_dir), Path(out)
    runs = load_runs(root)
    finished = [r for r in runs if r.status == "finished"]
    if not finished:
        raise ValueError(f"no finished run under {str(root)!r} ({len(runs)} unfinished)")
    names = [r.path.name for r in finished]
    if len(set(names)) != len(names):
        raise ValueError(f"run folder names repeat under {str(root)!r}: they name the exports")
    manifest = next(root.rglob("campaign.yaml"), None)
    campaign = (yaml.safe_load(manifest.read_text()) or {}) if manifest else {}
    earlier = earlier_export(out, protocol) if add else {}
    kept = [name for name in earlier.get("runs", []) if name not in names]
    out.parent.mkdir(parents=True, exist_ok=True)
    # built whole beside `out`, then swapped in: a failure on the way leaves `out` as it was
    with tempfile.TemporaryDirectory(dir=out.parent, prefix=f".{out.name}-") as stage:
        new = Path(stage) / "export"
        new.mkdir()
        for name in kept:
            shutil.copytree(out / name, new / name)
        thinned = {k: v for k, v in (earlier.get("thinned") or {}).items() if k in kept}
        for run in finished:
            thinned.update(_export_run(run.path, new / run.path.name))
        if planned_labels is None:
            planned_labels = [entry.get("labels") or {} for entry in campaign.get("runs", [])]
        planned: dict[str, int] = {}  # runs per teacher the campaign was to make (after exclude)
        for labels in planned_labels:
            teacher = str(labels.get("teacher"))
            planned[teacher] = planned.get(teacher, 0) + 1
        for teacher, count in (earlier.get("planned_runs") or {}).items():
            planned[teacher] = max(planned.get(teacher, 0), count)
        # a run not finished: one with evaluations, or one planned that has none yet
        left_out = {r.path.name for r in runs if r.status != "finished"}
        left_out |= {str(entry["name"]) for entry in campaign.get("runs", [])}
        left_out = (left_out | set(earlier.get("left_out") or [])) - set(names + kept)
        doc = {
            "protocol": protocol,
            "exported": datetime.date.today().isoformat(),
            "runs": names + kept,
            "left_out": sorted(left_out),
            **_runs_record(new, names + kept),
            "thinned": thinned,
            "planned_runs": planned,
            "spec": campaign.get("spec") if spec is None else spec,
        }
        (new / "protocol.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
        if out.exists():
            out.rename(Path(stage) / "replaced")
        new.rename(out)
    return names + kept


def _runs_record(folder: Path, names: list[str]) -> dict:
    """protocol.yaml's record of the runs exported in `folder` (machines, versions, resumes,
    bytes), read from their exported config.yaml and provenance.json, so that runs kept from
    an earlier export count as the new ones do."""
    environments, machines = [], set()
    resumed: dict[str, int] = {}  # run -> times it was interrupted and resumed
    dirty: list[str] = []  # runs with a segment started from a tree with uncommitted changes
    for name in sorted(names):
        config = yaml.safe_load((folder / name / "config.yaml").read_text()) or {}
        environments.append(config.get("environment", {}))
        segments = provenance.load(folder / name) or []
        for segment in segments:
            machines.add(f"{segment.get('cpu_model')} · {segment.get('device')}")
        if provenance.interruptions(segments):
            resumed[name] = provenance.interruptions(segments)
        if any(segment.get("dirty") for segment in segments):
            dirty.append(name)
    return {
        "hardware": {
            "platform": sorted({e.get("platform", "?") for e in environments}),
            "python": sorted({e.get("python", "?") for e in environments}),
            "runs_on": sorted(machines),  # CPU model · device of every run segment (provenance)
            "exported_on": {"cpus": os.cpu_count(), "cpu_model": provenance.cpu_model()},
        },
        "packages": environments[0].get("packages", {}),
        "git_commits": sorted({str(e.get("git_commit")) for e in environments}),
        "resumed": resumed,  # from each run's provenance.json: reviewers see them at a glance
        "dirty_tree": dirty,
        "bytes": shipped_bytes(folder),  # the runs' files, before protocol.yaml
    }


def _export_run(run: Path, dest: Path) -> dict[str, dict]:
    """One finished run in the committed form; returns what its budgets thinned."""
    dest.mkdir()
    config = _config(run)
    (dest / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    shutil.copyfile(run / "evals.csv", dest / "evals.csv")
    shutil.copyfile(run / "status.json", dest / "status.json")
    _eval_tasks(run, dest)
    steps = int(config.get("resolved", {}).get("steps") or config["config"]["steps"])
    _episodes_summary(run, steps, dest)
    return _curriculum_files(run, dest)


def earlier_export(out, protocol: str) -> dict:
    """The protocol.yaml of the export in `out` that runs are added to, checked to be one of
    `protocol`."""
    out = Path(out)
    doc_path = out / "protocol.yaml"
    if not doc_path.exists():
        raise ValueError(f"add: {str(out)!r} holds no export to add runs to (no protocol.yaml)")
    doc = yaml.safe_load(doc_path.read_text()) or {}
    if doc.get("protocol") != protocol:
        raise ValueError(
            f"add: {str(out)!r} is an export of protocol {doc.get('protocol')!r}, not {protocol!r}"
        )
    return doc
