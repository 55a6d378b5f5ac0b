"""Property tests of what teachers accept: valid episodes are taken, anything else is a ValueError
naming the parameter, and a rejected call leaves the teacher exactly as it was."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from acl3d.teachers import make

SPACE = {"height": [0.0, 3.0], "spacing": [0.0, 6.0]}
LOW, HIGH = np.array([0.0, 0.0]), np.array([3.0, 6.0])
SMALL = {
    "random": {},
    "alp-gmm": {"fit_rate": 20, "potential_ks": [2, 3]},
    "covar-gmm": {"fit_rate": 20, "potential_ks": [2, 3]},
    "riac": {"max_region_size": 20, "nb_split_attempts": 5},
    "adr": {"queue_len": 2, "min_reward_thr": 0.1, "max_reward_thr": 0.5},
    "oracle": {"step_rate": 5, "reward_thr": 0.5},
    "robust-plr": {"buffer_size": 10},
    "accel": {"buffer_size": 10},
    "terrain-levels": {"nb_workers": 2, "promote_return": 0.5, "demote_return": 0.1},
}
FUZZ = settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


def _warm(name: str):
    """A teacher past its first fits/splits, so rejected calls could corrupt real state."""
    teacher = make(name, SPACE, seed=0, **SMALL[name])
    rng = np.random.default_rng(0)
    for _ in range(45):
        task = teacher.sample_task()
        teacher.episodic_update(task, float(rng.random()), bool(rng.random() < 0.3))
    return teacher


def _same(a, b) -> bool:
    """Deep equality of two state_dicts (dicts, lists, arrays, scalars; NaN == NaN)."""
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)
    return a == b or (a != a and b != b)


TEACHERS = {name: _warm(name) for name in SMALL}

finite_task = st.tuples(
    st.floats(0.0, 3.0, allow_nan=False), st.floats(0.0, 6.0, allow_nan=False)
).map(lambda t: np.array(t, dtype=np.float32))
sane_reward = st.floats(-1e6, 1e6, allow_nan=False)
bad_number = st.one_of(
    st.just(float("nan")),
    st.just(float("inf")),
    st.just(-float("inf")),
    st.sampled_from([1e308, -1e308, 1e13, 10**400]),
    st.sampled_from(["1.0", "nan", True, False, None, 1 + 2j, [1.0], b"1"]),
)
bad_task = st.one_of(
    st.tuples(bad_number, st.floats(0.0, 6.0)).map(list),
    st.tuples(st.floats(0.0, 3.0), bad_number).map(list),
    st.just([1e160, 1.0]),
    st.just(["1.0", "2.0"]),
    st.just([True, 1.0]),
    st.just([1.0]),
    st.just([1.0, 2.0, 3.0]),
    st.just("1.0, 2.0"),
    st.just(None),
    st.just([[1.0, 2.0]]),
    st.just([40.0, 2.0]),  # 10+ ranges outside the bounds
)
bad_success = st.sampled_from(["False", "True", 0, 1, None, 1.0, np.float64(1.0), [True]])


@pytest.mark.parametrize("name", list(SMALL))
@FUZZ
@given(task=finite_task, reward=sane_reward, success=st.booleans())
def test_valid_episodes_are_accepted(name, task, reward, success):
    teacher = TEACHERS[name]
    n = teacher.nb_episodes
    teacher.episodic_update(task, reward, success)
    assert teacher.nb_episodes == n + 1
    sample = teacher.sample_task()
    assert sample.shape == (2,) and np.all(sample >= LOW) and np.all(sample <= HIGH)


@pytest.mark.parametrize("name", list(SMALL))
@FUZZ
@given(data=st.data())
def test_invalid_episodes_raise_and_change_nothing(name, data):
    teacher = TEACHERS[name]
    which = data.draw(st.sampled_from(["task", "reward", "is_success"]))
    task, reward, success = np.array([1.0, 2.0], dtype=np.float32), 0.5, False
    if which == "task":
        task = data.draw(bad_task)
    elif which == "reward":
        reward = data.draw(bad_number)
    else:
        success = data.draw(bad_success)
    before = teacher.state_dict()
    with pytest.raises(ValueError, match=which):
        teacher.episodic_update(task, reward, success)
    assert _same(teacher.state_dict(), before)


@pytest.mark.parametrize("name", ["robust-plr", "accel"])
@FUZZ
@given(reward=bad_number)
def test_invalid_step_rewards_raise_and_change_nothing(name, reward):
    teacher = TEACHERS[name]
    before = teacher.state_dict()
    with pytest.raises(ValueError, match="reward"):
        teacher.step_update([0.0, 1.0], [0.0], reward, [0.0, 1.0], False)
    assert _same(teacher.state_dict(), before)


@FUZZ
@given(
    seed=st.one_of(
        st.just(True), st.just(-1), st.just("3"), st.just(3.0), st.just(1 + 0j), st.just([3])
    ),
    name=st.sampled_from(list(SMALL)),
)
def test_bad_seeds_are_rejected(seed, name):
    with pytest.raises(ValueError, match="seed"):
        make(name, SPACE, seed=seed, **SMALL[name])


@pytest.mark.parametrize(
    "bounds",
    [
        {"x": ["0", "1"]},
        {"x": [0, "1"]},
        {"x": [True, 1.0]},
        {"x": [0.0, float("nan")]},
        {"x": [1.0, 0.0]},
        {"x": [0.0, 10**400]},
        {},
        {"x": None},
    ],
)
def test_bad_bounds_are_rejected(bounds):
    with pytest.raises(ValueError):
        make("random", bounds, seed=0)


def test_a_rejected_absurd_task_leaves_later_fits_working():
    """issue 12: a [1e160, 1] task used to break every later GMM fit."""
    for name in ("alp-gmm", "covar-gmm"):
        teacher = make(name, SPACE, seed=1, fit_rate=10, potential_ks=[2])
        with pytest.raises(ValueError, match="task"):
            teacher.episodic_update([1e160, 1.0], 0.5)
        with pytest.raises(ValueError, match="reward"):
            teacher.episodic_update([1.0, 1.0], 1e308)
        for i in range(30):
            teacher.episodic_update(teacher.sample_task(), float(i % 3))
        assert teacher.nb_episodes == 30 and len(teacher.bk["episodes"]) == 3
