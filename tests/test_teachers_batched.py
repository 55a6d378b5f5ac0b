"""Batched teacher calls: many tasks sampled and many episodes learnt in one call, and the
mixture teachers' background refits applied at a fixed episode (runs stay reproducible)."""

from __future__ import annotations

import multiprocessing

import numpy as np
import pytest
from test_teachers_classic import FAST, NAMES, SPACES, _reward

from acl3d.teachers import make
from acl3d.teachers.state_files import load_state, save_state

SPACE = SPACES["degenerate"]
GMM_FAST = {"fit_rate": 40, "potential_ks": [2, 3]}


def drive_batched(teacher, rounds: int, n: int, start: int = 0) -> np.ndarray:
    """`rounds` times: n tasks at once, then their n episodes at once."""
    out = []
    for r in range(start, start + rounds):
        tasks = teacher.sample_tasks(n)
        returns = [_reward(t, SPACE, r * n + j) for j, t in enumerate(tasks)]
        teacher.update_batch(tasks, returns, np.zeros(n, bool))
        out.append(tasks)
    return np.concatenate(out)


def play_singly(teacher, episodes: int) -> None:
    """`episodes` times: one task, then its episode."""
    for _ in range(episodes):
        t = teacher.sample_tasks(1)
        teacher.update_batch(t, [_reward(t[0], SPACE, teacher.nb_episodes)])


def restored_copy(teacher, tmp_path, name: str, params: dict):
    """A new teacher loaded from `teacher`'s saved state (other seed: the state decides)."""
    save_state(tmp_path / "t", teacher.state_dict())
    copy = make(name, SPACE, seed=0, **params)
    copy.load_state_dict(load_state(tmp_path / "t"))
    return copy


@pytest.mark.parametrize("name", NAMES)
def test_batches_are_in_bounds_reproducible_and_one_is_sample_task(name):
    a, b, c = (make(name, SPACE, seed=3, **FAST[name]) for _ in range(3))
    tasks = drive_batched(a, 12, 16)
    assert tasks.shape == (192, SPACE.dim) and tasks.dtype == np.float32
    assert np.all(tasks >= SPACE.low) and np.all(tasks <= SPACE.high)
    np.testing.assert_array_equal(tasks, drive_batched(b, 12, 16))
    assert a.nb_episodes == 192 and a.sample_tasks(0).shape == (0, SPACE.dim)
    for _ in range(60):  # n = 1 is exactly the one-task API
        twin = make_twin(c)
        t = c.sample_tasks(1)[0]
        np.testing.assert_array_equal(t, twin.sample_task())
        c.update_batch(t[None], [_reward(t, SPACE, c.nb_episodes)], None)


def make_twin(teacher):
    """A teacher in the same state (same class, parameters and RNG state)."""
    twin = make(teacher.name, SPACE, seed=0, **FAST[teacher.name])
    twin.load_state_dict(teacher.state_dict())
    return twin


@pytest.mark.parametrize("name", NAMES)
def test_update_batch_equals_one_update_per_episode(name):
    a, b = (make(name, SPACE, seed=1, **FAST[name]) for _ in range(2))
    _assert_batches_equal_single_updates(a, b)


@pytest.mark.parametrize("lag", [0, 7, 55])
def test_alp_gmm_batches_equal_single_updates_across_refit_events(lag):
    params = {**GMM_FAST, "nb_bootstrap": 25, "fit_lag": lag}
    a, b = (make("alp-gmm", SPACE, seed=4, **params) for _ in range(2))
    _assert_batches_equal_single_updates(a, b)
    assert a.bk["episodes"] == b.bk["episodes"] and a.bk["tasks_alps"] == b.bk["tasks_alps"]
    assert (a.r_min, a.r_max, a.raw_alps) == (b.r_min, b.r_max, b.raw_alps)


def _assert_batches_equal_single_updates(a, b):
    tasks = np.random.default_rng(0).uniform(SPACE.low, SPACE.high, (90, SPACE.dim))
    returns = np.array([_reward(t, SPACE, i) for i, t in enumerate(tasks)])
    successes = returns > 0.5
    for lo in range(0, 90, 30):
        a.update_batch(tasks[lo : lo + 30], returns[lo : lo + 30], successes[lo : lo + 30])
    for t, r, s in zip(tasks, returns, successes):
        b.episodic_update(t, r, bool(s))
    np.testing.assert_array_equal(a.sample_tasks(20), b.sample_tasks(20))


def test_random_batch_draws_the_same_tasks_as_single_calls():
    a, b = make("random", SPACE, seed=7), make("random", SPACE, seed=7)
    np.testing.assert_array_equal(a.sample_tasks(50), [b.sample_task() for _ in range(50)])


@pytest.mark.parametrize(
    "bad",
    [
        {"tasks": np.zeros((2, 3))},
        {"returns": [0.0, np.nan]},
        {"returns": [0.0]},
        {"successes": [0.5, 1.0]},
        {"tasks": np.full((2, SPACE.dim), 1e9)},
    ],
)
def test_bad_batch_raises_naming_it_and_changes_nothing(bad):
    teacher = make("alp-gmm", SPACE, seed=0, **GMM_FAST)
    before = teacher.state_dict()
    args = {"tasks": np.tile(SPACE.low, (2, 1)), "returns": [0.0, 1.0], "successes": [True, False]}
    args.update(bad)
    with pytest.raises(ValueError, match=next(iter(bad))):
        teacher.update_batch(**args)
    assert teacher.nb_episodes == 0 and teacher.state_dict()["rng"] == before["rng"]
    with pytest.raises(ValueError, match="n"):
        teacher.sample_tasks(-1)


@pytest.mark.parametrize("name", ["alp-gmm", "covar-gmm"])
def test_background_refit_applies_after_exactly_k_episodes_and_resumes_exactly(name, tmp_path):
    params = {**GMM_FAST, "fit_lag": 7}
    a, b = make(name, SPACE, seed=2, **params), make(name, SPACE, seed=2, **params)
    tasks = drive_batched(a, 10, 9)  # 90 episodes: fits started at 40 and 80
    assert a.bk["episodes"] == [47, 87]
    np.testing.assert_array_equal(tasks, drive_batched(b, 10, 9))
    drive_batched(a, 1, 3)  # 93 episodes: nothing pending
    for n_before in (82, 83):  # save while the refit of episode 80 is in flight
        c = make(name, SPACE, seed=2, **params)
        play_singly(c, n_before)
        d = restored_copy(c, tmp_path, name, params)
        for teacher in (c, d):
            play_singly(teacher, 10)
        assert c.bk["episodes"] == d.bk["episodes"] == [47, 87]
        np.testing.assert_array_equal(c.sample_tasks(30), d.sample_tasks(30))


def test_a_fit_lag_beyond_fit_rate_keeps_several_refits_in_flight_and_resumes_exactly(tmp_path):
    params = {**GMM_FAST, "fit_lag": 95}  # fits at 40, 80, 120, 160 applied at 135, 175, ...
    a, b = make("alp-gmm", SPACE, seed=3, **params), make("alp-gmm", SPACE, seed=3, **params)
    drive_batched(a, 11, 13)  # 143 episodes
    assert a.bk["episodes"] == [135] and len(a._in_flight) == 2
    play_singly(b, 125)  # b stops with three refits in flight, saved and restored
    assert len(b._in_flight) == 3
    c = restored_copy(b, tmp_path, "alp-gmm", params)
    for teacher in (b, c):
        play_singly(teacher, 60)
    assert b.bk["episodes"] == c.bk["episodes"] == [135, 175]
    np.testing.assert_array_equal(b.sample_tasks(30), c.sample_tasks(30))


def test_fit_lag_is_checked():
    with pytest.raises(ValueError, match="fit_lag"):
        make("alp-gmm", SPACE, seed=0, fit_rate=40, fit_lag=-1)


def _teach_with_refits() -> None:
    """A process's whole life: a teacher whose refits run in worker processes."""
    teacher = make("alp-gmm", SPACE, seed=1, **{**GMM_FAST, "fit_lag": 5})
    drive_batched(teacher, 6, 9)  # 54 episodes: the refit of episode 40 applied at 45
    assert teacher.bk["episodes"] == [45]


def test_a_process_started_by_multiprocessing_ends_after_its_refits():
    """A campaign attempt is such a process: it hung at exit, joining the refit workers before
    anything told them to stop."""
    process = multiprocessing.get_context("spawn").Process(target=_teach_with_refits)
    process.start()
    process.join(60)
    if process.exitcode is None:
        process.kill()
    assert process.exitcode == 0


def test_state_files_store_torch_tensors_as_arrays(tmp_path):
    """Torch weights in a teacher's state save as plain arrays (detached, on the CPU)."""
    import torch

    state = {
        "w": torch.arange(3.0, requires_grad=True),
        "nested": [torch.ones(2, dtype=torch.float64)],
    }
    save_state(tmp_path / "s", state)
    loaded = load_state(tmp_path / "s")
    np.testing.assert_array_equal(loaded["w"], np.arange(3.0, dtype=np.float32))
    assert loaded["nested"][0].dtype == np.float64
