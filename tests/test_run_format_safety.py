"""The run format's faults: torn or missing evaluations, a LATEST naming a pruned step, edited or
truncated checkpoint files, a dead writer, a signal during a status write, a full disk at start,
and the provenance carried with a run."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from cli_support import one_line_error
from run_safety_support import (
    FIRST,
    LAST,
    TINY,
    assert_same_training,
    truncate,
)

from acl3d import atomic_files
from acl3d.campaign.run_state import read_state
from acl3d.cli import main
from acl3d.training import TrainConfig
from acl3d.training.run_dir import DamagedCheckpoint, RunDir
from acl3d.training.session import verify_checkpoint


def fake_run(root: Path, name: str, evals: str | None, teacher: str = "random") -> Path:
    """A run directory as analysis reads it: config.yaml, status.json, evals.csv."""
    run = root / name
    run.mkdir(parents=True)
    (run / "config.yaml").write_text(yaml.safe_dump({"config": {"teacher": teacher, "seed": 0}}))
    (run / "status.json").write_text(json.dumps({"status": "finished"}))
    if evals is not None:
        header = "step,episodes,mastered_pct,mean_return,std_return,mean_length,n_tasks,wall_time_s"
        (run / "evals.csv").write_text(f"{header}\n2048,40,0,-5.0,1,50,4,1.0\n{evals}")
    return run


def test_analysis_skips_runs_with_torn_or_missing_evaluations_and_names_them(tmp_path, capsys):
    from acl3d.analysis.runs import load_runs

    fake_run(tmp_path, "good", "4096,82,25,-3.0,1,50,4,2.0\n")
    torn = {
        "short": "4096,82\n",
        "value": "4096,82,0,-,1,50,4,2.0\n",
        "cut": "4096,82,0,-3.0\n",
        "end": "4096,82,0,-\n",
    }
    for name, row in torn.items():
        fake_run(tmp_path, name, row)
    fake_run(tmp_path, "none", None)
    runs = load_runs(tmp_path)
    assert [r.name for r in runs] == ["good"] and list(runs[0].metrics["mastered_pct"]) == [0, 25]
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 5 and "Traceback" not in "".join(err)
    for name in torn:
        line = next(e for e in err if f"skipping run {name}:" in e)
        assert str(tmp_path / name / "evals.csv") in line and "line 3 is torn" in line
    assert any(f"skipping run none: {tmp_path / 'none' / 'evals.csv'} is missing" in e for e in err)


@pytest.mark.parametrize("latest", ["", "step_000000000128"])
def test_latest_empty_or_naming_a_pruned_step_resumes_from_the_newest_checkpoint(
    latest, tiny_run, tiny_run_copy, capsys
):
    run = tiny_run_copy()
    (run / "final_model.zip").unlink()
    RunDir(run).set_status("crashed")
    (run / "checkpoints" / "LATEST").write_text(latest)
    assert read_state(run, 512).checkpoint_step == 512  # a campaign resumes it, never restarts
    assert main(["train", "--resume", str(run)]) == 0
    assert "LATEST " in capsys.readouterr().err
    assert (run / "checkpoints" / "LATEST").read_text() == LAST
    assert_same_training(tiny_run, run)


def test_an_edited_checkpoint_file_fails_its_hash_and_resume_falls_back(
    tiny_run, tiny_run_copy, capsys
):
    run = tiny_run_copy()
    rng = run / "checkpoints" / LAST / "rng.json"
    text = rng.read_text()
    edited = text.replace('"pos": ', '"pos": 3', 1)
    assert edited != text
    rng.write_text(edited)
    (run / "final_model.zip").unlink()
    RunDir(run).set_status("crashed")
    config = TrainConfig.from_dict(RunDir(run).read_config())
    with pytest.raises(DamagedCheckpoint, match="rng.json differs from the checkpoint's manifest"):
        verify_checkpoint(run / "checkpoints" / LAST, config)
    assert main(["train", "--resume", str(run)]) == 0
    assert f"skipping damaged checkpoint {LAST}" in capsys.readouterr().err
    assert_same_training(tiny_run, run)

    run = tiny_run_copy()
    (run / "checkpoints" / FIRST / "manifest.json").unlink()
    with pytest.raises(DamagedCheckpoint, match="manifest.json is missing"):
        verify_checkpoint(run / "checkpoints" / FIRST, config)


def test_evaluate_on_a_crashed_run_falls_back_past_a_truncated_model(tiny_run_copy, capsys):
    run = tiny_run_copy()
    (run / "final_model.zip").unlink()
    RunDir(run).set_status("crashed")
    truncate(run / "checkpoints" / LAST / "model.zip")
    assert main(["evaluate", str(run), "--nb-test-episodes", "4"]) == 0
    out, err = capsys.readouterr()
    assert f"skipping damaged checkpoint {LAST}" in err and "model.zip" in err
    assert f"evaluating {run / 'checkpoints' / FIRST / 'model.zip'} (step 256)" in out


def test_running_with_a_dead_process_reads_as_crashed(tiny_run_copy, tmp_path):
    from acl3d.analysis.runs import load_runs

    run = tiny_run_copy()
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    (run / "status.json").write_text(json.dumps({"status": "running", "pid": gone.pid}))
    assert RunDir(run).status() == "crashed"
    state = read_state(run, 512)
    assert state.status == "crashed" and f"process {gone.pid} ended" in state.error
    assert load_runs(run.parent)[0].status == "crashed"
    RunDir(run).set_status("running")  # this process, alive
    assert RunDir(run).status() == "running"


def test_a_signal_during_a_status_write_is_held_until_the_write_is_whole(
    tiny_run_copy, monkeypatch
):
    run = tiny_run_copy()
    replace = atomic_files.atomic_replace

    def interrupted(tmp, path):
        os.kill(os.getpid(), signal.SIGINT)  # a campaign's second Ctrl-C, mid-write
        replace(tmp, path)

    monkeypatch.setattr(atomic_files, "atomic_replace", interrupted)
    # Python's own Ctrl-C handler, whatever an earlier test of this worker process left
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            RunDir(run).set_status("interrupted", latest_checkpoint=LAST)
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, previous)
    assert json.loads((run / "status.json").read_text())["status"] == "interrupted"


def test_a_full_disk_at_start_leaves_no_directory(tmp_path, capsys, monkeypatch):
    def full(tmp, path):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(atomic_files, "atomic_replace", full)
    out = tmp_path / "new" / "run"
    assert main(["train", *TINY, "--out", str(out)]) == 1
    one_line_error(capsys, "no space left on device", "nothing was written")
    assert not (tmp_path / "new").exists()


def test_provenance_is_carried_and_cleared_with_the_run(tiny_run_copy):
    from acl3d.run_format.documents import read_provenance, write_provenance

    run = tiny_run_copy()
    assert [s["event"] for s in read_provenance(run)] == ["start"]  # written at the start
    (run / "provenance.json").unlink()
    assert read_provenance(run) is None  # a run written before provenance.json
    write_provenance(run, [{"acl3d": "1.0", "cpu": "x86_64"}])
    assert read_provenance(run) == [{"acl3d": "1.0", "cpu": "x86_64"}]
    with pytest.raises(ValueError, match="provenance=\\[1\\]; valid: a list of mappings"):
        write_provenance(run, [1])
    RunDir(run).clear()
    assert not (run / "provenance.json").exists()
