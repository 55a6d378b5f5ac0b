"""Campaigns end to end: real training runs on a local Ray instance next to a broken one, and a
campaign killed mid-run and continued (finished runs skipped, the interrupted one resumed)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from acl3d.analysis import analyze
from acl3d.campaign import CampaignDir, CampaignSpec, load_spec, run_campaign
from acl3d.cli import main

# Tiny real runs: 256-step PPO rollouts, 40-step episodes, a 4-task test set.
TINY = {
    "n_envs": 1,
    "vec_env": "dummy",
    "nb_test_episodes": 4,
    "env_kwargs": {"max_episode_steps": 40},
    "student_params": {"n_steps": 256, "batch_size": 64, "n_epochs": 1},
    "verbose": 0,
}


def _campaign_lines(run_dir: Path) -> list[str]:
    return [
        line for line in (run_dir / "campaign.log").read_text().splitlines() if "[campaign]" in line
    ]


def test_campaign_on_ray_with_a_broken_run_then_analyze(tmp_path, capfd):
    spec = CampaignSpec.from_dict(
        {
            "name": "mini",
            "base": {**TINY, "student": "ppo", "preset": "fast", "steps": 512},
            "grid": {
                "teacher": {
                    "random": {"teacher": "random"},
                    "alp-gmm": {"teacher": "alp-gmm"},
                    # passes the spec check, rejected by train before the run starts: reported
                    # with its traceback and not retried (retrying cannot help)
                    "broken": {"teacher": "random", "teacher_params": {"nope": 1}},
                }
            },
        }
    )
    out = tmp_path / "camp"
    result = run_campaign(spec, out, executor="ray", max_parallel=2, retries=2, live=False)
    assert sorted(result.finished) == ["alp-gmm__s0", "random__s0"]
    assert result.failed == ["broken__s0"]
    assert "Token authentication" not in capfd.readouterr().err  # no warning opens a campaign
    camp = CampaignDir(out)
    for name in result.finished:
        run = camp.run_dir(name)
        assert json.loads((run / "status.json").read_text())["status"] == "finished"
        config = yaml.safe_load((run / "config.yaml").read_text())["config"]
        assert config["teacher"] == name.split("__")[0] and config["torch_threads"] == 1
        lines = _campaign_lines(run)
        assert len(lines) == 1 and "starting afresh" in lines[0] and "acl3d/__init__.py" in lines[0]
    failures = sorted((camp.run_dir("broken__s0") / "failures").iterdir())
    assert [f.name for f in failures] == ["attempt_1.txt"]
    assert "Traceback" in failures[0].read_text() and "nope" in failures[0].read_text()
    manifest = camp.read()
    assert [r["name"] for r in manifest["runs"]] == ["random__s0", "alp-gmm__s0", "broken__s0"]
    capfd.readouterr()
    assert main(["campaign", "status", str(out)]) == 0
    assert "2 finished, 0 running, 1 failed" in capfd.readouterr().out

    report = analyze(out, reps=200)
    evaluations = (report / "evaluations.csv").read_text().splitlines()
    assert evaluations[0].startswith("run,status,") and len(evaluations) == 3
    for name in ("report.md", "aggregates.csv", "final_scores.csv", "welch_over_steps.csv",
                 "curves_mastered_pct.png", "aggregates.png", "performance_profile.png"):  # fmt: skip
        assert (report / name).stat().st_size > 0


def _mark_started(run_dir: Path) -> None:
    run_dir.mkdir(parents=True)
    (run_dir / "config.yaml").write_text("config: {}\n")


def test_interrupted_campaign_continues(tmp_path, checkout):
    out = tmp_path / "camp"
    options = {**TINY, "steps": 1536, "checkpoint_every": 256, "eval_every": 1024}
    cmd = [sys.executable, "-m", "acl3d", "campaign", "run", "quick", "--out", str(out),
           "--seeds", "1", "--executor", "local", "--max-parallel", "1"]  # fmt: skip
    sets = [f"{k}={json.dumps(v)}" for k, v in options.items()]
    for item in sets:
        cmd += ["--set", item]
    proc = subprocess.Popen(cmd, cwd=checkout, start_new_session=True, stdout=subprocess.DEVNULL)
    first, second = out / "runs" / "random__s0", out / "runs" / "alp-gmm__s0"
    deadline = time.monotonic() + 120
    try:  # SIGKILL the campaign process once the first run is done and the second has a checkpoint
        while not (second / "checkpoints" / "LATEST").exists():
            assert time.monotonic() < deadline and proc.poll() is None
            time.sleep(0.05)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        # its attempt does not go on training alone: it ends by itself, like on Ctrl-C
        attempt = int(_campaign_lines(second)[0].split(" pid ")[1].split(":")[0])
        while _alive(attempt):
            assert time.monotonic() < deadline, "the attempt outlived its campaign process"
            time.sleep(0.05)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
    assert json.loads((first / "status.json").read_text())["status"] == "finished"
    assert json.loads((second / "status.json").read_text())["status"] == "interrupted"
    finished_at = (first / "status.json").stat().st_mtime_ns

    spec = load_spec("quick").scaled(seeds=1, sets=options)
    result = run_campaign(spec, out, executor="local", max_parallel=1, live=False)
    assert sorted(result.finished) == ["alp-gmm__s0", "random__s0"]
    assert (first / "status.json").stat().st_mtime_ns == finished_at  # not redone
    assert len(_campaign_lines(first)) == 1
    lines = _campaign_lines(second)
    assert len(lines) == 2 and "resuming from its step-" in lines[1]
    assert not (second / "failures").exists()
    evals = (second / "evals.csv").read_text().splitlines()
    assert [row.split(",")[0] for row in evals[1:]] == ["1024", "1536"]


def _alive(pid: int) -> bool:
    """A running process (not a zombie waiting for its new parent to reap it)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_campaign_dir_holding_another_campaign_is_refused(tmp_path):
    spec = load_spec("quick").scaled(seeds=1, sets={**TINY, "steps": 512})
    camp = CampaignDir(tmp_path)
    camp.prepare(spec, spec.expand(), {})
    _mark_started(camp.run_dir("random__s0"))
    other = load_spec("quick").scaled(seeds=1, sets={**TINY, "steps": 1024})
    with pytest.raises(ValueError, match="holds campaign 'quick' whose started runs"):
        run_campaign(other, tmp_path, executor="local")
    more_seeds = load_spec("quick").scaled(seeds=2, sets={**TINY, "steps": 512})
    camp.prepare(more_seeds, more_seeds.expand(), {})  # a campaign may grow
    assert [r["name"] for r in camp.read()["runs"]] == [r.name for r in more_seeds.expand()]
    _mark_started(camp.run_dir("random__s1"))
    camp.prepare(spec, spec.expand(), {})  # fewer seeds: a run that started is not lost
    assert [r["name"] for r in camp.read()["runs"]] == ["random__s0", "random__s1", "alp-gmm__s0"]
    assert camp.read()["spec"]["seeds"] == [0, 1]
    manifest = camp.manifest.read_bytes()
    for bad, message in [
        ({"executor": "slurm"}, "executor 'slurm' unknown"),
        ({"executor": "local", "max_parallel": 0}, "max_parallel must be an integer >= 1"),
        ({"executor": "local", "address": "10.0.0.1:6379"}, "ray executor only"),
        ({"retries": -1}, "retries must be an integer >= 0"),
    ]:
        with pytest.raises(ValueError, match=message):  # refused before the directory changes
            run_campaign(load_spec("quick").scaled(seeds=3), tmp_path, **bad)
    assert camp.manifest.read_bytes() == manifest


def test_a_selection_of_cells_adds_to_the_campaign_and_keeps_its_started_runs(tmp_path):
    """`--only` runs some cells of a campaign in its directory (a cell re-run, or cells added
    session by session); the runs it leaves out stay, but a selection with other options is
    another campaign."""
    from acl3d.cli.campaign import narrowed

    whole = load_spec("quick").scaled(seeds=2, sets={**TINY, "steps": 512})
    camp = CampaignDir(tmp_path)
    first = narrowed(whole, ["teacher=random", "seed=0"])
    camp.prepare(first, first.expand(), {})
    _mark_started(camp.run_dir("random__s0"))
    second = narrowed(whole, ["seed=1"])
    camp.prepare(second, second.expand(), {})
    doc = camp.read()
    assert [r["name"] for r in doc["runs"]] == ["random__s0", "random__s1", "alp-gmm__s1"]
    assert doc["spec"]["seeds"] == [0, 1] and set(doc["spec"]["grid"]["teacher"]) == {
        "random",
        "alp-gmm",
    }
    longer = narrowed(load_spec("quick").scaled(seeds=2, sets={**TINY, "steps": 1024}), ["seed=1"])
    with pytest.raises(ValueError, match=r"started runs \['random__s0'\] are not in this one"):
        camp.prepare(longer, longer.expand(), {})
    assert [r["name"] for r in camp.read()["runs"]] == [r["name"] for r in doc["runs"]]


def test_a_campaign_grows_by_the_cells_its_spec_stops_excluding(tmp_path):
    """A provisional protocol that held a teacher out (Robust PLR until the student passed it
    every step) takes it in: its directory continues under the spec without that exclusion,
    but not under one that would exclude runs that started."""
    from acl3d.cli.campaign import narrowed

    def spec(exclude):
        doc = load_spec("quick").scaled(seeds=2, sets={**TINY, "steps": 512}).to_dict()
        return CampaignSpec.from_dict({**doc, "exclude": exclude})

    camp = CampaignDir(tmp_path)
    held_out = spec([{"teacher": "alp-gmm"}])
    first = narrowed(held_out, ["seed=0"])
    camp.prepare(first, first.expand(), {})
    _mark_started(camp.run_dir("random__s0"))
    grown = narrowed(spec([]), ["seed=1"])
    camp.prepare(grown, grown.expand(), {})
    doc = camp.read()
    assert [r["name"] for r in doc["runs"]] == ["random__s0", "random__s1", "alp-gmm__s1"]
    assert doc["spec"]["exclude"] == []
    shrunk = narrowed(spec([{"teacher": "random", "seed": 0}]), ["seed=1"])
    with pytest.raises(ValueError, match=r"started runs \['random__s0'\] that this spec excludes"):
        camp.prepare(shrunk, shrunk.expand(), {})
    assert camp.read() == doc
