"""Runs that no mistake can corrupt: every refusal comes before anything is written, one process
at a time per run directory, damaged checkpoints skipped for the previous one, a full disk or a
killed writer leaving a resumable run, and one-line messages instead of tracebacks (the run
format's own faults: tests/test_run_format_safety.py).
"""

from __future__ import annotations

import errno
import json
import os
import shutil
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
    snapshot,
    truncate,
)

from acl3d import atomic_files
from acl3d.cli import main
from acl3d.training import TrainConfig
from acl3d.training.run_dir import DamagedCheckpoint, RunDir
from acl3d.training.session import Session, verify_checkpoint


# ---------------------------------------------------------------------- checks before writing
@pytest.mark.parametrize(
    "args, option",
    [
        (["--nb-test-episodes", "1000000000"], "--nb-test-episodes=1000000000"),
        (["--torch-threads", "100000"], "--torch-threads=100000"),
        (["--n-envs", "4097"], "--n-envs=4097"),
        (["--eval-envs", "100000"], "--eval-envs=100000"),
        (["--vec-env", "subproc", "--n-envs", "4000"], "worker processes"),
        (["--seed", "4294967296"], "--seed=4294967296"),
        (["--student-param", "learning_rate=-1"], "--student-param learning_rate=-1"),
        (["--student-param", "gamma=1.5"], "--student-param gamma=1.5"),
        (["--env-kwarg", "max_episode_steps=-1"], "--env-kwarg max_episode_steps=-1"),
        (["--env-kwarg", "bogus=1"], "--env-kwarg bogus=1; valid: keyword arguments"),
        (["--device", "bogus"], "--device='bogus'"),
        (["--student", "sb3:DQN"], "--student='sb3:DQN'; DQN does not support the environment's"),
    ],
)
def test_bad_options_are_refused_before_anything_is_written(args, option, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["train", *TINY, *args, "--out", str(out)]) == 2
    one_line_error(capsys, option)
    assert not out.exists()


@pytest.mark.parametrize("height", [100, 1e308])
def test_unplayable_test_set_task_is_refused_at_start(height, tmp_path, capsys):
    tasks = tmp_path / "tasks.json"
    tasks.write_text(json.dumps([{"stump_height": 1.0}, {"stump_height": height}]))
    out = tmp_path / "run"
    assert main(["train", *TINY, "--test-set", str(tasks), "--out", str(out)]) == 2
    one_line_error(capsys, "test set: task 1", "stump_height")
    assert not out.exists()


@pytest.mark.parametrize(
    "args, option",
    [
        (["--steps", "inf"], "--steps"),
        (["--steps", "nan"], "--steps"),
    ],
)
def test_unparsable_values_are_usage_errors(args, option, tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        main(["train", *TINY, *args, "--out", str(tmp_path / "run")])
    assert stop.value.code == 2 and option in capsys.readouterr().err.strip().splitlines()[-1]


def test_config_file_and_out_mistakes_are_one_line_errors(
    tiny_run_copy, tmp_path, capsys, monkeypatch
):
    bad = tmp_path / "bad.yaml"
    bad.write_text("teacher: [random\nsteps: 10\n")
    assert main(["train", "--config", str(bad), "--out", str(tmp_path / "a")]) == 2
    one_line_error(capsys, "--config", "bad.yaml")
    assert (
        main(["train", *TINY, "--student-param", "gamma=[0.9", "--out", str(tmp_path / "b")]) == 2
    )
    one_line_error(capsys, "--student-param", "not valid YAML")

    a_file = tmp_path / "a_file"
    a_file.write_text("")
    for out in (a_file, a_file / "run"):
        assert main(["train", *TINY, "--out", str(out)]) == 2
        one_line_error(capsys, "--out=", "is a file")

    def read_only(self, *args, **kwargs):  # a read-only filesystem (root ignores permissions)
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(self))

    monkeypatch.setattr(Path, "mkdir", read_only)
    assert main(["train", *TINY, "--out", str(tmp_path / "ro" / "run")]) == 2
    one_line_error(capsys, "--out=", "Read-only file system")
    monkeypatch.undo()
    assert not (tmp_path / "ro").exists()

    run = tiny_run_copy()
    doc = yaml.safe_load((run / "config.yaml").read_text())
    del doc["resolved"]
    (run / "config.yaml").write_text(yaml.safe_dump(doc))
    assert main(["train", "--resume", str(run), "--steps", "1024"]) == 2
    one_line_error(capsys, "config.yaml has no 'resolved' section")


# ---------------------------------------------------------------------- one process per run
LOCK_HOLDER = """
import sys, time
from acl3d.training.run_dir import RunDir
run = RunDir(sys.argv[1]); run.lock(); run.set_status("running", pid=__import__("os").getpid())
print("locked", flush=True); time.sleep(120)
"""


def test_a_run_in_use_is_refused_and_a_killed_holder_releases_it(tiny_run_copy, capsys):
    run = tiny_run_copy()
    holder = subprocess.Popen(
        [sys.executable, "-c", LOCK_HOLDER, str(run)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        before = snapshot(run)
        assert main(["train", "--resume", str(run), "--steps", "1024"]) == 2
        one_line_error(capsys, "in use by process", str(holder.pid))
        assert main(["train", *TINY, "--out", str(run), "--overwrite"]) == 2
        one_line_error(capsys, "in use")
        assert snapshot(run) == before
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    other = RunDir(run)
    other.lock()  # the OS released the killed holder's lock
    other.unlock()


# ---------------------------------------------------------------------- resume
@pytest.mark.parametrize(
    "damaged",
    ["model.zip", "controller.npz", "runtime.json", "rng.npz", "model_vecnormalize.npz"],
)
def test_every_checkpoint_file_is_verified(damaged, tiny_run_copy):
    run = tiny_run_copy()
    truncate(run / "checkpoints" / LAST / damaged)
    config = TrainConfig.from_dict(RunDir(run).read_config())
    with pytest.raises(DamagedCheckpoint, match=damaged.split(".")[0]):
        verify_checkpoint(run / "checkpoints" / LAST, config)
    verify_checkpoint(run / "checkpoints" / FIRST, config)


def test_damaged_latest_checkpoint_falls_back_and_resumes_exactly(tiny_run, tiny_run_copy, capsys):
    run = tiny_run_copy()
    truncate(run / "checkpoints" / LAST / "model.zip")
    (run / "final_model.zip").unlink()
    RunDir(run).set_status("crashed")
    leftovers = ["_teacher_99999_tmp.json", "_teacher_99999_tmp.npz", ".status.json.99999.tmp"]
    for name in leftovers:
        (run / name).write_text("left by a killed writer")
    (run / ".notes.tmp").write_text("a user's file, not a temporary name acl3d makes")
    assert main(["train", "--resume", str(run)]) == 0
    assert f"skipping damaged checkpoint {LAST}" in capsys.readouterr().err
    assert RunDir(run).status() == "finished"
    assert_same_training(tiny_run, run)
    assert not any((run / name).exists() for name in leftovers)
    assert (run / ".notes.tmp").exists()


def test_no_complete_checkpoint_is_refused_and_changes_nothing(tiny_run_copy, capsys):
    run = tiny_run_copy()
    for folder in (run / "checkpoints").glob("step_*"):
        truncate(folder / "rng.npz")
    before = snapshot(run)
    assert main(["train", "--resume", str(run), "--steps", "1024"]) == 2
    one_line_error(capsys, "no complete checkpoint", "damaged", "--overwrite")
    assert snapshot(run) == before


@pytest.mark.parametrize("field, value", [("teacher", "alp-gmm"), ("n_envs", 4), ("student", "sac"), ("seed", 5)])  # fmt: skip
def test_edited_config_is_refused_on_resume(field, value, tiny_run_copy, capsys):
    run = tiny_run_copy()
    doc = yaml.safe_load((run / "config.yaml").read_text())
    doc["config"][field] = value
    (run / "config.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    before = snapshot(run)
    assert main(["train", "--resume", str(run), "--steps", "1024"]) == 2
    one_line_error(capsys, f"config {field}={value!r}", "a run keeps its")
    assert snapshot(run) == before


def test_a_run_without_checkpoint_says_how_to_start_again(tiny_run_copy, tmp_path, capsys):
    run = tiny_run_copy()
    shutil.rmtree(run / "checkpoints")
    assert main(["train", "--resume", str(run)]) == 2
    one_line_error(capsys, "no complete checkpoint", f"--overwrite --out {run}")
    assert main(["train", *TINY, "--out", str(run)]) == 2
    one_line_error(capsys, "already holds a run", "--overwrite")
    (run / "notes.txt").write_text("mine")
    assert main(["train", *TINY, "--steps", "256", "--out", str(run), "--overwrite"]) == 0
    assert RunDir(run).status() == "finished" and (run / "notes.txt").read_text() == "mine"
    assert len((run / "episodes.csv").read_text().splitlines()) < 40  # the old rows are gone


# ---------------------------------------------------------------------- faults while running
def test_a_full_disk_is_one_line_and_leaves_a_resumable_run(
    tiny_run, tmp_path, capsys, monkeypatch
):
    write = Session._write_checkpoint

    def full_at_second(self, folder):
        if folder.name.endswith(LAST):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(folder / "model.zip"))
        write(self, folder)

    monkeypatch.setattr(Session, "_write_checkpoint", full_at_second)
    out = tmp_path / "run"
    assert main(["train", *TINY, "--out", str(out)]) == 1
    one_line_error(capsys, "no space left on device", f"acl3d train --resume {out}")
    assert RunDir(out).status() == "crashed"
    monkeypatch.undo()
    assert not [p for p in out.rglob("*") if p.name.endswith(".tmp") or "_tmp" in p.name]
    assert main(["train", "--resume", str(out)]) == 0
    assert_same_training(tiny_run, out)


def test_a_failed_status_write_leaves_no_temporary_file(tiny_run_copy, monkeypatch):
    run = tiny_run_copy()

    def full(tmp, path):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp))

    monkeypatch.setattr(atomic_files, "atomic_replace", full)
    before = snapshot(run)
    with pytest.raises(OSError):
        RunDir(run).set_status("crashed")
    assert snapshot(run) == before


# ---------------------------------------------------------------------- evaluate and report
def test_evaluate_and_report_check_their_inputs_first(tiny_run_copy, tmp_path, capsys):
    run = tiny_run_copy()
    missing = tmp_path / "missing" / "evals.csv"
    assert main(["evaluate", str(run), "--out", str(missing)]) == 2
    one_line_error(capsys, "--out=", "does not exist")
    truncate(run / "teacher.npz")
    assert main(["evaluate", str(run)]) == 2
    one_line_error(capsys, "teacher.json/.npz cannot be read")

    run = tiny_run_copy()
    truncate(run / "teacher.json")
    assert main(["report", str(run), "--no-video"]) == 2
    one_line_error(capsys, "teacher.json/.npz cannot be read")
    assert not (run / "report").exists()


def test_report_checks_that_it_can_render_before_its_plots(tiny_run_copy, monkeypatch, capsys):
    from acl3d import rendering

    def no_gl(*args, **kwargs):
        raise RuntimeError("OpenGL rendering failed with MUJOCO_GL=egl (EGLError: no device)")

    monkeypatch.setattr(rendering, "TrackRenderer", no_gl)
    run = tiny_run_copy()
    assert main(["report", str(run)]) == 2
    one_line_error(capsys, "OpenGL rendering failed", "MUJOCO_GL=egl")
    assert not (run / "report").exists()
