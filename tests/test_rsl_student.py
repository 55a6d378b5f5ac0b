"""The rsl-ppo student: a short run writes a complete run directory, a run killed after a
checkpoint resumes bit for bit, and its saved policy plays through `render --model`'s loader."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

pytest.importorskip("rsl_rl")

from acl3d import provenance  # noqa: E402
from acl3d.cli import main  # noqa: E402
from acl3d.teachers.state_files import load_state  # noqa: E402
from acl3d.training import students  # noqa: E402
from acl3d.training.config import TrainConfig, validate  # noqa: E402
from acl3d.training.torch_student import presets  # noqa: E402
from acl3d.training.torch_student.rsl_ppo import SavedPolicy  # noqa: E402

STEPS = 768
COMMON = [
    "--student", "rsl-ppo", "--env", "stump-tracks", "--teacher", "alp-gmm", "--seed", "2",
    "--teacher-param", "fit_rate=10", "--teacher-param", "nb_bootstrap=5",
    "--env-kwarg", "max_episode_steps=60", "--n-envs", "4", "--nb-test-episodes", "4",
    "--student-param", "num_steps_per_env=32", "--student-param", "hidden_dims=[32, 32]",
    "--eval-every", "256", "--checkpoint-every", "128", "--periodical-samples-every", "256",
    "--steps", str(STEPS), "--no-progress", "--quiet",
]  # fmt: skip


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("rsl") / "reference"
    assert main(["train", *COMMON, "--out", str(out)]) == 0
    return out


def test_short_run_writes_the_run_directory(reference):
    for name in ("config.yaml", "episodes.csv", "evals.csv", "evals_tasks.csv", "final_model.zip"):
        assert (reference / name).exists(), name
    assert any((reference / "tb").rglob("events.out.tfevents.*"))
    evals = (reference / "evals.csv").read_text().splitlines()
    assert len(evals) == 1 + STEPS // 256
    assert len((reference / "episodes.csv").read_text().splitlines()) > 10  # episodes of <= 60
    policy = SavedPolicy(reference / "final_model.zip")
    actions = policy(np.zeros((3, policy.observation_size), np.float32))
    assert actions.shape == (3, 4) and np.all(np.abs(actions) <= 1)


def test_provenance_records_the_machine_and_device(reference):
    (segment,) = provenance.load(reference)
    assert (segment["event"], segment["step"], segment["end"]) == ("start", 0, "finished")
    assert segment["end_step"] == STEPS
    assert segment["device"] == "cpu, vec_env batched"
    for key in ("acl3d", "cpu_model", "host", "python", "torch", "mujoco", "numpy"):
        assert segment[key], key


def _read_latest(run: Path) -> str | None:
    try:
        return (run / "checkpoints" / "LATEST").read_text().strip()
    except OSError:
        return None


def test_sigkilled_run_resumes_bit_identically(reference, tmp_path, checkout):
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "acl3d", "train", *COMMON, "--out", str(out)]
    proc = subprocess.Popen(cmd, cwd=checkout, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 300
        while _read_latest(out) is None and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.005)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL, err.decode()[-2000:]
    assert not (out / "final_model.zip").exists()
    assert main(["train", "--resume", str(out), "--no-progress", "--quiet"]) == 0
    killed, resumed = provenance.load(out)  # the killed segment has no end
    assert "end" not in killed and killed["event"] == "start"
    assert resumed["event"] == "resume" and resumed["end"] == "finished" and resumed["step"] > 0
    assert provenance.interruptions([killed, resumed]) == 1
    for name in ("evals_tasks.csv", "episodes.csv"):
        assert (reference / name).read_text() == (out / name).read_text(), name
    dump_a, dump_b = load_state(reference / "teacher"), load_state(out / "teacher")
    for key in ("sampled_tasks", "train_returns", "test_returns"):
        for x, y in zip(np.atleast_1d(dump_a[key]), np.atleast_1d(dump_b[key]), strict=True):
            np.testing.assert_array_equal(x, y, err_msg=key)
    a, b = (
        torch.load(p / "checkpoints" / _read_latest(p) / "student.pt") for p in (reference, out)
    )
    for key, value in a["student"]["actor_state_dict"].items():
        assert torch.equal(value, b["student"]["actor_state_dict"][key]), key


def _evals(run: Path) -> list[list[str]]:
    """evals.csv without its wall-time column."""
    return [line.split(",")[:-1] for line in (run / "evals.csv").read_text().splitlines()]


def test_evaluations_played_together_survive_a_kill_after_a_checkpoint(reference, tmp_path):
    """Three evaluations wait for one pass (`--eval-together 3`): their results equal those of
    evaluations played when due, and a run killed while two were waiting (the checkpoint of step
    640 keeps their policies) plays them after its resume with the same results."""
    out = tmp_path / "together"
    assert main(["train", *COMMON, "--eval-together", "3", "--out", str(out)]) == 0
    assert (out / "evals_tasks.csv").read_text() == (reference / "evals_tasks.csv").read_text()
    assert _evals(out) == _evals(reference)
    state = torch.load(out / "checkpoints" / "step_000000000640" / "student.pt")
    assert [p["step"] for p in state["pending_evaluations"]] == [256, 512]
    (out / "checkpoints" / "LATEST").write_text("step_000000000640\n")  # killed after it
    (out / "final_model.zip").unlink()
    assert main(["train", "--resume", str(out), "--no-progress", "--quiet"]) == 0
    assert (out / "evals_tasks.csv").read_text() == (reference / "evals_tasks.csv").read_text()
    assert _evals(out) == _evals(reference)
    assert main(["train", *COMMON, "--eval-together", "0", "--out", str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()
    with pytest.raises(ValueError, match=r"eval_together=65; valid: an integer in \[1, 64\]"):
        validate(TrainConfig(student="rsl-ppo", eval_together=65), on_this_machine=False)
    with pytest.raises(ValueError, match="eval_together=2; valid: None or 1 with an SB3"):
        validate(TrainConfig(student="ppo", eval_together=2), on_this_machine=False)
    with pytest.raises(ValueError, match="vec_env='warp'; valid: auto, batched, dummy or sub"):
        validate(TrainConfig(student="ppo", vec_env="warp"), on_this_machine=False)


def test_evaluate_reproduces_the_runs_own_last_evaluation(reference, tmp_path, capsys):
    """`acl3d evaluate RUN` plays the policy file as the run evaluated it; a checkpoint's
    policy and a bare policy file (with --env) evaluate too."""
    out = tmp_path / "episodes.csv"
    assert main(["evaluate", str(reference), "--out", str(out)]) == 0
    own = [r.split(",") for r in (reference / "evals_tasks.csv").read_text().splitlines()[1:]]
    last = [row[2:4] for row in own if row[0] == str(STEPS)]
    assert [r.split(",")[1:3] for r in out.read_text().splitlines()[1:]] == last
    printed = capsys.readouterr().out
    assert f"(step {STEPS})" in printed and f"own evaluation at step {STEPS}" in printed
    checkpoint = reference / "checkpoints" / "step_000000000640" / "model.zip"
    assert (
        main(["evaluate", str(checkpoint), "--env", "stump-tracks", "--nb-test-episodes", "4"]) == 0
    )
    assert "(step 640)" in capsys.readouterr().out


def test_a_run_killed_after_its_last_checkpoint_finishes_on_resume(reference, tmp_path):
    """The checkpoint of the last step holds that step's frozen policy among those waiting
    (`--eval-together 4`: none played yet); killed before the final pass, the run resumes,
    plays them once, writes no second checkpoint and finishes."""
    out = tmp_path / "late"
    assert main(["train", *COMMON, "--eval-together", "4", "--out", str(out)]) == 0
    last = out / "checkpoints" / f"step_{STEPS:012d}"
    state = torch.load(last / "student.pt")
    assert [p["step"] for p in state["pending_evaluations"]] == [256, 512, 768]
    (out / "final_model.zip").unlink()  # killed during the final pass
    status = json.loads((out / "status.json").read_text())
    dead = {"status": "running", "pid": 2**22 + 7, "host": status["host"]}  # no such process
    (out / "status.json").write_text(json.dumps(dead))
    assert main(["train", "--resume", str(out), "--no-progress", "--quiet"]) == 0
    assert (out / "evals_tasks.csv").read_text() == (reference / "evals_tasks.csv").read_text()
    assert _evals(out) == _evals(reference)
    assert (out / "final_model.zip").exists()


def _episodes_until(run: Path, step: int | None) -> list[str]:
    rows = (run / "episodes.csv").read_text().splitlines()[1:]
    return [row for row in rows if step is None or int(row.split(",")[0]) <= step]


def test_a_forgetting_student_starts_afresh_and_resumes_exactly(reference, tmp_path):
    """`--reset-student-every 384`: the run is the reference's until the reset, another after
    it, and a run stopped at 512 steps and resumed is the uninterrupted one."""
    whole, parts = tmp_path / "whole", tmp_path / "parts"
    reset = [*COMMON, "--reset-student-every", "384"]
    assert main(["train", *reset, "--out", str(whole)]) == 0
    shorter = [*reset, "--out", str(parts)]
    shorter[shorter.index("--steps") + 1] = "512"
    assert main(["train", *shorter]) == 0
    assert main(["train", "--resume", str(parts), "--steps", str(STEPS), "--quiet"]) == 0
    assert _episodes_until(whole, None) == _episodes_until(parts, None)
    assert _episodes_until(whole, 384) == _episodes_until(reference, 384)
    assert _episodes_until(whole, None) != _episodes_until(reference, None)


def test_a_teacher_learning_from_steps_gets_each_episode_after_its_steps(tmp_path, monkeypatch):
    """Robust PLR with rsl-ppo on the CPU batched env: each episode reaches the teacher after its
    steps, whose rewards sum to its return (its score, the positive value loss, comes from them
    and rsl-ppo's critic, asked once for the episodes ending together: the same values, bit
    for bit, as one call an episode), and a run stopped at 512 steps and resumed is the
    uninterrupted one (the teacher's open step buffers included)."""
    from acl3d.teachers.plr import RobustPLR

    scored, asked_together = [], []
    original = RobustPLR._episode_score

    def score(self, index, reward):
        steps = self._finished[0] if self._finished else None
        scored.append((None if steps is None else float(np.sum(steps[1])), reward))
        if self._values:
            alone = self.value_estimator(steps[0])
            asked_together.append(np.array_equal(self._values[0], alone))
        return original(self, index, reward)

    monkeypatch.setattr(RobustPLR, "_episode_score", score)
    alp_gmm = ("alp-gmm", "--teacher-param", "fit_rate=10", "nb_bootstrap=5")
    plr = [a for a in COMMON if a not in alp_gmm]
    plr[plr.index("--teacher") + 1 : plr.index("--teacher") + 1] = ["robust-plr"]
    whole, parts = tmp_path / "whole", tmp_path / "parts"
    assert main(["train", *plr, "--out", str(whole)]) == 0
    resolved = yaml.safe_load((whole / "config.yaml").read_text())["resolved"]
    assert resolved["exclude_exploratory"] is True  # its new levels stay out of the updates
    assert len(scored) > 10
    assert all(total is not None and abs(total - ret) < 1e-3 for total, ret in scored), scored
    assert asked_together and all(asked_together)  # episodes ending at the same step
    shorter = [*plr, "--out", str(parts)]
    shorter[shorter.index("--steps") + 1] = "512"
    assert main(["train", *shorter]) == 0
    assert main(["train", "--resume", str(parts), "--steps", str(STEPS), "--quiet"]) == 0
    assert _episodes_until(whole, None) == _episodes_until(parts, None)


def test_its_evaluations_are_announced_before_it_trains(tmp_path, capsys):
    tasks = tmp_path / "tasks.json"
    tasks.write_text(json.dumps([{"stump_height": h, "obstacle_spacing": 3.0} for h in (0, 1)]))
    argv = ["train", "--student", "rsl-ppo", "--teacher", "random", "--n-envs", "2",
            "--student-param", "num_steps_per_env=16", "--student-param", "hidden_dims=[8]",
            "--env-kwarg", "max_episode_steps=20", "--test-set", str(tasks), "--steps", "32",
            "--no-progress", "--quiet", "--out", str(tmp_path / "run")]  # fmt: skip
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert f"test_set={tasks}: a file of 2 test tasks (nb_test_episodes=25" in err
    assert "one evaluation, at the end of training" in err


def test_presets_and_checks():
    assert students.is_on_policy("rsl-ppo")
    fast = students.hyperparameters("rsl-ppo", "fast", 16)
    assert fast["num_steps_per_env"] == 128 and fast["hidden_dims"] == [64, 64]
    assert students.collection_steps("rsl-ppo", fast, 16) == 2048
    bench = presets.hyperparameters("benchmark", 4096)
    assert bench["num_steps_per_env"] == 24 and bench["hidden_dims"] == [256, 128, 64]
    with pytest.raises(ValueError, match=r"student_params\['learning_rate'\]=-1"):
        presets.hyperparameters("fast", 16, {"learning_rate": -1})
    with pytest.raises(ValueError, match="unknown student parameter 'n_steps' for rsl-ppo"):
        presets.hyperparameters("fast", 16, {"n_steps": 5})
    with pytest.raises(ValueError, match=r"hidden_dims"):
        presets.hyperparameters("fast", 16, {"hidden_dims": [0]})


def test_min_noise_std_is_checked_against_the_initial_noise():
    assert presets.hyperparameters("fast", 16, {"min_noise_std": 0.1})["min_noise_std"] == 0.1
    with pytest.raises(ValueError, match=r"student_params\['min_noise_std'\]=-0.1"):
        presets.hyperparameters("fast", 16, {"min_noise_std": -0.1})
    with pytest.raises(ValueError, match=r"min_noise_std'\]=1.0.*\[0, init_noise_std\)"):
        presets.hyperparameters("fast", 16, {"min_noise_std": 1.0})


@pytest.mark.parametrize("floor", [0.0, 0.1])
def test_the_action_noise_stays_above_its_floor(floor, tmp_path):
    """A std the updates drove below `min_noise_std` samples, scores and saves at the floor;
    without a floor it samples at its own value."""
    from acl3d.training.torch_student.rsl_ppo import RslPPO

    n, obs_size = 4096, 3
    params = presets.hyperparameters("fast", n, {"min_noise_std": floor})
    torch.manual_seed(0)
    student = RslPPO(params, obs_size, 2, n, "cpu", -10 * torch.ones(2), 10 * torch.ones(2))
    with torch.no_grad():
        student.alg.actor.distribution.std_param.fill_(0.01)
    obs = torch.zeros(n, obs_size)
    with torch.inference_mode():
        spread = student.act(obs).std(0)
    assert torch.allclose(spread, torch.full((2,), max(floor, 0.01)), rtol=0.05)
    assert student.action_std == pytest.approx(max(floor, 0.01))  # what TensorBoard logs
    student.save_policy(tmp_path / "policy.zip")
    saved = SavedPolicy(tmp_path / "policy.zip")
    assert saved.spec["min_noise_std"] == floor
    torch.manual_seed(1)
    sampled = torch.as_tensor(saved(obs.numpy(), deterministic=False))
    mean = torch.as_tensor(saved(obs.numpy()))
    assert torch.allclose((sampled - mean).std(0), torch.full((2,), max(floor, 0.01)), rtol=0.05)


def test_each_student_gets_its_own_default_number_of_envs(tmp_path):
    """16 envs fill 2 cores for SB3; rsl-ppo trains fastest on 64 CPU worlds and fills a GPU
    from 4,096. A run records the number, so a later change of default never changes it."""
    assert TrainConfig(student="ppo").effective_n_envs == 16
    assert TrainConfig().effective_n_envs == 64
    assert TrainConfig(student="rsl-ppo", device="cuda").effective_n_envs == 4096
    assert TrainConfig(student="rsl-ppo", n_envs=8).effective_n_envs == 8
    assert TrainConfig(student="sac", device="cuda").effective_n_envs == 16
    validate(TrainConfig(student="rsl-ppo"))
    out = tmp_path / "run"
    options = ["--steps", "128", "--nb-test-episodes", "4", "--no-progress", "--quiet"]
    limits = ["--env-kwarg", "max_episode_steps=20", "--student-param", "num_steps_per_env=2"]
    assert main(["train", "--student", "rsl-ppo", "--out", str(out), *options, *limits]) == 0
    assert yaml.safe_load((out / "config.yaml").read_text())["config"]["n_envs"] == 64


@pytest.mark.parametrize("every_step", [False, True])  # True: as on a GPU
def test_the_update_learns_from_each_steps_normalised_and_bootstrapped_rewards(every_step):
    """`record` keeps the env's rewards and the update normalises them and bootstraps the
    episodes the time limit cut: the rewards it learns from are those that normalising and
    bootstrapping at every step give, bit for bit (the critic does not change in a rollout),
    whether the critic runs at the steps that cut an episode (the CPU) or at every step."""
    from acl3d.training.torch_student.rsl_ppo import RewardNormaliser, RslPPO

    n, steps, obs_size = 5, 12, 7
    params = presets.hyperparameters("fast", n, {"num_steps_per_env": steps})
    torch.manual_seed(0)
    student = RslPPO(params, obs_size, 2, n, "cpu", -torch.ones(2), torch.ones(2))
    student.bootstraps_every_step = every_step
    reference = RewardNormaliser(n, params["gamma"], "cpu")
    g = torch.Generator().manual_seed(1)
    expected, learnt = [], []
    with torch.inference_mode():
        for t in range(steps):
            obs = torch.randn(n, obs_size, generator=g)
            student.act(obs)
            rewards = torch.randn(n, generator=g) * 10
            terminated = torch.rand(n, generator=g) < 0.2
            truncated = (torch.rand(n, generator=g) < 0.3) if t % 3 else torch.zeros(n, dtype=bool)
            final = torch.randn(n, obs_size, generator=g)
            student.record(rewards, terminated, truncated, final)
            r = reference(rewards, terminated | truncated)
            cut = truncated & ~terminated
            values = student.alg.value(final)
            expected.append(torch.where(cut, r + params["gamma"] * values, r))
    assert any(bool((e != 0).any()) for e in expected)
    returns = student.alg.compute_returns
    student.alg.compute_returns = lambda last: (
        learnt.append(student.alg.storage.rewards.clone()),
        returns(last),
    )
    student.update(torch.randn(n, obs_size, generator=g))
    assert torch.equal(learnt[0].view(steps, n), torch.stack(expected))
    assert torch.equal(student.rewards.var, reference.var)
