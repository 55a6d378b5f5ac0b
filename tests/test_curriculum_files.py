"""The exported files that let others check a curriculum: every episode and the teacher's dump,
each within its byte budget (every k-th entry kept, and said, when a run is too long)."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from acl3d import results
from acl3d.analysis.curriculum_files import (
    EPISODES_FILE,
    RESULTS_BUDGET,
    read_episodes,
    read_teacher,
    shipped_bytes,
    write_episodes,
    write_teacher,
)
from acl3d.teachers.state_files import save_state


def _episode_log(run, n: int, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    cols = {
        "step": np.cumsum(rng.integers(50, 2000, n)),
        "worker": rng.integers(0, 16, n),
        "return": rng.normal(0, 100, n).round(4),
        "length": rng.integers(50, 2000, n),
        "success": rng.random(n) < 0.2,
        "truncated": rng.random(n) < 0.5,
        "stump_height": rng.uniform(0, 3, n).round(5),
        "obstacle_spacing": rng.uniform(0, 6, n).round(5),
    }
    run.mkdir(parents=True, exist_ok=True)
    with (run / "episodes.csv").open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(cols)
        writer.writerows(zip(*(v.astype(int) if v.dtype == bool else v for v in cols.values())))
    return cols


@pytest.mark.parametrize(("n", "budget"), [(300, 160_000), (20_000, 60_000)])
def test_episodes_within_budget_keep_every_kth(tmp_path, n, budget):
    cols = _episode_log(tmp_path / "run", n)
    dest = tmp_path / "out"
    dest.mkdir()
    written = write_episodes(tmp_path / "run", dest, budget)
    size = (dest / EPISODES_FILE).stat().st_size
    assert written["bytes"] == size <= budget and written["episodes"] == n
    got = read_episodes(dest)
    every = int(got["every"])
    assert every == written["every"] and int(got["episodes"]) == n
    assert (every == 1) == (n == 300)  # the long run is thinned, the short one is not
    np.testing.assert_array_equal(got["step"], cols["step"][::every])
    np.testing.assert_array_equal(got["return"], cols["return"][::every].astype(np.float32))
    np.testing.assert_array_equal(got["success"], cols["success"][::every])
    np.testing.assert_array_equal(got["length"], cols["length"][::every])
    task = np.column_stack([cols["stump_height"], cols["obstacle_spacing"]])[::every]
    np.testing.assert_array_equal(got["task"], task.astype(np.float32))
    assert list(got["task_names"]) == ["stump_height", "obstacle_spacing"]
    assert got["step"].dtype == np.int32 and got["return"].dtype == np.float32
    # a run directory reads the same columns from its CSV log
    raw = read_episodes(tmp_path / "run")
    np.testing.assert_array_equal(raw["step"], cols["step"])


@pytest.mark.parametrize(("budget", "every"), [(130, 8), (1000, 1), (1, 501)])
def test_the_stride_is_the_smallest_that_fits(budget, every):
    from acl3d.analysis.curriculum_files import _thinned

    tried = []

    def write(k):
        tried.append(k)
        return k, 1000 // k  # bytes fall as the stride grows

    assert _thinned(1000, budget, write) == (every, every)
    assert len(tried) < 30


def test_a_run_without_episodes_is_skipped_and_named_on_read(tmp_path):
    assert write_episodes(tmp_path, tmp_path) is None
    run = tmp_path / "run"  # finished before any episode ended (long episodes, short budget)
    _episode_log(run, 0)
    assert write_episodes(run, run)["episodes"] == 0
    assert read_episodes(run)["task"].shape == (0, 2)
    for write in (write_episodes, write_teacher):
        with pytest.raises(ValueError, match="budget=0; valid: an integer >= 1"):
            write(run, run, 0)
    with pytest.raises(ValueError, match="neither episodes.npz nor episodes.csv"):
        read_episodes(tmp_path)


def _dump(run, fits: int, episodes: int) -> None:
    rng = np.random.default_rng(1)
    save_state(
        run / "teacher",
        {
            "format": "acl3d-teacher-dump-1",
            "teacher": "alp-gmm",
            "names": ["stump_height", "obstacle_spacing"],
            "bounds": {"stump_height": [0.0, 3.0], "obstacle_spacing": [0.0, 6.0]},
            "low": np.zeros(2),
            "high": np.array([3.0, 6.0]),
            "shuffled": False,
            "sampled_tasks": rng.random((episodes, 2)),
            "train_tasks": rng.random((episodes, 2)),
            "train_returns": rng.random(episodes),
            "test_returns": rng.random(100),
            "periodical_samples": [rng.random((100, 2)) for _ in range(20)],
            "periodical_steps": np.arange(20, dtype=np.int64) * 100_000,
            "teacher_bk": {
                # one entry per episode, as ALP-GMM's (task, ALP) pairs
                "tasks_alps": [
                    rng.random(3).round(4).tolist() for _ in range(episodes)
                ],  # fmt: skip
                # one entry per refit
                "weights": [rng.dirichlet(np.ones(4)) for _ in range(fits)],
                "means": [rng.random((4, 2)) for _ in range(fits)],
                "covariances": [rng.random((4, 2, 2)) for _ in range(fits)],
                "episodes": [150 * (i + 1) for i in range(fits)],
            },
        },
    )


@pytest.mark.parametrize(("episodes", "budget"), [(300, 48_000), (6000, 32_000)])
def test_teacher_dump_without_duplicates_within_budget(tmp_path, episodes, budget):
    run, dest = tmp_path / "run", tmp_path / "out"
    run.mkdir()
    dest.mkdir()
    _dump(run, 40, episodes)
    written = write_teacher(run, dest, budget)
    sizes = sum((dest / f"teacher.{ext}").stat().st_size for ext in ("json", "npz"))
    assert written["bytes"] == sizes <= budget
    got = read_teacher(dest)  # load_state's format, as the run directory's dump
    for key in ("sampled_tasks", "train_tasks", "train_returns", "test_returns"):
        assert key not in got and key in got["left_out"]
    assert got["every"] == written["every"]
    bk = got["teacher_bk"]
    if episodes == 300:
        assert got["every"] == {} and len(bk["tasks_alps"]) == 300
    else:  # the per-episode list is thinned, every k-th entry kept
        every = got["every"]["teacher_bk/tasks_alps"]
        assert set(got["every"]) == {"teacher_bk/tasks_alps"} and every > 1
        assert len(bk["tasks_alps"]) == -(-episodes // every)
        original = read_teacher(run)["teacher_bk"]["tasks_alps"]
        np.testing.assert_array_equal(bk["tasks_alps"][1], np.float32(original[every]))
    # the refits' lists are kept whole and aligned: entry i of each is the same refit
    assert len(bk["means"]) == len(bk["weights"]) == len(bk["covariances"]) == 40
    assert bk["episodes"].tolist() == [150 * (i + 1) for i in range(40)]  # numbers: an array
    assert bk["means"][0].dtype == np.float32 and got["low"].dtype == np.float32
    assert len(got["periodical_samples"]) == len(got["periodical_steps"]) == 20
    assert got["bounds"] == {"stump_height": [0.0, 3.0], "obstacle_spacing": [0.0, 6.0]}
    assert write_teacher(tmp_path / "none", dest) is None


@pytest.mark.parametrize("episodes", [300, 0])
def test_a_teacher_dump_with_empty_histories_exports(tmp_path, episodes):
    """A short run: no refit yet (empty per-refit lists), maybe no episode either."""
    run, dest = tmp_path / "run", tmp_path / "out"
    run.mkdir()
    dest.mkdir()
    _dump(run, 0, episodes)
    written = write_teacher(run, dest, 48_000)
    bk = read_teacher(dest)["teacher_bk"]
    assert written["every"] == {} and len(bk["means"]) == 0
    assert len(bk["tasks_alps"]) == episodes


def test_the_shipped_results_stay_within_their_budget():
    total = sum(shipped_bytes(results.path(name)) for name in results.protocols())
    assert 0 < total < RESULTS_BUDGET
