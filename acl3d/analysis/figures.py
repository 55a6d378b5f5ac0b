"""The report's figures, drawn on bare matplotlib Figures (pyplot's global state is left alone)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from acl3d.analysis import stats
from acl3d.analysis.compare import Comparison
from acl3d.teachers.plots import teacher_color

_METRIC_NAMES = {"mastered_pct": "% mastered test tasks", "mean_return": "mean test return"}
_RANGES = {"mastered_pct": (0.0, 100.0), "P(improvement)": (0.0, 1.0)}  # what a metric can be


def _save(fig: Figure, path: Path) -> Path:
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    return path


def _colors(teachers: list[str]) -> dict[str, str]:
    return {t: teacher_color(t) for t in teachers}


def _say_if_flat(ax, values, axis: str, metric: str, what: str) -> bool:
    """When every value is the same, say so on the axes over the metric's natural range (or
    +-1 around the value) instead of letting matplotlib zoom onto it (a flat line on a +-0.04
    axis reads as noise around zero); True if it did."""
    v = np.asarray([x for x in values if x is not None], float)
    v = v[np.isfinite(v)]
    if not len(v) or np.ptp(v) > 0:
        return False
    value = float(v[0])
    low, high = _RANGES.get(metric, (value - 1.0, value + 1.0))
    pad = 0.05 * (high - low)
    (ax.set_ylim if axis == "y" else ax.set_xlim)(low - pad, high + pad)
    ax.text(0.5, 0.5, what.format(value=value), transform=ax.transAxes, ha="center",
            va="center", fontsize=9, bbox={"facecolor": "white", "edgecolor": "0.6"})  # fmt: skip
    return True


def curves(comp: Comparison, rows: list[dict], path: Path) -> Path:
    """Mean score over training steps with 95% bootstrap bands, one panel per task."""
    tasks = sorted({r["task"] for r in rows})
    cols = min(3, len(tasks))
    nrows = -(-len(tasks) // cols)
    fig = Figure(figsize=(5 * cols, 3.6 * nrows))
    colors = _colors(comp.teachers)
    for i, task in enumerate(tasks):
        ax = fig.add_subplot(nrows, cols, i + 1)
        for teacher in comp.teachers:
            pts = sorted((r for r in rows if r["task"] == task and r["teacher"] == teacher),
                         key=lambda r: r["step"])  # fmt: skip
            if not pts:
                continue
            x = np.array([p["step"] for p in pts])
            ax.plot(
                x,
                [p["mean"] for p in pts],
                "o-",
                markersize=3,
                color=colors[teacher],
                label=teacher,
            )
            ax.fill_between(x, [p["low"] for p in pts], [p["high"] for p in pts],
                            color=colors[teacher], alpha=0.2, linewidth=0)  # fmt: skip
        panel = [r[k] for r in rows if r["task"] == task for k in ("mean", "low", "high")]
        name = _METRIC_NAMES.get(comp.metric, comp.metric)
        _say_if_flat(ax, panel, "y", comp.metric,
                     f"every run: {name} = {{value:g}}\nat every evaluation (no spread)")  # fmt: skip
        ax.set_title(task if len(tasks) > 1 else "mean over runs, 95% bootstrap band", fontsize=9)
        ax.set_xlabel("training steps")
        ax.set_ylabel(_METRIC_NAMES.get(comp.metric, comp.metric))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    return _save(fig, path)


def intervals(comp: Comparison, aggregates: list[dict], path: Path) -> Path:
    """IQM, mean and P(improvement) as points with their 95% CIs, one row per teacher."""
    names = ["IQM", "mean", "P(improvement)"]
    fig = Figure(figsize=(4 * len(names), 0.6 * len(aggregates) + 1.4))
    colors = _colors(comp.teachers)
    for i, name in enumerate(names):
        ax = fig.add_subplot(1, len(names), i + 1)
        rows = [r for r in aggregates if isinstance(r.get(name), stats.Interval)]  # not refused
        for y, row in enumerate(rows):
            iv = row[name]
            ax.plot([iv.low, iv.high], [y, y], color=colors[row["teacher"]], linewidth=6,
                    alpha=0.5, solid_capstyle="butt")  # fmt: skip
            ax.plot([iv.point], [y], "|", color="black", markersize=14)
        ax.set_yticks(range(len(rows)), [r["teacher"] for r in rows] if i == 0 or rows else [])
        ax.set_ylim(-0.7, max(len(rows), 1) - 0.3)
        values = [x for r in rows for x in (r[name].low, r[name].point, r[name].high)]
        if name == "P(improvement)":
            ax.axvline(0.5, color="gray", linestyle="--", linewidth=1)
            ax.set_title(f"P({comp.baseline} < teacher)")
            _say_if_flat(ax, values, "x", name, "{value:g} for every teacher:\nall runs tie")
        else:
            ax.set_title(f"{name} of final {_METRIC_NAMES.get(comp.metric, comp.metric)}")
            _say_if_flat(ax, values, "x", comp.metric, "{value:g} for every teacher\n(no spread)")
        ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    return _save(fig, path)


def performance_profiles(comp: Comparison, reps: int, seed: int, path: Path) -> Path:
    """Fraction of runs whose final score exceeds tau, with 95% bootstrap bands."""
    finals = [c.final(comp.metric) for c in comp.cells.values()]
    top = max(float(np.max(f)) for f in finals)
    low = min(0.0, min(float(np.min(f)) for f in finals))
    taus = np.linspace(low, max(top, low + 1e-9), 101)
    fig = Figure(figsize=(6, 4))
    ax = fig.add_subplot(1, 1, 1)
    colors = _colors(comp.teachers)
    for teacher in comp.teachers:
        scores = [comp.cells[(teacher, t)].final(comp.metric) for t in comp.tasks_of(teacher)]
        point, lo, hi = stats.performance_profile(scores, taus, reps=min(reps, 2000), seed=seed)
        ax.plot(taus, point, color=colors[teacher], label=teacher)
        ax.fill_between(taus, lo, hi, color=colors[teacher], alpha=0.2, linewidth=0)
    name = _METRIC_NAMES.get(comp.metric, comp.metric)
    _say_if_flat(ax, np.concatenate(finals), "x", comp.metric,
                 f"every run's final {name} = {{value:g}}")  # fmt: skip
    ax.set_xlabel(f"final {name} (tau)")
    ax.set_ylabel("fraction of runs with score > tau")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    return _save(fig, path)


def radar(comp: Comparison, path_prefix: Path) -> list[Path]:
    """Each teacher's mean final score per criterion over the baseline's, one chart per EK level.

    Only when the runs carry at least three criteria (a radar needs three axes).
    """
    if "criterion" not in comp.keys:
        return []
    ci = comp.keys.index("criterion")
    criteria = sorted({task[ci] for task in comp.tasks})
    if len(criteria) < 3:
        return []
    ek_i = comp.keys.index("expert_knowledge") if "expert_knowledge" in comp.keys else None
    levels = sorted({task[ek_i] for task in comp.tasks}) if ek_i is not None else [None]
    colors = _colors(comp.teachers)
    angles = np.linspace(0, 2 * np.pi, len(criteria), endpoint=False)
    paths = []
    for level in levels:
        fig = Figure(figsize=(6, 6))
        ax = fig.add_subplot(1, 1, 1, projection="polar")
        ax.plot(np.append(angles, angles[0]), np.ones(len(criteria) + 1), color="black",
                linestyle="--", label=f"{comp.baseline} (= 1)")  # fmt: skip
        for teacher in comp.teachers:
            if teacher == comp.baseline:
                continue
            ratios = []
            for criterion in criteria:
                pairs = [(c, b) for c, b in comp.paired_tasks(teacher) if c.task[ci] == criterion
                         and (ek_i is None or c.task[ek_i] == level)]  # fmt: skip
                mine = np.concatenate([c.final(comp.metric) for c, _ in pairs]) if pairs else []
                base = np.concatenate([b.final(comp.metric) for _, b in pairs]) if pairs else []
                ok = len(mine) and np.mean(base) > 0
                ratios.append(float(np.mean(mine) / np.mean(base)) if ok else np.nan)
            values = np.append(ratios, ratios[0])
            ax.plot(np.append(angles, angles[0]), values, color=colors[teacher], label=teacher)
        ax.set_xticks(angles, criteria, fontsize=8)
        title = f"final {comp.metric} / {comp.baseline}'s"
        ax.set_title(title + (f", expert knowledge {level}" if level is not None else ""))
        ax.legend(loc="upper right", bbox_to_anchor=(1.35, 1.1), fontsize=8)
        suffix = f"_ek-{level}" if level is not None else ""
        paths.append(_save(fig, path_prefix.with_name(f"{path_prefix.name}{suffix}.png")))
    return paths
