"""Teachers compared with a baseline teacher, task by task, as TeachMyAgent's notebooks did.

Runs are grouped into cells (teacher, task), a task being the combination of the labels that
vary besides the teacher and the seed (e.g. criterion x expert knowledge). A teacher's cell is
compared with the baseline's cell of the same task; when the baseline has no run at that
expert-knowledge level it is the baseline's cell with the other labels equal (TeachMyAgent ran
Random once and reused it for every level). Evaluations are aligned by their index (the k-th
evaluation of every run), reported at the median step of that index.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from acl3d.analysis import stats
from acl3d.analysis.runs import METRICS, Run, task_keys


@dataclass
class Cell:
    teacher: str
    task: tuple
    runs: list[Run]

    def final(self, metric: str) -> np.ndarray:
        return np.array([r.metrics[metric][-1] for r in self.runs])

    def curve(self, metric: str) -> list[tuple[int, np.ndarray]]:
        """(median step, values of the runs that reached it) for every evaluation index."""
        longest = max(r.steps.size for r in self.runs)
        out = []
        for k in range(longest):
            reached = [r for r in self.runs if r.steps.size > k]
            step = int(np.median([r.steps[k] for r in reached]))
            out.append((step, np.array([r.metrics[metric][k] for r in reached])))
        return out


class Comparison:
    def __init__(self, runs: list[Run], baseline: str, metric: str = "mastered_pct"):
        if metric not in runs[0].metrics:
            raise ValueError(f"metric {metric!r} not in the runs' evaluations")
        self.metric, self.baseline = metric, baseline
        self.keys = task_keys(runs)
        cells: dict[tuple, list[Run]] = {}
        for r in runs:
            cells.setdefault((r.teacher, r.task_key(self.keys)), []).append(r)
        self.cells = {k: Cell(k[0], k[1], v) for k, v in cells.items()}
        self.teachers = sorted({t for t, _ in self.cells}, key=lambda t: (t != baseline, t))
        if baseline not in self.teachers:
            raise ValueError(
                f"baseline teacher {baseline!r} has no runs; teachers: {', '.join(self.teachers)} "
                "(choose one: baseline=..., --baseline on the command line)"
            )
        self.tasks = sorted({task for _, task in self.cells})

    # ------------------------------------------------------------------ cells
    def task_name(self, task: tuple) -> str:
        return ", ".join(f"{k}={v}" for k, v in zip(self.keys, task)) or "all"

    def tasks_of(self, teacher: str) -> list[tuple]:
        return [task for t, task in self.cells if t == teacher]

    def baseline_cell(self, task: tuple) -> Cell | None:
        if (self.baseline, task) in self.cells:
            return self.cells[(self.baseline, task)]
        if "expert_knowledge" not in self.keys:
            return None
        i = self.keys.index("expert_knowledge")
        same = [
            c
            for (t, other), c in self.cells.items()
            if t == self.baseline and other[:i] + other[i + 1 :] == task[:i] + task[i + 1 :]
        ]
        return same[0] if len(same) == 1 else None

    def paired_tasks(self, teacher: str) -> list[tuple[Cell, Cell]]:
        """(teacher cell, baseline cell) for every task both have."""
        pairs = []
        for task in self.tasks_of(teacher):
            base = self.baseline_cell(task)
            if base is not None:
                pairs.append((self.cells[(teacher, task)], base))
        return pairs

    def data_warnings(self) -> list[str]:
        """What makes these statistics meaningless or fragile, in words: every final score equal
        (nothing to rank; another metric may separate the teachers) or cells of one run."""
        notes = []
        finals = np.concatenate([cell.final(self.metric) for cell in self.cells.values()])
        if np.ptp(finals) == 0:
            other = next(m for m in METRICS if m != self.metric)
            notes.append(
                f"every run's final {self.metric} is {finals[0]:g}: the intervals, tests and "
                f"figures cannot separate the teachers; try --metric {other}"
            )
        alone = sorted(
            f"{t} ({self.task_name(task)})"
            for (t, task), c in self.cells.items()
            if len(c.runs) < 2
        )
        if alone:
            notes.append(
                f"{len(alone)} cell(s) hold a single run ({', '.join(alone[:4])}"
                f"{', ...' if len(alone) > 4 else ''}): bootstrap intervals and Welch's test need "
                "several seeds per teacher (campaign --seeds)"
            )
        return notes

    # ------------------------------------------------------------------ statistics
    def aggregates(self, reps: int, seed: int) -> list[dict]:
        """IQM and mean of final scores per teacher over its tasks, with stratified CIs."""
        rows = []
        for teacher in self.teachers:
            scores = [self.cells[(teacher, t)].final(self.metric) for t in self.tasks_of(teacher)]
            row = {"teacher": teacher, "runs": sum(s.size for s in scores), "tasks": len(scores)}
            for name, func in stats.AGGREGATES.items():
                row[name] = stats.aggregate_interval(scores, func, reps, seed)
            if teacher != self.baseline:
                pairs = self.paired_tasks(teacher)
                xs = [c.final(self.metric) for c, _ in pairs]
                ys = [b.final(self.metric) for _, b in pairs]
                if pairs and not stats.enough_runs(*xs, *ys):
                    row["P(improvement)"] = stats.INSUFFICIENT
                elif pairs:
                    row["P(improvement)"] = stats.probability_of_improvement(xs, ys, reps, seed)
            rows.append(row)
        return rows

    def final_table(self) -> list[dict]:
        """Per teacher and task: runs, mean, std, ratio to the baseline, Welch's and the
        Mann-Whitney test at the end with their Holm-adjusted p over the table's comparisons,
        and the seeds per side a t-test would need for 80% power at the observed effect (raw and
        at the table's corrected level, `with_power`)."""
        rows: list[dict] = []
        compared: list[tuple[dict, np.ndarray, np.ndarray]] = []
        for teacher in self.teachers:
            for task in self.tasks_of(teacher):
                values = self.cells[(teacher, task)].final(self.metric)
                base = self.baseline_cell(task)
                row = {
                    "teacher": teacher,
                    "task": self.task_name(task),
                    "runs": values.size,
                    "mean": float(values.mean()),
                    "std": float(values.std(ddof=1)) if values.size > 1 else float("nan"),
                }
                if base is not None and teacher != self.baseline:
                    b = base.final(self.metric)
                    row["baseline_mean"] = float(b.mean())
                    # a ratio says "x times the baseline" only for positive scores (% mastered)
                    ratio = values.mean() / b.mean() if b.mean() > 0 else float("nan")
                    row["ratio"] = float(ratio)
                    test = stats.welch(values, b)
                    row.update(t=test.t, p=test.p, significant=test.significant)
                    row["mw_p"] = stats.mann_whitney(values, b).p
                    compared.append((row, values, b))
                rows.append(row)
        with_power(compared)
        return with_holm(with_holm(rows, "p"), "mw_p")

    def welch_over_steps(self) -> list[dict]:
        """Welch's test against the baseline at every evaluation index."""
        rows = []
        for teacher in self.teachers:
            if teacher == self.baseline:
                continue
            for cell, base in self.paired_tasks(teacher):
                for (step, x), (_, y) in zip(cell.curve(self.metric), base.curve(self.metric)):
                    test = stats.welch(x, y)
                    rows.append(
                        {
                            "teacher": teacher,
                            "task": self.task_name(cell.task),
                            "step": step,
                            "mean": float(x.mean()),
                            "baseline_mean": float(y.mean()),
                            "t": test.t,
                            "p": test.p,
                            "significant": test.significant,
                        }
                    )
        return with_holm(rows, "p")

    def curves(self, reps: int, seed: int) -> list[dict]:
        """Mean over runs at every evaluation with 95% bootstrap bands, per cell."""
        rows = []
        cells = list(self.cells.items())
        for task in self.tasks:  # a task without its own baseline runs shows the reused ones
            base = self.baseline_cell(task)
            if (self.baseline, task) not in self.cells and base is not None:
                cells.append(((self.baseline, task), base))
        for (teacher, task), cell in cells:
            for step, values in cell.curve(self.metric):
                band = stats.mean_band(values, reps, seed)
                rows.append(
                    {
                        "teacher": teacher,
                        "task": self.task_name(task),
                        "step": step,
                        "runs": values.size,
                        "mean": band.point,
                        "low": band.low,
                        "high": band.high,
                    }
                )
        return rows


def with_power(compared: list[tuple[dict, np.ndarray, np.ndarray]]) -> None:
    """Sets `seeds_needed` and `seeds_needed_holm` of each (row, x, y) of a table: the runs per
    side for 80% power at the observed effect of X against Y, at 0.05 and at the level where a
    comparison passes Holm's correction over the table's Welch tests (`stats.family_alpha`).
    Claims rest on the corrected test, so the second is what a claim would need."""
    alpha = stats.family_alpha([row["p"] for row, _, _ in compared])
    for row, x, y in compared:
        row["seeds_needed"] = stats.seeds_needed(x, y)
        row["seeds_needed_holm"] = stats.seeds_needed(x, y, alpha=alpha)


def with_holm(rows: list[dict], column: str) -> list[dict]:
    """`rows` with `<column>_holm`: Holm's correction over every row holding `column` (the
    family of comparisons the table shows), and `significant_holm` for Welch's p."""
    tested = [r for r in rows if column in r]
    for row, adjusted in zip(tested, stats.holm([r[column] for r in tested])):
        row[f"{column}_holm"] = float(adjusted)
        if column == "p":
            row["significant_holm"] = bool(np.isfinite(adjusted) and adjusted < stats.ALPHA)
    return rows
