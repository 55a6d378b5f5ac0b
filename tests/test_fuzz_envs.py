"""Property tests of the env inputs: valid input is accepted, invalid input is a ValueError naming
the parameter, and a rejected call leaves the env's state exactly as it was."""

import os

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from acl3d.bodies import make_body
from acl3d.envs.parkour_env import ParkourEnv
from acl3d.task_space import TaskSpace
from acl3d.terrain.parkour import BUILDABLE as PARKOUR_BUILDABLE

# the suite replays the same 40 examples per test (reproducible CI); a fuzzing session draws
# fresh ones: ACL3D_FUZZ_EXAMPLES=1000 python -m pytest tests/test_fuzz_envs.py
EXAMPLES = int(os.environ.get("ACL3D_FUZZ_EXAMPLES", "0"))
FUZZ = settings(
    max_examples=EXAMPLES or 40,
    derandomize=not EXAMPLES,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
STUMP_BUILDABLE = {"stump_height": (-5.0, 19.0), "obstacle_spacing": (0.0, 93.0)}

# what is never a real number: strings (numeric ones too), bools, None, complex, non-finite,
# ints beyond float range, containers
NOT_A_NUMBER = st.one_of(
    st.text(max_size=4),
    st.floats(-10, 10).map(str),
    st.booleans(),
    st.just(np.bool_(True)),
    st.none(),
    st.complex_numbers(max_magnitude=10),
    st.sampled_from([np.nan, np.inf, -np.inf, 10**400, -(10**400)]),
    st.dictionaries(st.text(max_size=2), st.integers(), max_size=1),
)


def as_number(draw, value: float):
    """The same number in one of the forms users pass: float, int, numpy scalar, 1-list."""
    form = draw(st.sampled_from(["float", "np.float64", "np.float32", "list", "array"]))
    return {
        "float": float(value),
        "np.float64": np.float64(value),
        "np.float32": np.float32(value),
        "list": [value],
        "array": np.array([value]),
    }[form]


@pytest.fixture(scope="module")
def stump():
    env = gym.make("acl3d/StumpTracks-v0", body="fish").unwrapped
    env.reset(seed=0)
    return env


@pytest.fixture(scope="module")
def parkour():
    env = gym.make("acl3d/Parkour-v0").unwrapped
    env.reset(seed=0)
    return env


def unchanged(env, call) -> str:
    """Run a call that must be rejected; return its message after checking nothing changed."""
    before = env.get_state()
    with pytest.raises(ValueError) as err:
        call()
    after = env.get_state()
    assert before.keys() == after.keys()
    assert all(np.array_equal(before[k], after[k]) for k in before)
    return str(err.value)


# ---------------------------------------------------------------------- tasks
@st.composite
def stump_tasks(draw):
    names = draw(st.sets(st.sampled_from(list(STUMP_BUILDABLE)), min_size=1))
    return {n: as_number(draw, draw(st.floats(*STUMP_BUILDABLE[n]))) for n in names}


@given(task=stump_tasks())
@FUZZ
def test_valid_stump_tasks_are_accepted(stump, task):
    stump.set_task(task)
    got = stump.get_task()
    for name, value in task.items():
        assert got[name] == float(np.asarray(value, dtype=np.float64).reshape(-1)[0])


UNBUILDABLE = {  # beyond what the generator builds (negative stump heights are flat ground)
    "stump_height": st.floats(19.3, 1e300),
    "obstacle_spacing": st.one_of(st.floats(93.4, 1e300), st.floats(-1e300, -1e-9)),
}


@given(
    name=st.sampled_from(list(STUMP_BUILDABLE)),
    data=st.data(),
    seed=st.one_of(st.none(), st.integers(0, 2**32)),
)
@FUZZ
def test_invalid_stump_tasks_are_rejected_and_change_nothing(stump, name, data, seed):
    value = data.draw(
        st.one_of(
            NOT_A_NUMBER,
            UNBUILDABLE[name],
            st.lists(st.floats(0, 1), min_size=2, max_size=3),
        )
    )
    message = unchanged(stump, lambda: stump.set_task({name: value}))
    assert name in message
    message = unchanged(stump, lambda: stump.reset(seed=seed, options={"task": {name: value}}))
    assert name in message


@given(
    vector=st.one_of(
        st.lists(st.floats(0, 3), min_size=0, max_size=4).filter(lambda v: len(v) != 2),
        st.tuples(st.floats(0, 3), NOT_A_NUMBER).map(list),
        st.just(np.array([1.0, 2.0], dtype=complex)),
        st.just(np.array([True, False])),
    )
)
@FUZZ
def test_invalid_task_vectors_are_rejected(stump, vector):
    assert "task vector" in unchanged(stump, lambda: stump.set_task(vector))


@st.composite
def parkour_tasks(draw):
    task = {}
    for name, (lo, hi) in PARKOUR_BUILDABLE.items():
        if draw(st.booleans()):
            if name == "input_vector":
                task[name] = draw(st.lists(st.floats(lo, hi), min_size=3, max_size=3))
            else:
                task[name] = as_number(draw, draw(st.floats(lo, hi)))
    return task


@given(task=parkour_tasks(), seed=st.integers(0, 2**31))
@settings(FUZZ, max_examples=15)
def test_valid_parkour_tasks_reset_and_step(parkour, task, seed):
    obs, _ = parkour.reset(seed=seed, options={"task": task})
    obs, *_ = parkour.step(np.zeros(parkour.action_space.shape))
    assert np.all(np.isfinite(obs))


@given(
    name=st.sampled_from(list(PARKOUR_BUILDABLE)),
    value=st.one_of(NOT_A_NUMBER, st.floats(101.0, 1e300), st.floats(-1e300, -1.01)),
)
@FUZZ
def test_invalid_parkour_tasks_are_rejected_and_change_nothing(parkour, name, value):
    if name == "input_vector" and not isinstance(value, str):
        value = [0.0, value, 0.0]
    assert name in unchanged(
        parkour, lambda: parkour.reset(seed=1, options={"task": {name: value}})
    )


# ---------------------------------------------------------------------- seeds, options, actions
@given(seed=st.one_of(st.booleans(), st.integers(max_value=-1), st.floats(), st.text(max_size=3)))
@FUZZ
def test_invalid_seeds_are_rejected_and_do_not_reseed(stump, seed):
    assert "seed" in unchanged(stump, lambda: stump.reset(seed=seed))


@given(key=st.text(min_size=1, max_size=6).filter(lambda k: k != "task"))
@FUZZ
def test_unknown_reset_options_are_rejected_with_a_valid_task_beside_them(stump, key):
    options = {"task": {"stump_height": 2.5}, key: 1}
    assert repr(key) in unchanged(stump, lambda: stump.reset(seed=3, options=options))


@given(action=st.lists(st.floats(-1e6, 1e6), min_size=4, max_size=4))
@FUZZ
def test_finite_actions_of_the_right_shape_are_accepted(stump, action):
    obs, reward, terminated, truncated, _ = stump.step(action)
    assert np.all(np.isfinite(obs)) and np.isfinite(reward)
    if terminated:
        stump.reset(seed=0)


@given(
    action=st.one_of(
        st.lists(st.floats(-1, 1), max_size=6).filter(lambda a: len(a) != 4),
        st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1), NOT_A_NUMBER).map(list),
        st.complex_numbers(max_magnitude=1).map(lambda z: np.full(4, z + 1e-3j)),
        st.just(np.zeros((2, 2))),
    )
)
@FUZZ
def test_invalid_actions_are_rejected_and_change_nothing(stump, action):
    assert "action" in unchanged(stump, lambda: stump.step(action))


# ---------------------------------------------------------------------- bodies, constructors
@given(
    body=st.sampled_from(
        [("spider", "nb_pairs_of_legs", 1, 8), ("millipede", "nb_of_bodies", 1, 12)]
    ),
    data=st.data(),
)
@FUZZ
def test_body_counts_accept_documented_integers_only(body, data):
    name, option, low, high = body
    n = data.draw(st.integers(low, high))
    assert len(make_body(name, **{option: n}).motors) > 0
    bad = data.draw(
        st.one_of(
            NOT_A_NUMBER,
            st.integers(high + 1, 10**6),
            st.integers(-(10**6), low - 1),
            st.floats(low, high).filter(lambda v: v != int(v)),
            st.integers(low, high).map(float),
        )
    )
    with pytest.raises(ValueError, match=option):
        make_body(name, **{option: bad})


@given(
    torque=st.one_of(
        NOT_A_NUMBER.filter(lambda v: v is not None),  # None: the body's default
        st.floats(-1e9, 0.999),
        st.floats(10_000.001, 1e300),
    ),
    planar=st.one_of(st.text(max_size=5), st.integers(0, 1), st.floats(0, 1)),
)
@FUZZ
def test_body_torque_and_planar_are_strict(torque, planar):
    assert make_body("wheel", motors_torque=50.0, planar=False).torque == 50.0
    with pytest.raises(ValueError, match="motors_torque"):
        make_body("wheel", motors_torque=torque)
    with pytest.raises(ValueError, match="planar"):
        make_body("wheel", planar=planar)


CONSTRUCTOR_ARGS = {
    "frame_skip": st.one_of(
        NOT_A_NUMBER.filter(lambda v: v is not None),  # None: the body's default
        st.integers(21, 100),
        st.integers(-5, 0),
        st.floats(),
    ),
    "width": st.one_of(NOT_A_NUMBER, st.integers(-5, 0), st.integers(8193, 10**5)),
    "height": st.one_of(NOT_A_NUMBER, st.floats(1, 100)),
    "quality": st.one_of(
        st.text(max_size=5).filter(lambda q: q not in ("fast", "high")), st.integers()
    ),
    "render_mode": st.text(max_size=5).filter(lambda m: m not in ("rgb_array", "human")),
    "planar": st.one_of(st.text(max_size=5), st.integers(0, 1)),
    "input_space": st.one_of(
        st.text(max_size=6).filter(lambda s: s not in ("medium", "easy", "full")), st.none()
    ),
    "end_on_death": st.one_of(st.text(max_size=5), st.integers(0, 1), st.none()),
    "movable_creepers": st.one_of(st.text(max_size=5), st.integers(0, 1)),
    "water_clip": st.one_of(NOT_A_NUMBER, st.floats(-1e9, -1e-9)),
}


@given(name=st.sampled_from(list(CONSTRUCTOR_ARGS)), data=st.data())
@FUZZ
def test_invalid_constructor_arguments_name_the_argument(name, data):
    value = data.draw(CONSTRUCTOR_ARGS[name])
    with pytest.raises(ValueError, match=name):  # the class: gym.make chokes on "%" itself
        ParkourEnv(**{name: value})


@given(frame_skip=st.integers(1, 20), planar=st.sampled_from([None, True, False]))
@settings(FUZZ, max_examples=4)
def test_valid_constructor_arguments_build(frame_skip, planar):
    env = gym.make("acl3d/StumpTracks-v0", frame_skip=frame_skip, planar=planar)
    obs, _ = env.reset(seed=0)
    assert env.unwrapped.model.opt.timestep == pytest.approx(0.02 / frame_skip)


@given(
    bounds=st.dictionaries(
        st.text(min_size=1, max_size=3),
        st.one_of(
            NOT_A_NUMBER,
            st.lists(st.one_of(st.floats(allow_nan=True), NOT_A_NUMBER), max_size=4),
            st.lists(st.lists(st.floats(-5, 5), max_size=3), max_size=3),
        ),
        max_size=3,
    )
)
@FUZZ
def test_task_space_bounds_are_valid_or_a_value_error(bounds):
    try:
        space = TaskSpace.from_bounds(bounds)
    except ValueError:
        return
    assert np.all(np.isfinite(space.low)) and np.all(space.low <= space.high)
