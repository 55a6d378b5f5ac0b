"""What the run-safety tests share: a tiny finished run (checkpoints at 256 and 512 steps) and
copies of it to damage (fixtures, registered by conftest.py), and comparisons of two runs'
training."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from acl3d.cli import main
from acl3d.training import students

TINY = [
    "--teacher", "random", "--student", "ppo", "--preset", "fast", "--n-envs", "2",
    "--nb-test-episodes", "4", "--env-kwarg", "max_episode_steps=50",
    "--student-param", "n_steps=128", "--student-param", "batch_size=128",
    "--eval-every", "256", "--checkpoint-every", "256", "--steps", "512",
    "--no-progress", "--quiet",
]  # fmt: skip
FIRST, LAST = "step_000000000256", "step_000000000512"


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory) -> Path:
    """A finished 512-step run with checkpoints at 256 and 512 steps."""
    out = tmp_path_factory.mktemp("finished") / "run"
    assert main(["train", *TINY, "--out", str(out)]) == 0
    return out


@pytest.fixture
def tiny_run_copy(tiny_run, tmp_path):
    def make() -> Path:
        run = tmp_path / f"copy{len(list(tmp_path.iterdir()))}"
        shutil.copytree(tiny_run, run)
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
