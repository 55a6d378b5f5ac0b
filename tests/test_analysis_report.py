"""`acl3d analyze` on synthetic run directories: tidy CSV, Welch tests per step and at the end,
the baseline reused across expert-knowledge levels, radar charts, the report."""

import csv
import json
import shutil

import numpy as np
import pytest
import yaml
from scipy import stats as sps

from acl3d.analysis import analyze
from acl3d.cli import main

CRITERIA = ("mostly-unfeasible", "mostly-trivial", "rugged-difficulty")
STEPS = (1000, 2000, 3000)


def _write_run(root, name, labels, mastered):
    run = root / "runs" / name
    run.mkdir(parents=True)
    config = {k: labels[k] for k in ("teacher", "expert_knowledge", "seed")}
    (run / "config.yaml").write_text(yaml.safe_dump({"config": {"env": "stump-tracks", **config}}))
    (run / "status.json").write_text(json.dumps({"status": "finished"}))
    with (run / "evals.csv").open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["step", "episodes", "mastered_pct", "mean_return"])
        for step, value in zip(STEPS, mastered):
            writer.writerow([step, 10, value, value * 3 - 100])


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    """Random at one level only; alp-gmm better than it on every criterion, at two levels."""
    root = tmp_path_factory.mktemp("campaign")
    rng = np.random.default_rng(0)
    runs, finals = [], {}
    for criterion in CRITERIA:
        for teacher, levels, base in (
            ("random", ["low"], 10.0),
            ("alp-gmm", ["low", "high"], 30.0),
        ):
            for ek in levels:
                for seed in range(4):
                    final = base + rng.integers(0, 10) + 5 * CRITERIA.index(criterion)
                    finals.setdefault((teacher, criterion, ek), []).append(final)
                    name = f"{teacher}__{criterion}__ek-{ek}__s{seed}"
                    labels = {"teacher": teacher, "criterion": criterion,
                              "expert_knowledge": ek, "seed": seed}  # fmt: skip
                    _write_run(root, name, labels, [0, final / 2, final])
                    runs.append({"name": name, "labels": labels, "options": {}})
    (root / "campaign.yaml").write_text(yaml.safe_dump({"spec": {"name": "t"}, "runs": runs}))
    report = analyze(root, reps=500)
    return root, report, finals


def _rows(path):
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def test_tidy_evaluations_csv(campaign):
    root, report, _ = campaign
    rows = _rows(report / "evaluations.csv")
    assert len(rows) == 3 * (4 + 8) * len(STEPS)
    first = rows[0]
    assert {
        "run",
        "teacher",
        "criterion",
        "expert_knowledge",
        "seed",
        "step",
        "mastered_pct",
    } <= set(first)
    assert [r["step"] for r in rows[:3]] == ["1000", "2000", "3000"]


def test_welch_at_the_end_and_over_steps(campaign):
    _, report, finals = campaign
    final = _rows(report / "final_scores.csv")
    for ek in ("low", "high"):  # Random's low-level runs are the baseline of both levels
        row = next(r for r in final if r["teacher"] == "alp-gmm"
                   and r["task"] == f"criterion=rugged-difficulty, expert_knowledge={ek}")  # fmt: skip
        x, y = (
            finals[("alp-gmm", "rugged-difficulty", ek)],
            finals[("random", "rugged-difficulty", "low")],
        )
        assert float(row["p"]) == pytest.approx(sps.ttest_ind(x, y, equal_var=False).pvalue)
        assert row["significant"] == "True"
        assert float(row["ratio"]) == pytest.approx(np.mean(x) / np.mean(y))
    steps = _rows(report / "welch_over_steps.csv")
    assert len(steps) == 2 * 3 * len(STEPS)  # alp-gmm x 2 levels x 3 criteria, every evaluation
    assert all(r["p"] == "nan" for r in steps if r["step"] == "1000")  # all zero: undefined
    aggregates = {r["teacher"]: r for r in _rows(report / "aggregates.csv")}
    assert float(aggregates["alp-gmm"]["P(improvement)"]) == 1.0
    assert aggregates["random"]["P(improvement)"] == ""
    lo, hi = float(aggregates["alp-gmm"]["IQM_low"]), float(aggregates["alp-gmm"]["IQM_high"])
    assert lo <= float(aggregates["alp-gmm"]["IQM"]) <= hi


def test_figures_and_report(campaign):
    _, report, _ = campaign
    for name in ("curves_mastered_pct.png", "aggregates.png", "performance_profile.png",
                 "radar_ek-low.png", "radar_ek-high.png"):  # fmt: skip
        assert (report / name).read_bytes()[:4] == b"\x89PNG"
    text = (report / "report.md").read_text()
    assert "![radar_ek-high](radar_ek-high.png)" in text and "| alp-gmm |" in text


def test_cli_and_bad_input(campaign, tmp_path, capsys):
    root, _, _ = campaign
    out = tmp_path / "r"
    assert main(["analyze", str(root), "--out", str(out), "--metric", "mean_return",
                 "--reps", "200"]) == 0  # fmt: skip
    assert (out / "curves_mean_return.png").exists()
    shutil.copytree(root / "runs", tmp_path / "outer" / "inner" / "runs")  # a nested campaign
    shutil.copy(root / "campaign.yaml", tmp_path / "outer" / "inner")
    analyze(tmp_path / "outer", out, reps=100)
    final = _rows(out / "final_scores.csv")
    assert {r["task"] for r in final} == {
        f"criterion={c}, expert_knowledge={ek}" for c in CRITERIA for ek in ("low", "high")
    }
    assert main(["analyze", str(root), "--baseline", "riac", "--out", str(out)]) == 2
    assert "baseline teacher 'riac' has no runs" in capsys.readouterr().err
    assert main(["analyze", str(tmp_path / "empty")]) == 2
    assert main(["analyze", str(root), "--reps", "5", "--out", str(out)]) == 2


def test_corrected_tests_rank_test_and_power_beside_the_raw_p(campaign):
    _, report, _ = campaign
    final = [r for r in _rows(report / "final_scores.csv") if r["teacher"] == "alp-gmm"]
    raw = np.array([float(r["p"]) for r in final])
    holm = np.array([float(r["p_holm"]) for r in final])
    assert np.all(holm >= raw - 1e-12) and holm.min() == pytest.approx(len(raw) * raw.min())
    for row in final:
        assert 0 < float(row["mw_p"]) <= float(row["mw_p_holm"]) <= 1
        assert float(row["seeds_needed_holm"]) >= float(row["seeds_needed"]) >= 2
    assert "significant_holm" in (report / "report.md").read_text()


def test_probability_of_improvement_refused_below_three_runs(tmp_path):
    for teacher, base in (("random", 10.0), ("alp-gmm", 30.0)):
        for seed in range(2):
            labels = {"teacher": teacher, "expert_knowledge": "low", "seed": seed}
            _write_run(tmp_path, f"{teacher}__s{seed}", labels, [0, base, base + seed])
    (tmp_path / "campaign.yaml").write_text(yaml.safe_dump({"spec": {"name": "t"}, "runs": []}))
    report = analyze(tmp_path, reps=200)
    aggregates = {r["teacher"]: r for r in _rows(report / "aggregates.csv")}
    assert aggregates["alp-gmm"]["P(improvement)"] == "insufficient runs"
    assert "insufficient runs" in (report / "report.md").read_text()
