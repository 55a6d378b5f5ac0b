"""Exact resume and crash-safe run directories, on real training runs.

A run killed at any moment (SIGKILL of a real `acl3d train` process, or a fault injected while it
writes a checkpoint) and resumed from its last checkpoint must give the same evaluations, the same
training episodes, the same teacher records and the same final weights, bit for bit, as the run
that was never interrupted. Refused commands must leave the run directory untouched.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from stable_baselines3.common.callbacks import BaseCallback

from acl3d import atomic_files
from acl3d.cli import build_parser, main
from acl3d.cli.train import options_from_args
from acl3d.teachers.state_files import load_state
from acl3d.training import run_dir as run_dir_module
from acl3d.training import students, train
from acl3d.training.run_dir import RunDir

STEPS = 1024
CHECKPOINT_EVERY = 256
# Episodes (up to 100 steps) run across rollouts and checkpoints; ALP-GMM fits during the run.
COMMON = [
    "--env", "stump-tracks", "--preset", "fast", "--teacher", "alp-gmm", "--seed", "3",
    "--teacher-param", "fit_rate=20", "--teacher-param", "nb_bootstrap=10",
    "--env-kwarg", "max_episode_steps=100", "--nb-test-episodes", "4",
    "--eval-every", "512", "--checkpoint-every", str(CHECKPOINT_EVERY),
    "--periodical-samples-every", "256", "--steps", str(STEPS), "--no-progress", "--quiet",
]  # fmt: skip
SETUPS = {
    # N envs in the default (batched) env; one env behind a CurriculumEnv in a DummyVecEnv.
    "ppo-2": [
        "--student", "ppo", "--n-envs", "2",
        "--student-param", "n_steps=128", "--student-param", "batch_size=128",
    ],
    "sac-1": [
        "--student", "sac", "--n-envs", "1", "--vec-env", "dummy",
        "--student-param", "learning_starts=100", "--student-param", "batch_size=64",
    ],
}  # fmt: skip


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """Uninterrupted runs, one per setup (trained on first use)."""
    root = tmp_path_factory.mktemp("reference")
    done = {}

    def get(setup: str) -> Path:
        if setup not in done:
            out = root / setup
            assert main(["train", *COMMON, *SETUPS[setup], "--out", str(out)]) == 0
            done[setup] = out
        return done[setup]

    return get


def assert_same_run(a: Path, b: Path) -> None:
    """Same evaluations (wall time aside), episodes, teacher records and final weights."""
    for name in ("evals_tasks.csv", "episodes.csv"):
        assert (a / name).read_text() == (b / name).read_text(), name
    evals_a, evals_b = ((p / "evals.csv").read_text().splitlines() for p in (a, b))
    assert [r.rsplit(",", 1)[0] for r in evals_a] == [r.rsplit(",", 1)[0] for r in evals_b]
    assert len(evals_a) == 1 + STEPS // 512
    dump_a, dump_b = load_state(a / "teacher"), load_state(b / "teacher")
    for key in ("sampled_tasks", "train_returns", "test_returns", "periodical_samples"):
        for x, y in zip(np.atleast_1d(dump_a[key]), np.atleast_1d(dump_b[key]), strict=True):
            np.testing.assert_array_equal(x, y, err_msg=key)
    model_a = students.load(None, a / "final_model.zip")
    model_b = students.load(None, b / "final_model.zip")
    params_a, params_b = model_a.policy.state_dict(), model_b.policy.state_dict()
    for key in params_a:
        assert torch.equal(params_a[key], params_b[key]), key


def read_latest(run: Path) -> str | None:
    try:
        return (run / "checkpoints" / "LATEST").read_text().strip()
    except OSError:
        return None


@pytest.mark.parametrize("setup", list(SETUPS))
def test_sigkilled_run_resumes_bit_identically(setup, reference, tmp_path, checkout):
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "acl3d", "train", *COMMON, *SETUPS[setup], "--out", str(out)]
    proc = subprocess.Popen(cmd, cwd=checkout, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 300
        while read_latest(out) is None and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.005)
        time.sleep(np.random.default_rng().uniform(0, 0.1))  # any moment after the checkpoint
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL, err.decode()[-2000:]
    assert not (out / "final_model.zip").exists()  # really killed before the end
    assert main(["train", "--resume", str(out), "--no-progress"]) == 0
    assert_same_run(reference(setup), out)


class FaultInjected(Exception):
    pass


class FaultyDisk:
    """Counts the file syncs of the first checkpoint write, then fails the second checkpoint
    write at its k-th sync (k random): a crash between any two syncs or renames of a write."""

    def __init__(self, k_rng: np.random.Generator):
        self.rng, self.count, self.left, self.k = k_rng, 0, None, None
        self.counting = False

    def fsync(self, path) -> None:
        self.count += self.counting
        if self.left is not None:
            self.left -= 1
            if self.left == 0:
                raise FaultInjected(f"sync {self.k} of {self.count} of the second checkpoint")
        REAL_FSYNC(path)

    def write_checkpoint(self, run, step, write):
        self.counting = step == CHECKPOINT_EVERY
        if step == 2 * CHECKPOINT_EVERY:
            self.k = self.left = int(self.rng.integers(1, self.count + 1))
        try:
            return REAL_WRITE_CHECKPOINT(run, step, write)
        finally:
            self.counting, self.left = False, None


REAL_FSYNC = run_dir_module.fsync_path
REAL_WRITE_CHECKPOINT = RunDir.write_checkpoint


@pytest.mark.parametrize("trial", [0, 1])
def test_fault_while_writing_a_checkpoint_leaves_a_resumable_run(
    trial, reference, tmp_path, monkeypatch
):
    """A crash at a random point of a checkpoint write leaves LATEST on a complete checkpoint,
    and resuming from it is exact."""
    disk = FaultyDisk(np.random.default_rng(trial))
    monkeypatch.setattr(run_dir_module, "fsync_path", disk.fsync)
    monkeypatch.setattr(atomic_files, "fsync_path", disk.fsync)  # LATEST's write
    monkeypatch.setattr(RunDir, "write_checkpoint", lambda run, *a: disk.write_checkpoint(run, *a))
    args = build_parser().parse_args(["train", *COMMON, *SETUPS["sac-1"]])
    out = tmp_path / "faulty"
    with pytest.raises(FaultInjected):
        train(options_from_args(args), out=str(out))
    assert disk.count >= 8
    monkeypatch.undo()
    latest = RunDir(out).latest_checkpoint()  # complete, or this raises
    assert latest.name in (f"step_{CHECKPOINT_EVERY:012d}", f"step_{2 * CHECKPOINT_EVERY:012d}")
    assert train(resume=out, progress_bar=False).steps == STEPS
    assert_same_run(reference("sac-1"), out)


def test_refused_resume_changes_nothing(reference, tmp_path, capsys):
    run = tmp_path / "finished"
    shutil.copytree(reference("sac-1"), run)
    files = ("config.yaml", "config.json", "status.json", "evals.csv", "checkpoints/LATEST")
    before = {name: (run / name).read_bytes() for name in files}
    assert main(["train", "--resume", str(run)]) == 2
    assert f"the run already has {STEPS} steps" in capsys.readouterr().err
    assert main(["train", "--resume", str(run), "--teacher", "random"]) == 2
    assert "cannot change [--teacher] when resuming" in capsys.readouterr().err
    assert {name: (run / name).read_bytes() for name in files} == before


def test_run_killed_after_its_last_checkpoint_finishes_on_resume(reference, tmp_path):
    run = tmp_path / "almost"
    shutil.copytree(reference("sac-1"), run)
    (run / "final_model.zip").unlink()
    RunDir(run).set_status("running")
    evals = (run / "evals.csv").read_bytes()
    assert main(["train", "--resume", str(run), "--no-progress", "--quiet"]) == 0
    assert RunDir(run).status() == "finished"
    assert (run / "evals.csv").read_bytes() == evals  # nothing trained or evaluated again
    assert_same_run(reference("sac-1"), run)


def test_run_killed_while_publishing_its_last_checkpoint_resumes_exactly(reference, tmp_path):
    """Killed between publishing the last checkpoint and naming it in LATEST: the run resumes
    from the one before, after the final evaluation and the episodes up to the end were logged.
    The logs are cut back to that checkpoint, and the final evaluation, redone as the first of a
    fresh evaluation env (the uninterrupted run's second), is the same."""
    run = tmp_path / "publishing"
    shutil.copytree(reference("sac-1"), run)
    (run / "final_model.zip").unlink()
    RunDir(run).set_status("running")
    previous = f"step_{STEPS - CHECKPOINT_EVERY:012d}"
    (run / "checkpoints" / "LATEST").write_text(previous)
    assert main(["train", "--resume", str(run), "--no-progress", "--quiet"]) == 0
    assert read_latest(run) == f"step_{STEPS:012d}"
    assert_same_run(reference("sac-1"), run)


class CountingCallback(BaseCallback):
    """A user's own SB3 callback."""

    def __init__(self):
        super().__init__()
        self.steps = self.rollouts = 0
        self.saw_checkpoint = False

    def _on_step(self) -> bool:
        self.steps += 1
        return True

    def _on_rollout_end(self) -> None:
        self.rollouts += 1

    def _on_training_end(self) -> None:  # runs after the run's own final checkpoint
        self.saw_checkpoint = read_latest(Path(self.model.tensorboard_log).parent)


def test_user_callbacks_and_steps_rounded_to_whole_rollouts(tmp_path, capsys):
    cb = CountingCallback()
    result = train(
        env="stump-tracks",
        student="ppo",
        preset="fast",
        n_envs=2,
        vec_env="dummy",
        steps=300,
        student_params={"n_steps": 128, "batch_size": 128},
        env_kwargs={"max_episode_steps": 60},
        nb_test_episodes=4,
        out=str(tmp_path / "run"),
        progress_bar=False,
        callbacks=[cb],
    )
    err = capsys.readouterr().err
    assert "steps=300 is not a whole number of PPO rollouts of 256 steps: training 512" in err
    assert result.steps == 512 and RunDir(result.run_dir).read_section("resolved")["steps"] == 512
    assert (cb.steps, cb.rollouts) == (256, 2)
    assert cb.saw_checkpoint == "step_000000000512"
    with pytest.raises(ValueError, match="not a stable_baselines3 BaseCallback"):
        train(out=str(tmp_path / "bad"), callbacks=[print])
    assert not (tmp_path / "bad").exists()
