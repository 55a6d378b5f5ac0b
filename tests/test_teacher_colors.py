"""One colour per teacher in every figure, and figures that say so when their data is flat."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from matplotlib.colors import to_rgb

from acl3d.analysis import figures
from acl3d.analysis.compare import Comparison
from acl3d.analysis.runs import Run
from acl3d.teachers import TEACHERS
from acl3d.teachers.plots import OTHER_COLORS, TEACHER_COLORS, teacher_color


def test_every_shipped_teacher_has_its_own_colour():
    assert set(TEACHER_COLORS) == set(TEACHERS)
    colours = [to_rgb(c) for c in (*TEACHER_COLORS.values(), *OTHER_COLORS)]
    assert len(set(colours)) == len(colours)  # no two teachers alike, nor a fallback like them


def test_a_teacher_of_ones_own_gets_a_stable_colour_no_shipped_teacher_has():
    colour = teacher_color("my-teacher")
    assert colour == teacher_color("my-teacher") and colour in OTHER_COLORS


def _runs(values: dict[str, list[list[float]]], metric: str) -> list[Run]:
    """Runs of each teacher (one list of evaluation values per seed), 3 evaluations each."""
    return [
        Run(
            f"{t}-{s}",
            Path("."),
            {"teacher": t, "seed": s},
            "done",
            np.array([100, 200, 300]),
            {metric: np.asarray(v, float)},
        )  # fmt: skip
        for t, seeds in values.items()
        for s, v in enumerate(seeds)
    ]


def _drawn(path: Path, monkeypatch) -> list:
    """The axes figures.curves drew (kept from the Figure before it is saved)."""
    kept = []
    monkeypatch.setattr(figures, "_save", lambda fig, p: kept.extend(fig.axes) or p)
    return kept


def test_curves_draw_each_teacher_in_its_colour(tmp_path, monkeypatch):
    comp = Comparison(
        _runs({"random": [[0, 5, 10]], "setter-solver": [[1, 2, 30]]}, "mastered_pct"), "random"
    )
    axes = _drawn(tmp_path, monkeypatch)
    figures.curves(comp, comp.curves(50, 0), tmp_path / "c.png")
    lines = {line.get_label(): line.get_color() for line in axes[0].get_lines()}
    assert lines == {t: TEACHER_COLORS[t] for t in ("random", "setter-solver")}
    assert not axes[0].texts  # real spread: nothing to say


@pytest.mark.parametrize(
    "metric, value, ylim", [("mastered_pct", 0.0, (-5.0, 105.0)), ("mean_return", -20.0, None)]
)
def test_flat_data_says_so_on_a_readable_axis(tmp_path, monkeypatch, metric, value, ylim):
    flat = [[value] * 3] * 3  # 3 runs a side: P(improvement) is not refused
    comp = Comparison(_runs({"random": flat, "alp-gmm": flat}, metric), "random", metric)
    axes = _drawn(tmp_path, monkeypatch)
    figures.curves(comp, comp.curves(50, 0), tmp_path / "c.png")
    figures.intervals(comp, comp.aggregates(50, 0), tmp_path / "i.png")
    curve, *panels = axes
    low, high = curve.get_ylim()
    assert high - low >= 2.0  # not matplotlib's +-0.04 around the value
    if ylim is not None:
        assert (low, high) == pytest.approx(ylim)
    assert "no spread" in curve.texts[0].get_text() and f"{value:g}" in curve.texts[0].get_text()
    assert all(ax.texts for ax in panels)  # IQM, mean and P(improvement) say it too
