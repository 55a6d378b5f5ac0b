"""A user's runs beside a reference protocol's committed runs (`analyze --reference`).

The reference is a shipped protocol's name (`acl3d.results`, e.g. "stump-v1") or a folder of
runs. Before any statistic, every new run must follow the reference's protocol: same
environment, body, environment options, task space, student and its effective
hyper-parameters, number of envs, budget (steps), evaluation schedule and policy, expert
knowledge and test set (the test tasks themselves, to 1e-6). A difference is refused with the
field named. Then the usual report (tables, IQM and mean with CIs, probability of improvement
and Welch's test against Random, performance profiles, curves) covers both, and a section
compares each new teacher with each reference teacher.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import yaml

from acl3d import provenance, results
from acl3d.analysis import stats
from acl3d.analysis.compare import with_holm, with_power
from acl3d.analysis.export import EVAL_TASK_COLUMNS, task_columns
from acl3d.analysis.report import check_options, markdown_table, write_csv, write_report
from acl3d.analysis.runs import Run, load_runs

# (field name in messages, path in config.yaml)
CONFIG_FIELDS = (
    ("env", ("config", "env")),
    ("body", ("config", "body")),
    ("env_kwargs", ("config", "env_kwargs")),
    ("student", ("config", "student")),
    ("student hyper-parameters", ("student_hyperparameters",)),
    ("n_envs", ("config", "n_envs")),
    ("budget (steps)", ("resolved", "steps")),
    ("evaluation schedule (eval_every)", ("resolved", "eval_every")),
    ("stochastic evaluation", ("config", "eval_stochastic")),
    ("expert_knowledge", ("config", "expert_knowledge")),
    ("scale_reward", ("config", "scale_reward")),
    ("shuffle_dimensions", ("config", "shuffle_dimensions")),
    ("reset_student_every", ("config", "reset_student_every")),
    ("nb_test_episodes", ("resolved", "nb_test_episodes")),
)


def reference_runs(reference: str) -> tuple[str, list[Run]]:
    """(label, runs) of a shipped protocol name or a folder of runs."""
    folder = Path(reference)
    if not folder.is_dir():
        folder = results.path(reference)  # raises naming the shipped protocols
    return folder.name, load_runs(folder)


def missing_runs(folder: Path, runs: list[Run]) -> list[str]:
    """The runs a protocol's campaign was to make that its folder lacks (a campaign exported
    before it finished): '<teacher> (k of n seeds)' per short teacher; empty without a
    protocol.yaml. Its `planned_runs` (runs per teacher, exclude rules applied) where recorded,
    else every teacher of the spec's grid times its seeds (v1's protocols)."""
    manifest = folder / "protocol.yaml"
    if not manifest.is_file():
        return []
    doc = yaml.safe_load(manifest.read_text()) or {}
    wanted = doc.get("planned_runs")
    if not wanted:
        spec = doc.get("spec") or {}
        seeds = spec.get("seeds", [])
        per_teacher = len(seeds) if isinstance(seeds, list) else int(seeds or 0)
        wanted = {name: per_teacher for name in (spec.get("grid") or {}).get("teacher") or {}}
    counts = {name: sum(r.teacher == name for r in runs) for name in wanted}
    return [f"{name} ({k} of {wanted[name]} seeds)" for name, k in counts.items()
            if k < wanted[name]]  # fmt: skip


def _get(doc: dict, keys: tuple[str, ...]):
    for key in keys:
        doc = doc.get(key) if isinstance(doc, dict) else None
    return doc


def _task_space(run: Path, config: dict):
    if "task_space" in config:
        return config["task_space"]
    teacher = run / "teacher.json"
    if teacher.exists():
        return json.loads(teacher.read_text()).get("bounds")
    return None


def _test_set(run: Path) -> tuple[list[str], np.ndarray] | None:
    """(task column names, tasks ordered by index) from test_set.csv or evals_tasks.csv."""
    source = run / "test_set.csv"
    known: tuple[str, ...] = ("task_index",)
    if not source.exists():
        source, known = run / "evals_tasks.csv", EVAL_TASK_COLUMNS
    if not source.exists():
        return None
    with source.open(newline="") as f:
        reader = csv.DictReader(f)
        names = task_columns(list(reader.fieldnames or []), known)
        first: dict[int, list[float]] = {}
        for row in reader:
            first.setdefault(int(row["task_index"]), [float(row[c]) for c in names])
    return names, np.array([first[i] for i in sorted(first)]).reshape(len(first), len(names))


def protocol_of(run: Run) -> dict:
    """The fields a run must share with the reference, read from its files."""
    config = yaml.safe_load((run.path / "config.yaml").read_text()) or {}
    fields = {name: _get(config, keys) for name, keys in CONFIG_FIELDS}
    fields["task space"] = _task_space(run.path, config)
    fields["test set"] = _test_set(run.path)
    return fields


def _same(a, b) -> bool:
    if isinstance(a, tuple) and isinstance(b, tuple):  # test sets: names, then the tasks
        return a[0] == b[0] and a[1].shape == b[1].shape and np.allclose(a[1], b[1], atol=1e-6)
    return a == b


def _shown(value) -> str:
    if isinstance(value, tuple):
        return f"{len(value[1])} tasks over {value[0]}"
    return repr(value)


def check_protocol(new: list[Run], reference: list[Run], label: str) -> None:
    """Refuse (ValueError) new runs whose protocol differs from the reference's, naming the
    field; fields a new run does not record (e.g. no teacher.json yet) are not compared."""
    expected = protocol_of(reference[0])
    for run in new:
        fields = protocol_of(run)
        for name, want in expected.items():
            have = fields[name]
            if have is None or want is None:
                continue
            if not _same(have, want):
                raise ValueError(
                    f"run {run.name!r} does not follow the reference protocol {label!r}: "
                    f"{name} is {_shown(have)}, the reference's is {_shown(want)}"
                )


def merged_runs(new: list[Run], reference: list[Run], label: str) -> list[Run]:
    """Both sets in one list; a new teacher named like a reference one gets ' (new)'."""
    taken = {r.teacher for r in reference}
    out = [dataclasses.replace(r, name=f"reference/{label}/{r.name}") for r in reference]
    for r in new:
        if r.teacher in taken:
            r = dataclasses.replace(r, labels={**r.labels, "teacher": f"{r.teacher} (new)"})
        out.append(r)
    return out


def against_each(
    new_teachers: list[str], runs: list[Run], metric: str, reps: int, seed: int
) -> list[dict]:
    """Each new teacher against each reference teacher on final scores: means, P(new > ref)
    with its bootstrap CI ("insufficient runs" below `stats.MIN_RUNS` on a side), Welch's and
    the Mann-Whitney test with Holm's correction over these comparisons, and the seeds per side
    a t-test would need for 80% power at the observed effect, raw and corrected."""
    finals: dict[str, list[float]] = {}
    for r in runs:
        finals.setdefault(r.teacher, []).append(float(r.metrics[metric][-1]))
    rows: list[dict] = []
    compared: list[tuple[dict, np.ndarray, np.ndarray]] = []
    for teacher in new_teachers:
        x = np.array(finals[teacher])
        for other in sorted(t for t in finals if t not in new_teachers):
            y = np.array(finals[other])
            test = stats.welch(x, y)
            rows.append(
                {
                    "teacher": teacher,
                    "reference": other,
                    "mean": float(x.mean()),
                    "reference_mean": float(y.mean()),
                    "difference": float(x.mean() - y.mean()),
                    "P(improvement)": (
                        stats.probability_of_improvement([x], [y], reps, seed)
                        if stats.enough_runs(x, y)
                        else stats.INSUFFICIENT
                    ),
                    "t": test.t,
                    "p": test.p,
                    "significant": test.significant,
                    "mw_p": stats.mann_whitney(x, y).p,
                }
            )
            compared.append((rows[-1], x, y))
    with_power(compared)
    return with_holm(with_holm(rows, "p"), "mw_p")


NOT_RECORDED = "not recorded"


def recorded_machine(run: Run) -> list[dict] | None:
    """A run's provenance segments; for a run without provenance.json (the shipped v1 runs) one
    segment from what its config.yaml recorded (`environment`: Python and package versions,
    commit; its CPU model was not recorded), else None."""
    segments = provenance.load(run.path)
    if segments:
        return segments
    config = yaml.safe_load((run.path / "config.yaml").read_text()) or {}
    env = config.get("environment")
    if not isinstance(env, dict):
        return None
    packages = env.get("packages") or {}
    versions = {name: packages.get(name) for name in provenance.PACKAGES}
    return [{"cpu_model": NOT_RECORDED, "python": env.get("python"), **versions,
             "commit": env.get("git_commit"), "platform": env.get("platform")}]  # fmt: skip


def machine_notes(new: list[Run], reference: list[Run], label: str) -> list[str]:
    """Where the new runs' CPU model or versions differ from the reference's (provenance.json,
    else what config.yaml recorded, `recorded_machine`; 'unknown' for runs that record neither):
    on another CPU a run of the same code may diverge by more than the teachers' gaps."""
    ref = recorded_machine(reference[0])
    notes: list[str] = []
    for run in new:
        mine = recorded_machine(run)
        diffs = provenance.differences(mine, ref)
        if mine and ref and mine[0].get("cpu_model") == ref[0].get("cpu_model") == NOT_RECORDED:
            diffs.append("cpu_model: not recorded by either run, so it may differ")
        notes += [d for d in diffs if d not in notes]
    return [f"machine and versions against the reference {label!r}: {n}" for n in notes]


def analyze_against(
    new_root,
    reference: str,
    out=None,
    metric: str = "mastered_pct",
    reps: int = stats.DEFAULT_REPS,
    seed: int = 0,
) -> Path:
    """The report of the runs under `new_root` beside the reference's (default
    NEW_ROOT/report_vs_<reference>)."""
    check_options(metric, reps)
    label, reference_set = reference_runs(reference)
    folder = Path(reference) if Path(reference).is_dir() else results.path(reference)
    missing = missing_runs(folder, reference_set)
    if missing:
        print(f"[acl3d] warning: the reference {label!r} is incomplete, its campaign was exported "
              f"before it finished: {', '.join(missing)}", file=sys.stderr, flush=True)  # fmt: skip
    new = load_runs(new_root)
    check_protocol(new, reference_set, label)
    runs = merged_runs(new, reference_set, label)
    new_teachers = sorted({r.teacher for r in runs[len(reference_set) :]})
    machine = machine_notes(new, reference_set, label)
    for note in machine:
        print(f"[acl3d] warning: {note}", file=sys.stderr, flush=True)
    rows = against_each(new_teachers, runs, metric, reps, seed)
    out = Path(out) if out is not None else Path(new_root) / f"report_vs_{label}"
    out.mkdir(parents=True, exist_ok=True)
    write_csv(rows, out / "against_each_reference.csv")
    columns = ["teacher", "reference", "mean", "reference_mean", "difference", "P(improvement)",
               "p", "p_holm", "mw_p", "mw_p_holm", "seeds_needed", "seeds_needed_holm",
               "significant_holm"]  # fmt: skip
    extra = "\n".join(
        [
            "",
            f"## Against each teacher of the reference {label!r}",
            "",
            f"Final {metric}: P(improvement) = probability that a run of the new teacher beats "
            'a run of the reference teacher (95% bootstrap CI; "insufficient runs" with fewer '
            f"than {stats.MIN_RUNS} on a side); p: Welch's t-test; mw_p: Mann-Whitney U; *_holm: "
            "Holm-adjusted over this table's comparisons (significant_holm: p_holm < 0.05); "
            f"seeds_needed: runs per side for 80% power at the observed effect at {stats.ALPHA} "
            "(seeds_needed_holm: at the level where a comparison passes this table's Holm "
            "correction, 0.05 over its number of tests).",
            "",
            markdown_table(rows, columns),
            "",
            "## Machine and versions",
            "",
            *(f"- {n}" for n in machine or ["same CPU model and versions as the reference"]),
            "",
        ]
    )
    return write_report(runs, out, "random", metric, reps, seed, extra)
