"""Evaluation and the curriculum's periodical samples have no side effect on training, even
with sampled (stochastic) actions.

Two runs with the same seed that differ only in their evaluation schedule train the same policy:
the same episodes row for row and the same weights. Each evaluation draws from its own streams,
seeded the same way every time, so an evaluation depends only on the weights it evaluates; a run
interrupted after an evaluation and resumed is still the uninterrupted one.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from stable_baselines3.common.callbacks import BaseCallback

from acl3d.cli import main
from acl3d.run_format.tables import read_csv
from acl3d.training import students, train
from acl3d.training.run_dir import RunDir

STEPS = 1024
RUN = dict(
    env="stump-tracks",
    student="ppo",
    preset="fast",
    teacher="random",
    seed=5,
    n_envs=2,
    steps=STEPS,
    student_params={"n_steps": 128, "batch_size": 128},
    env_kwargs={"max_episode_steps": 100},
    nb_test_episodes=4,
    eval_stochastic=True,
    checkpoint_every=256,
    progress_bar=False,
    verbose=0,
)


class StopAt(BaseCallback):
    """Interrupts the run at the first rollout start at or after `step` (after its checkpoint)."""

    def __init__(self, step: int):
        super().__init__()
        self.step = step

    def _on_step(self) -> bool:
        return True

    def _on_rollout_start(self) -> None:
        if self.model.num_timesteps >= self.step:
            raise KeyboardInterrupt("stopped by the test")


def weights(run: Path) -> dict[str, torch.Tensor]:
    return students.load(None, run / "final_model.zip").policy.state_dict()


def evaluations(run: Path) -> dict[int, list[float]]:
    rows = read_csv(RunDir(run).evals_tasks_csv)
    out: dict[int, list[float]] = {}
    for step, ret in zip(rows["step"], rows["return"]):
        out.setdefault(int(step), []).append(ret)
    return out


@pytest.fixture(scope="module")
def often(tmp_path_factory) -> Path:
    """The reference: a stochastic evaluation every 256 steps."""
    out = tmp_path_factory.mktemp("often") / "run"
    train(RUN, eval_every=256, out=str(out))
    return out


def test_evaluation_schedule_does_not_change_training(often, tmp_path):
    """Evaluating every 512 instead of every 256 steps, interrupted at 768 (after the
    evaluation at 512) and resumed: the same episodes and final weights as the reference."""
    out = tmp_path / "rarely"
    with pytest.raises(KeyboardInterrupt):
        train(RUN, eval_every=512, out=str(out), callbacks=[StopAt(768)])
    assert RunDir(out).latest_checkpoint().name == f"step_{768:012d}"
    assert train(resume=out, progress_bar=False).steps == STEPS
    assert (often / "episodes.csv").read_text() == (out / "episodes.csv").read_text()
    ref, got = weights(often), weights(out)
    for key in ref:
        assert torch.equal(ref[key], got[key]), key
    # an evaluation depends only on the weights: the same returns at the steps both evaluated
    ref_evals, got_evals = evaluations(often), evaluations(out)
    assert sorted(ref_evals) == [256, 512, 768, 1024] and sorted(got_evals) == [512, 1024]
    for step in got_evals:
        assert got_evals[step] == ref_evals[step], step
    # `acl3d evaluate` replays the run's own last evaluation, sampled actions included
    assert main(["evaluate", str(out), "--out", str(tmp_path / "again.csv")]) == 0
    assert read_csv(tmp_path / "again.csv")["return"] == got_evals[STEPS]
    # and the actions really were sampled: a deterministic evaluation returns otherwise
    det = tmp_path / "deterministic"
    train(RUN, eval_every=512, eval_stochastic=False, steps=512, out=str(det))
    assert evaluations(det)[512] != got_evals[512]
    assert not np.array_equal(evaluations(det)[512], ref_evals[512])


def test_a_shorter_budget_is_the_start_of_a_longer_one(often, tmp_path):
    """Only the budget differs, and with it the default cadence of the periodical curriculum
    samples (a tenth of the budget): the shorter run's episodes are the longer run's first."""
    out = tmp_path / "shorter"
    train(RUN, eval_every=256, steps=STEPS // 2, out=str(out))
    short = (out / "episodes.csv").read_text().splitlines()
    assert len(short) > 2
    assert (often / "episodes.csv").read_text().splitlines()[: len(short)] == short
