"""Runs that no mistake can corrupt: every refusal comes before anything is written, one process
at a time per run directory, damaged checkpoints skipped for the previous one, a full disk or a
killed writer leaving a resumable run, and one-line messages instead of tracebacks.
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

from acl3d import atomic_files
from acl3d.campaign.run_state import read_state
from acl3d.cli import main
from acl3d.training import TrainConfig, students
from acl3d.training.run_dir import DamagedCheckpoint, RunDir
from acl3d.training.session import Session, verify_checkpoint

TINY = [
    "--teacher", "random", "--student", "ppo", "--preset", "fast", "--n-envs", "2",
    "--nb-test-episodes", "4", "--env-kwarg", "max_episode_steps=50",
    "--student-param", "n_steps=128", "--student-param", "batch_size=128",
    "--eval-every", "256", "--checkpoint-every", "256", "--steps", "512",
    "--no-progress", "--quiet",
]  # fmt: skip
FIRST, LAST = "step_000000000256", "step_000000000512"


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A finished 512-step run with checkpoints at 256 and 512 steps."""
    out = tmp_path_factory.mktemp("finished") / "run"
    assert main(["train", *TINY, "--out", str(out)]) == 0
    return out


@pytest.fixture
def copy(finished, tmp_path):
    def make() -> Path:
        run = tmp_path / f"copy{len(list(tmp_path.iterdir()))}"
        shutil.copytree(finished, run)
        return run

    return make


def snapshot(run: Path) -> dict[str, bytes]:
    return {str(p.relative_to(run)): p.read_bytes() for p in run.rglob("*") if p.is_file()}


def truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def assert_same_training(a: Path, b: Path) -> None:
    """Same training episodes, test episodes, evaluations (wall time aside) and final model."""
    for name in ("episodes.csv", "evals_tasks.csv"):
        assert (a / name).read_text() == (b / name).read_text(), name
    evals = [
        [r.rsplit(",", 1)[0] for r in (p / "evals.csv").read_text().splitlines()] for p in (a, b)
    ]
    assert evals[0] == evals[1]
    params = [students.load("ppo", p / "final_model.zip").policy for p in (a, b)]
    for x, y in zip(params[0].state_dict().values(), params[1].state_dict().values()):
        assert (x == y).all()


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


def test_config_file_and_out_mistakes_are_one_line_errors(copy, tmp_path, capsys, monkeypatch):
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

    run = copy()
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


def test_a_run_in_use_is_refused_and_a_killed_holder_releases_it(copy, capsys):
    run = copy()
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
def test_every_checkpoint_file_is_verified(damaged, copy):
    run = copy()
    truncate(run / "checkpoints" / LAST / damaged)
    config = TrainConfig.from_dict(RunDir(run).read_config())
    with pytest.raises(DamagedCheckpoint, match=damaged.split(".")[0]):
        verify_checkpoint(run / "checkpoints" / LAST, config)
    verify_checkpoint(run / "checkpoints" / FIRST, config)


def test_damaged_latest_checkpoint_falls_back_and_resumes_exactly(finished, copy, capsys):
    run = copy()
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
    assert_same_training(finished, run)
    assert not any((run / name).exists() for name in leftovers)
    assert (run / ".notes.tmp").exists()


def test_no_complete_checkpoint_is_refused_and_changes_nothing(copy, capsys):
    run = copy()
    for folder in (run / "checkpoints").glob("step_*"):
        truncate(folder / "rng.npz")
    before = snapshot(run)
    assert main(["train", "--resume", str(run), "--steps", "1024"]) == 2
    one_line_error(capsys, "no complete checkpoint", "damaged", "--overwrite")
    assert snapshot(run) == before


@pytest.mark.parametrize("field, value", [("teacher", "alp-gmm"), ("n_envs", 4), ("student", "sac"), ("seed", 5)])  # fmt: skip
def test_edited_config_is_refused_on_resume(field, value, copy, capsys):
    run = copy()
    doc = yaml.safe_load((run / "config.yaml").read_text())
    doc["config"][field] = value
    (run / "config.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    before = snapshot(run)
    assert main(["train", "--resume", str(run), "--steps", "1024"]) == 2
    one_line_error(capsys, f"config {field}={value!r}", "a run keeps its")
    assert snapshot(run) == before


def test_a_run_without_checkpoint_says_how_to_start_again(copy, tmp_path, capsys):
    run = copy()
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
    finished, tmp_path, capsys, monkeypatch
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
    assert_same_training(finished, out)


def test_a_failed_status_write_leaves_no_temporary_file(copy, monkeypatch):
    run = copy()

    def full(tmp, path):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp))

    monkeypatch.setattr(atomic_files, "atomic_replace", full)
    before = snapshot(run)
    with pytest.raises(OSError):
        RunDir(run).set_status("crashed")
    assert snapshot(run) == before


# ---------------------------------------------------------------------- evaluate and report
def test_evaluate_and_report_check_their_inputs_first(copy, tmp_path, capsys):
    run = copy()
    missing = tmp_path / "missing" / "evals.csv"
    assert main(["evaluate", str(run), "--out", str(missing)]) == 2
    one_line_error(capsys, "--out=", "does not exist")
    truncate(run / "teacher.npz")
    assert main(["evaluate", str(run)]) == 2
    one_line_error(capsys, "teacher.json/.npz cannot be read")

    run = copy()
    truncate(run / "teacher.json")
    assert main(["report", str(run), "--no-video"]) == 2
    one_line_error(capsys, "teacher.json/.npz cannot be read")
    assert not (run / "report").exists()


def test_report_checks_that_it_can_render_before_its_plots(copy, monkeypatch, capsys):
    from acl3d import rendering

    def no_gl(*args, **kwargs):
        raise RuntimeError("OpenGL rendering failed with MUJOCO_GL=egl (EGLError: no device)")

    monkeypatch.setattr(rendering, "TrackRenderer", no_gl)
    run = copy()
    assert main(["report", str(run)]) == 2
    one_line_error(capsys, "OpenGL rendering failed", "MUJOCO_GL=egl")
    assert not (run / "report").exists()


# ---------------------------------------------------------------------- the run format
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
    latest, finished, copy, capsys
):
    run = copy()
    (run / "final_model.zip").unlink()
    RunDir(run).set_status("crashed")
    (run / "checkpoints" / "LATEST").write_text(latest)
    assert read_state(run, 512).checkpoint_step == 512  # a campaign resumes it, never restarts
    assert main(["train", "--resume", str(run)]) == 0
    assert "LATEST " in capsys.readouterr().err
    assert (run / "checkpoints" / "LATEST").read_text() == LAST
    assert_same_training(finished, run)


def test_an_edited_checkpoint_file_fails_its_hash_and_resume_falls_back(finished, copy, capsys):
    run = copy()
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
    assert_same_training(finished, run)

    run = copy()
    (run / "checkpoints" / FIRST / "manifest.json").unlink()
    with pytest.raises(DamagedCheckpoint, match="manifest.json is missing"):
        verify_checkpoint(run / "checkpoints" / FIRST, config)


def test_evaluate_on_a_crashed_run_falls_back_past_a_truncated_model(copy, capsys):
    run = copy()
    (run / "final_model.zip").unlink()
    RunDir(run).set_status("crashed")
    truncate(run / "checkpoints" / LAST / "model.zip")
    assert main(["evaluate", str(run), "--nb-test-episodes", "4"]) == 0
    out, err = capsys.readouterr()
    assert f"skipping damaged checkpoint {LAST}" in err and "model.zip" in err
    assert f"evaluating {run / 'checkpoints' / FIRST / 'model.zip'} (step 256)" in out


def test_running_with_a_dead_process_reads_as_crashed(copy, tmp_path):
    from acl3d.analysis.runs import load_runs

    run = copy()
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    (run / "status.json").write_text(json.dumps({"status": "running", "pid": gone.pid}))
    assert RunDir(run).status() == "crashed"
    state = read_state(run, 512)
    assert state.status == "crashed" and f"process {gone.pid} ended" in state.error
    assert load_runs(run.parent)[0].status == "crashed"
    RunDir(run).set_status("running")  # this process, alive
    assert RunDir(run).status() == "running"


def test_a_signal_during_a_status_write_is_held_until_the_write_is_whole(copy, monkeypatch):
    run = copy()
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


def test_provenance_is_carried_and_cleared_with_the_run(copy):
    from acl3d.run_format.documents import read_provenance, write_provenance

    run = copy()
    assert [s["event"] for s in read_provenance(run)] == ["start"]  # written at the start
    (run / "provenance.json").unlink()
    assert read_provenance(run) is None  # a run written before provenance.json
    write_provenance(run, [{"acl3d": "1.0", "cpu": "x86_64"}])
    assert read_provenance(run) == [{"acl3d": "1.0", "cpu": "x86_64"}]
    with pytest.raises(ValueError, match="provenance=\\[1\\]; valid: a list of mappings"):
        write_provenance(run, [1])
    RunDir(run).clear()
    assert not (run / "provenance.json").exists()
