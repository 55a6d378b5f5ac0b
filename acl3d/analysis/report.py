"""`analyze(root, out)`: tidy CSV, statistics tables, figures and a Markdown report.

OUT/evaluations.csv        every evaluation of every run (labels, step, metrics)
OUT/final_scores.csv       per teacher x task: runs, mean, std, ratio to baseline, Welch and
                           Mann-Whitney p (raw and Holm-adjusted), seeds needed for 80% power
OUT/aggregates.csv         per teacher: IQM, mean, P(improvement) with 95% CIs
OUT/welch_over_steps.csv   Welch's test against the baseline at every evaluation
OUT/curves.csv             mean and 95% bootstrap band at every evaluation, per cell
OUT/*.png, OUT/report.md   figures and the report linking them
"""

from __future__ import annotations

import csv
import math
import sys
from pathlib import Path

from acl3d.analysis import figures, stats
from acl3d.analysis.compare import Comparison
from acl3d.analysis.runs import METRICS, Run, load_runs, write_tidy_csv
from acl3d.analysis.stats import DEFAULT_REPS, Interval

_MAX_MARKDOWN_ROWS = 60


def _cell(value) -> str:
    if isinstance(value, Interval):
        return str(value)
    if isinstance(value, float):
        return "" if math.isnan(value) else f"{value:.4g}"
    return str(value)


def write_csv(rows: list[dict], path: Path) -> None:
    columns: list[str] = []
    for row in rows:
        columns += [k for k in row if k not in columns]
    flat_cols = []
    for c in columns:
        if any(isinstance(r.get(c), Interval) for r in rows):
            flat_cols += [c, f"{c}_low", f"{c}_high"]
        else:
            flat_cols.append(c)
    with path.open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(flat_cols)
        for row in rows:
            out = []
            for c in columns:
                v = row.get(c, "")
                if any(isinstance(r.get(c), Interval) for r in rows):
                    out += [v.point, v.low, v.high] if isinstance(v, Interval) else ["", "", ""]
                else:
                    out.append(v)
            writer.writerow(out)


def markdown_table(rows: list[dict], columns: list[str]) -> str:
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    for row in rows:
        lines.append("| " + " | ".join(_cell(row.get(c, "")) for c in columns) + " |")
    return "\n".join(lines)


MAX_REPS = 200_000  # bootstrap replicates: (reps x runs) index and score arrays in memory


def check_options(metric: str, reps: int) -> None:
    if metric not in METRICS:
        raise ValueError(f"metric {metric!r} unknown; valid: {', '.join(METRICS)}")
    if isinstance(reps, bool) or not isinstance(reps, int) or not 100 <= reps <= MAX_REPS:
        raise ValueError(f"reps={reps!r}; valid: an integer in [100, {MAX_REPS}]")


def analyze(
    root,
    out=None,
    baseline: str = "random",
    metric: str = "mastered_pct",
    reps: int = DEFAULT_REPS,
    seed: int = 0,
) -> Path:
    """Write the report of the runs under `root` into `out` (default ROOT/report)."""
    check_options(metric, reps)
    out = Path(out) if out is not None else Path(root) / "report"
    return write_report(load_runs(root), out, baseline, metric, reps, seed)


def write_report(
    runs: list[Run],
    out: Path,
    baseline: str = "random",
    metric: str = "mastered_pct",
    reps: int = DEFAULT_REPS,
    seed: int = 0,
    extra: str = "",
) -> Path:
    """The report of `runs` into `out`; `extra` (Markdown) is appended to report.md."""
    comp = Comparison(runs, baseline, metric)
    notes = comp.data_warnings()
    for note in notes:  # before the bootstrap, which may take a while
        print(f"[acl3d] warning: {note}", file=sys.stderr, flush=True)
    out.mkdir(parents=True, exist_ok=True)

    write_tidy_csv(runs, out / "evaluations.csv")
    aggregates = comp.aggregates(reps, seed)
    final = comp.final_table()
    over_steps = comp.welch_over_steps()
    curve_rows = comp.curves(reps, seed)
    for rows, name in ((final, "final_scores"), (aggregates, "aggregates"),
                       (over_steps, "welch_over_steps"), (curve_rows, "curves")):  # fmt: skip
        write_csv(rows, out / f"{name}.csv")
    pngs = [
        figures.curves(comp, curve_rows, out / f"curves_{metric}.png"),
        figures.intervals(comp, aggregates, out / "aggregates.png"),
        figures.performance_profiles(comp, reps, seed, out / "performance_profile.png"),
        *figures.radar(comp, out / "radar"),
    ]
    report = _report(comp, runs, aggregates, final, over_steps, pngs, reps)
    if notes:
        title, _, rest = report.partition("\n")
        report = "\n".join([title, "", *(f"> **Warning**: {n}" for n in notes), rest])
    (out / "report.md").write_text(report + extra)
    return out


def _steps_section(rows: list[dict], columns: list[str]) -> str:
    if not rows:
        return "(no teacher shares a task with the baseline)"
    if len(rows) <= _MAX_MARKDOWN_ROWS:
        return markdown_table(rows, columns)
    shown = [r for r in rows if r["significant_holm"]][:_MAX_MARKDOWN_ROWS]
    return (
        f"{len(rows)} tests; the {len(shown)} first significant ones below, all of them in "
        f"`welch_over_steps.csv`.\n\n" + markdown_table(shown, columns)
    )


def _report(comp, runs, aggregates, final, over_steps, pngs, reps) -> str:
    done = sum(r.status == "finished" for r in runs)
    agg_cols = ["teacher", "runs", "tasks", "IQM", "mean", "P(improvement)"]
    fin_cols = ["teacher", "task", "runs", "mean", "std", "baseline_mean", "ratio", "p",
                "p_holm", "mw_p", "mw_p_holm", "seeds_needed", "seeds_needed_holm",
                "significant_holm"]  # fmt: skip
    step_cols = ["teacher", "task", "step", "mean", "baseline_mean", "p", "p_holm",
                 "significant_holm"]  # fmt: skip
    parts = [
        f"# Campaign report: {comp.metric} against {comp.baseline}",
        "",
        f"{len(runs)} runs ({done} finished; unfinished runs count with their last "
        f"evaluation), teachers: {', '.join(comp.teachers)}; tasks: "
        f"{'; '.join(comp.task_name(t) for t in comp.tasks)}.",
        "",
        "## Final scores: aggregates with stratified-bootstrap 95% CIs",
        "",
        f"IQM and mean of the final {comp.metric} pooled over runs and tasks; P(improvement) = "
        f"probability that a run of the teacher beats a run of {comp.baseline} on the same task "
        f"(rliable's definitions, {reps} bootstrap replicates); "
        f'"{stats.INSUFFICIENT}" where a side has fewer than {stats.MIN_RUNS} runs.',
        "",
        markdown_table(aggregates, agg_cols),
        "",
        f"## Per task, against {comp.baseline}",
        "",
        "p: Welch's t-test; mw_p: Mann-Whitney U (two-sided, exact without ties); *_holm: "
        "Holm-adjusted over every comparison of this table; significant_holm: p_holm < 0.05 "
        "(only these support a claim); seeds_needed: runs per side for a t-test to reach 80% "
        "power at the observed effect at 0.05 (inf: no effect); seeds_needed_holm: the same at "
        "0.05 over the number of comparisons, where a p passes the Holm correction whatever the "
        "others' (what a claim needs).",
        "",
        markdown_table(final, fin_cols),
        "",
        "## Welch's t-test at every evaluation",
        "",
        "p_holm: Holm-adjusted over every test of this section.",
        "",
        _steps_section(over_steps, step_cols),
        "",
        "## Figures",
        "",
        *(f"![{p.stem}]({p.name})" for p in pngs),
        "",
    ]
    return "\n".join(parts)
