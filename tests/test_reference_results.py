"""Reference results: export of real runs, `analyze --reference` with its protocol check, the
leaderboard. tests/data/reference-mini{,-new} are the export of a tiny real campaign
(`scripts/make_reference_fixture.py`): Random, ALP-GMM, RIAC x 3 seeds, and Covar-GMM x 3 seeds
as the "new" teacher."""

from __future__ import annotations

import csv
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from acl3d import provenance, results
from acl3d.analysis import stats
from acl3d.analysis.curriculum_files import read_episodes, read_teacher
from acl3d.analysis.export import export_campaign
from acl3d.analysis.leaderboard import (
    HEADLINE_END,
    HEADLINE_START,
    LEADERBOARD_END,
    LEADERBOARD_START,
    seed_ranges,
    write_headline,
    write_leaderboard,
)
from acl3d.analysis.reference import analyze_against, machine_notes, missing_runs
from acl3d.analysis.runs import load_runs
from acl3d.cli import main

DATA = Path(__file__).parent / "data"
REFERENCE, NEW = DATA / "reference-mini", DATA / "reference-mini-new"


def _finals(folder: Path, metric: str) -> dict[str, np.ndarray]:
    out: dict[str, list[float]] = {}
    for run in sorted(p for p in folder.iterdir() if (p / "evals.csv").exists()):
        with (run / "evals.csv").open() as f:
            last = list(csv.DictReader(f))[-1]
        teacher = yaml.safe_load((run / "config.yaml").read_text())["config"]["teacher"]
        out.setdefault(teacher, []).append(float(last[metric]))
    return {t: np.array(v) for t, v in out.items()}


def test_new_teacher_beside_the_reference(tmp_path, capsys):
    out = tmp_path / "report"
    code = main(["analyze", str(NEW), "--reference", str(REFERENCE), "--metric", "mean_return",
                 "--reps", "500", "--out", str(out)])  # fmt: skip
    assert code == 0 and "report written" in capsys.readouterr().out
    with (out / "against_each_reference.csv").open() as f:
        rows = list(csv.DictReader(f))
    finals = {**_finals(REFERENCE, "mean_return"), **_finals(NEW, "mean_return")}
    assert {r["reference"] for r in rows} == {"random", "alp-gmm", "riac"}
    for row in rows:
        x, y = finals["covar-gmm"], finals[row["reference"]]
        assert float(row["mean"]) == pytest.approx(x.mean())
        assert float(row["reference_mean"]) == pytest.approx(y.mean())
        wins = ((x[:, None] > y[None, :]) + 0.5 * (x[:, None] == y[None, :])).mean()
        assert float(row["P(improvement)"]) == pytest.approx(wins)
    report = (out / "report.md").read_text()
    assert "## Against each teacher of the reference 'reference-mini'" in report
    # neither side has provenance.json: versions from config.yaml (equal), CPU model unknown
    assert "cpu_model: not recorded by either run, so it may differ" in report
    assert "torch:" not in report and "records no provenance" not in report
    for figure in ("performance_profile.png", "aggregates.png", "curves_mean_return.png"):
        assert (out / figure).stat().st_size > 0
    # the combined tables hold the reference's teachers and the new one
    with (out / "aggregates.csv").open() as f:
        assert {r["teacher"] for r in csv.DictReader(f)} == {
            "random",
            "alp-gmm",
            "riac",
            "covar-gmm",
        }


def test_versions_of_runs_without_provenance_come_from_their_config(tmp_path):
    """The shipped v1 runs predate provenance.json; their config.yaml recorded the versions."""
    reference = load_runs(REFERENCE)
    shutil.copytree(NEW, tmp_path / "new")
    for config in (tmp_path / "new").glob("*/config.yaml"):
        doc = yaml.safe_load(config.read_text())
        doc["environment"]["packages"]["torch"] = "2.0.0"
        config.write_text(yaml.safe_dump(doc))
    notes = machine_notes(load_runs(tmp_path / "new"), reference, "mini")
    assert any("torch: '2.0.0' (new) vs '2.13.0+cpu' (reference)" in n for n in notes)
    with_provenance = tmp_path / "recorded" / "covar-gmm__s0"
    shutil.copytree(NEW / "covar-gmm__s0", with_provenance)
    provenance.record(with_provenance, "start")
    cpu = provenance.cpu_model()
    notes = machine_notes(load_runs(with_provenance.parent), reference, "mini")
    assert any(f"cpu_model: {cpu!r} (new) vs 'not recorded' (reference)" in n for n in notes)


@pytest.mark.parametrize(
    ("edit", "field"),
    [
        (lambda run: _set_config(run, ("config", "body"), "spider"), "body"),
        (lambda run: _set_config(run, ("resolved", "steps"), 4096), "budget (steps)"),
        (lambda run: _set_config(run, ("student_hyperparameters", "n_epochs"), 3), "student hyper"),
        (lambda run: _shift_test_set(run), "test set"),
    ],
)
def test_runs_of_another_protocol_are_refused_naming_the_field(tmp_path, capsys, edit, field):
    new = tmp_path / "new"
    shutil.copytree(NEW, new)
    edit(sorted(new.glob("covar-gmm__s*"))[1])
    with pytest.raises(
        ValueError, match=f"does not follow the reference protocol.*{re.escape(field)}"
    ):
        analyze_against(new, str(REFERENCE), tmp_path / "report", "mean_return", 200)
    assert not (tmp_path / "report").exists()
    code = main(["analyze", str(new), "--reference", str(REFERENCE), "--reps", "200"])
    assert code == 2 and field in capsys.readouterr().err


def _set_config(run: Path, keys: tuple[str, str], value) -> None:
    doc = yaml.safe_load((run / "config.yaml").read_text())
    doc[keys[0]][keys[1]] = value
    (run / "config.yaml").write_text(yaml.safe_dump(doc))


def _shift_test_set(run: Path) -> None:
    text = (run / "test_set.csv").read_text().splitlines()
    index, height, spacing = text[2].split(",")
    text[2] = f"{index},{float(height) + 0.5},{spacing}"
    (run / "test_set.csv").write_text("\n".join(text) + "\n")


def test_unknown_reference_names_the_shipped_protocols(tmp_path):
    with pytest.raises(ValueError, match="not a shipped protocol"):
        analyze_against(NEW, "stump-v0", tmp_path / "r", "mean_return", 200)
    assert set(results.protocols()) <= {
        "stump-v1",
        "parkour-walker-v1",
        "stump-v2",
        "stump-rsl",
        "stump-rsl-10m",
    }


def test_export_of_a_real_run(tmp_path):
    from acl3d.training import train

    run_dir = tmp_path / "camp" / "runs" / "random__s0"
    train(teacher="random", student="ppo", preset="fast", steps=256, n_envs=1, vec_env="dummy",
          nb_test_episodes=4, eval_every=128, env_kwargs={"max_episode_steps": 30},
          student_params={"n_steps": 128, "batch_size": 64, "n_epochs": 1}, progress_bar=False,
          verbose=0, out=str(run_dir))  # fmt: skip
    planned = [{"name": f"random__s{i}", "labels": {"teacher": "random", "seed": i}}
               for i in (0, 1)]  # fmt: skip
    (tmp_path / "camp" / "campaign.yaml").write_text(yaml.safe_dump({"runs": planned}))
    provenance.close(run_dir, "interrupted", 128)  # as if stopped at step 128, then resumed
    provenance.record(run_dir, "resume", step=128, device="cpu")
    provenance.close(run_dir, "finished", 256)
    names = export_campaign(tmp_path / "camp", tmp_path / "exported", "mini")
    assert names == ["random__s0"]
    got = tmp_path / "exported" / "random__s0"
    assert sorted(p.name for p in got.iterdir()) == [
        "config.yaml", "episodes.npz", "episodes_summary.csv", "evals.csv", "evals_tasks.csv",
        "provenance.json", "status.json", "teacher.json", "teacher.npz", "test_set.csv",
    ]  # fmt: skip
    config = yaml.safe_load((got / "config.yaml").read_text())
    assert "out" not in config["config"] and "command" not in config["environment"]
    assert config["task_space"] == {"stump_height": [0.0, 3.0], "obstacle_spacing": [0.0, 6.0]}
    with (run_dir / "episodes.csv").open() as f:
        episodes = list(csv.DictReader(f))
    with (got / "episodes_summary.csv").open() as f:
        windows = list(csv.DictReader(f))
    assert sum(int(w["episodes"]) for w in windows) == len(episodes)
    returns = [float(e["return"]) for e in episodes]
    first = [w for w in windows if int(w["episodes"])][0]
    inside = [float(e["return"]) for e in episodes if float(e["step"]) <= int(first["step_end"])]
    assert float(first["mean_return"]) == pytest.approx(np.mean(inside), rel=1e-5)
    assert len(returns) > 0
    # every episode, the teacher's sampling record and the provenance ship with the run
    shipped = read_episodes(got)
    assert int(shipped["every"]) == 1 and int(shipped["episodes"]) == len(episodes)
    np.testing.assert_array_equal(shipped["return"], np.float32(returns))
    assert list(shipped["step"]) == [int(e["step"]) for e in episodes]
    dump, original_dump = read_teacher(got), read_teacher(run_dir)
    assert dump["every"] == {} and "train_returns" in dump["left_out"]
    assert len(dump["periodical_samples"]) == len(original_dump["periodical_samples"])
    assert dump["bounds"] == original_dump["bounds"]
    assert provenance.load(got) == provenance.load(run_dir)
    # so a reference exported since v2 is compared machine to machine, not 'unknown'
    assert machine_notes(load_runs(run_dir), load_runs(got), "mini") == []
    doc = yaml.safe_load((tmp_path / "exported" / "protocol.yaml").read_text())
    sizes = sum(p.stat().st_size for p in got.iterdir())
    assert doc["bytes"] == sizes and doc["thinned"] == {}
    assert doc["planned_runs"] == {"random": 2}  # what the campaign was to run
    segment, resume = provenance.load(run_dir)
    assert doc["hardware"]["runs_on"] == [f"{segment['cpu_model']} · {segment['device']}"]
    assert doc["resumed"] == {"random__s0": 1}
    assert doc["dirty_tree"] == (["random__s0"] if segment["dirty"] or resume["dirty"] else [])
    assert missing_runs(tmp_path / "exported", load_runs(got)) == ["random (1 of 2 seeds)"]
    # a built-in protocol's campaign run a few cells at a time plans the protocol's whole spec
    doc = {"spec": {"name": "stump-v2"}, "runs": planned[:1]}
    (tmp_path / "camp" / "campaign.yaml").write_text(yaml.safe_dump(doc))
    out = tmp_path / "exported-v2"
    assert main(["campaign", "export", str(tmp_path / "camp"), "--protocol", "stump-v2",
                 "--out", str(out)]) == 0  # fmt: skip
    planned_v2 = yaml.safe_load((out / "protocol.yaml").read_text())["planned_runs"]
    assert planned_v2["random"] == planned_v2["alp-gmm"] == 16 and planned_v2["riac"] == 8
    assert planned_v2["accel"] == planned_v2["self-paced"] == 8  # they learn from steps
    # the exported run is read like the original one
    (original,), (exported,) = load_runs(run_dir), load_runs(got)
    np.testing.assert_array_equal(original.metrics["mean_return"], exported.metrics["mean_return"])


def test_leaderboard_from_committed_form(tmp_path):
    root = tmp_path / "results"
    shutil.copytree(REFERENCE, root / "reference-mini")
    page = tmp_path / "docs" / "results.md"
    page.parent.mkdir()
    page.write_text(f"# Results\n\n{LEADERBOARD_START}\nold\n{LEADERBOARD_END}\n\nkept\n")
    assert write_leaderboard(root, page, tmp_path / "docs" / "figures", reps=200) == [
        "reference-mini"
    ]
    text = page.read_text()
    assert "old" not in text and text.endswith("kept\n") and "### reference-mini" in text
    finals = _finals(REFERENCE, "mean_return")
    rows = {
        line.split(" | ")[0].strip("| "): line
        for line in text.splitlines()
        if "±" in line and not line.startswith("| teacher")
    }
    assert list(rows) == ["random", "alp-gmm", "riac"]  # Random first
    for teacher, x in finals.items():
        assert f"{x.mean():.1f} ± {x.std(ddof=1):.1f}" in rows[teacher]
    # the power estimate at 0.05, then at the level of Holm's correction over the 2 comparisons
    assert "return seeds for 80% power (Holm)" in text
    x, y = finals["alp-gmm"], finals["random"]
    raw, corrected = stats.seeds_needed(x, y), stats.seeds_needed(x, y, alpha=0.05 / 2)
    assert corrected > raw and rows["alp-gmm"].endswith(f"| {raw:.0f} ({corrected:.0f}) |")
    assert "budget 1,024 steps per run · 3 seeds" in text
    assert (tmp_path / "docs" / "figures" / "reference-mini_mean_return.png").exists()
    assert "](figures/reference-mini_mean_return.png)" in text
    # the README's headline: the same numbers, shorter
    readme = tmp_path / "README.md"
    readme.write_text(f"# acl3d\n{HEADLINE_START}\nold table\n{HEADLINE_END}\n## Next\n")
    write_headline(root / "reference-mini", readme, "fig.png", "docs/results.md", reps=200)
    headline = readme.read_text()
    assert "old table" not in headline and headline.endswith("## Next\n")
    iqm = next(line for line in text.splitlines() if line.startswith("| alp-gmm"))
    assert iqm.split(" | ")[5] in headline  # return IQM [95% CI] of alp-gmm, as in the page
    assert iqm.split(" | ")[4] in headline  # and its % mastered p (Welch, Holm)


def test_an_incomplete_reference_is_named_before_the_report(tmp_path, capsys):
    partial = tmp_path / "reference-partial"
    shutil.copytree(REFERENCE, partial)
    shutil.rmtree(partial / "riac__s2")  # exported before its last run finished
    code = main(["analyze", str(NEW), "--reference", str(partial), "--metric", "mean_return",
                 "--reps", "200", "--out", str(tmp_path / "report")])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 0
    assert "reference 'reference-partial' is incomplete" in err and "riac (2 of 3 seeds)" in err
    assert "alp-gmm (" not in err and "random (" not in err


def test_incomplete_against_the_runs_the_campaign_planned(tmp_path, capsys):
    """A v2 protocol gives teachers different seed counts (exclude rules): the export records
    the runs per teacher its campaign planned, and only those missing are named."""
    partial = tmp_path / "reference-planned"
    shutil.copytree(REFERENCE, partial)
    doc = yaml.safe_load((partial / "protocol.yaml").read_text())
    doc["planned_runs"] = {"random": 3, "alp-gmm": 3, "riac": 2}
    (partial / "protocol.yaml").write_text(yaml.safe_dump(doc))
    shutil.rmtree(partial / "riac__s2")  # RIAC planned with 2 seeds: complete
    shutil.rmtree(partial / "alp-gmm__s1")
    code = main(["analyze", str(NEW), "--reference", str(partial), "--metric", "mean_return",
                 "--reps", "200", "--out", str(tmp_path / "report")])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 0 and "alp-gmm (2 of 3 seeds)" in err
    assert "riac (" not in err and "random (" not in err


def test_a_protocols_header_names_each_teachers_seeds_as_ranges_when_they_differ():
    assert seed_ranges([3, 0, 1, 2, 9, 7]) == "0–3, 7, 9"
    assert seed_ranges(range(16)) == "0–15" and seed_ranges([2, 3]) == "2, 3"


def test_a_holm_adjusted_p_below_001_keeps_a_digit_in_the_leaderboard():
    from acl3d.analysis.leaderboard import _p_cell

    assert _p_cell(0.0007, 0.0021) == "0.001 (0.002) *" and _p_cell(0.2, 0.6) == "0.200 (0.60)"
