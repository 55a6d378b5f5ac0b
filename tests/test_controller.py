"""TeacherController, DimensionsShuffler and curriculum profiles (expert knowledge:
test_expert_knowledge.py; test sets: test_test_sets.py)."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest
import torch
from test_teachers_classic import FAST, NAMES

from acl3d import envs
from acl3d.curriculum_profile import CurriculumProfile
from acl3d.envs.profiles import HEXAGON_TRACKS, PARKOUR, STUMP_TRACKS
from acl3d.task_space import TaskSpace
from acl3d.teachers import TEACHERS, load_state
from acl3d.teachers.controller import TeacherController
from acl3d.teachers.dimensions_shuffler import DimensionsShuffler

torch.set_num_threads(1)

STUMPS = {"stump_height": [0.0, 3.0], "obstacle_spacing": [0.0, 6.0]}
MIXED = {"a": [-1.0, 2.0], "const": [0.5, 0.5], "b": [0.0, 10.0, 2]}
FAST_GAN = {"pretrain_iters": 3, "nb_pretrain_samples": 32, "gan_train_iters": 3, "update_size": 4}


def play(controller: TeacherController, n: int, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    tasks = []
    for _ in range(n):
        task = controller.sample_task()
        tasks.append(task)
        for s in range(2):
            controller.record_step(task, None, float(task[0]), task, s == 1)
        controller.record_episode(
            task, float(rng.normal(100, 100)), 2, bool(rng.random() < 0.5), initial_obs=task
        )
    return tasks


# ---------------------------------------------------------------------- DimensionsShuffler
def test_shuffler_is_a_bijection_of_the_box():
    low, high = np.array([0.0, -3.0, 2.0]), np.array([3.0, 3.0, 2.0])
    sh = DimensionsShuffler(low, high, cuttings=4, seed=1)
    rng = np.random.default_rng(0)
    x = rng.uniform(low, high, size=(2000, 3))
    edges = low + np.arange(5)[:, None] * (high - low) / 4  # every interval boundary and both ends
    for points in (x, edges):
        np.testing.assert_allclose(sh.inverse(sh.forward(points)), points, atol=1e-12)
        np.testing.assert_allclose(sh.forward(sh.inverse(points)), points, atol=1e-12)
    y = sh.forward(x)
    assert np.all(y >= low) and np.all(y <= high)
    np.testing.assert_array_equal(y[:, 2], 2.0)  # constant dimension untouched
    # interval i of dimension d lands in interval perms[d, i], same offset
    mids = low[:2] + (np.arange(4)[:, None] + 0.5) * (high - low)[:2] / 4
    landed = np.floor(
        (sh.forward(np.c_[mids, np.full(4, 2.0)])[:, :2] - low[:2]) / ((high - low)[:2] / 4)
    )
    np.testing.assert_array_equal(landed.T, sh.perms[:2])
    assert not np.array_equal(sh.perms[0], np.arange(4)) or not np.array_equal(
        sh.perms[1], np.arange(4)
    )


def test_shuffler_survives_float32_round_trips_near_boundaries():
    sh = DimensionsShuffler([0.0], [3.0], cuttings=4, seed=3)
    x = np.array([[0.75 - 1e-9], [0.75], [0.75 + 1e-9], [1.5 - 1e-7], [3.0]])
    back = sh.inverse(sh.forward(x).astype(np.float32).astype(np.float64))
    np.testing.assert_allclose(back, x, atol=1e-5)


def test_shuffler_seeded():
    a, b = (
        DimensionsShuffler([0] * 5, [1] * 5, seed=4),
        DimensionsShuffler([0] * 5, [1] * 5, seed=4),
    )
    np.testing.assert_array_equal(a.perms, b.perms)
    with pytest.raises(ValueError, match="cuttings"):
        DimensionsShuffler([0], [1], cuttings=0)


# ---------------------------------------------------------------------- training records
@pytest.mark.parametrize(
    "profile, ret, expected",
    [
        (STUMP_TRACKS, 100.0, 0.5),
        (STUMP_TRACKS, -1000.0, 0.0),
        (HEXAGON_TRACKS, 1000.0, 1.0),
        (PARKOUR, 105.0, 0.5),
        (None, 50.0, 0.75),  # an environment without a profile: bounds [-100, 100]
        (None, -100.0, 0.0),
    ],
)
def test_reward_scaling_per_environment(profile, ret, expected):
    c = TeacherController("random", STUMPS, 0, profile=profile, scale_reward=True)
    seen = []
    c.teacher.episodic_update = lambda task, reward, success=False: seen.append(reward)
    task = c.sample_task()
    c.record_episode(task, ret, 10, False)
    assert seen == [pytest.approx(expected)]
    # the raw return is what is recorded
    assert c.state_dict()["records"]["train_returns"].tolist() == [ret]


@pytest.mark.parametrize("name", envs.ENV_NAMES)
def test_every_environment_declares_its_curriculum_profile(name, tmp_path):
    env = envs.make(name)
    try:
        profile = env.unwrapped.curriculum_profile
        space = env.unwrapped.task_space
    finally:
        env.close()
    assert isinstance(profile, CurriculumProfile) and profile.name == name
    assert profile.success_return == 230.0 and profile.adr_reward_thresholds == (0.0, 180.0)
    copied = pickle.loads(pickle.dumps(profile))  # profiles travel to worker processes
    assert copied.reward_bounds == profile.reward_bounds and set(copied.test_sets) == set(
        profile.test_sets
    )
    c = TeacherController("random", space, 0, profile=profile)
    c.dump(tmp_path / "dump")
    dump = json.loads((tmp_path / "dump.json").read_text())
    assert dump["env_name"] == name and dump["success_return"] == 230.0


def test_curriculum_profiles_reject_bad_facts():
    for bad in ((1.0, 1.0), (0.0, float("nan")), (0.0,), "wide"):
        with pytest.raises(ValueError, match="reward_bounds"):
            CurriculumProfile(reward_bounds=bad)
    with pytest.raises(ValueError, match="adr_reward_thresholds"):
        CurriculumProfile(adr_reward_thresholds=(180.0, 0.0))
    with pytest.raises(ValueError, match="success_return"):
        CurriculumProfile(success_return=True)
    for bad in ({"walking": [[0.0]]}, ["walking"]):
        with pytest.raises(ValueError, match="test_sets"):
            CurriculumProfile(test_sets=bad)
    with pytest.raises(ValueError, match="default_test_grid"):
        CurriculumProfile(default_test_grid={"stump_height": (3.0, 0.0)})
    assert CurriculumProfile(reward_bounds=np.array([0, 10])).scale(5) == 0.5
    with pytest.raises(ValueError, match="profile"):
        TeacherController("random", STUMPS, 0, profile="stump-tracks")


def test_custom_reward_bounds_and_unscaled_default():
    c = TeacherController("random", STUMPS, 0, scale_reward=True, reward_bounds=(0, 10))
    assert c.scale(5) == 0.5
    c = TeacherController("random", STUMPS, 0)
    seen = []
    c.teacher.episodic_update = lambda task, reward, success=False: seen.append(reward)
    c.record_episode(c.sample_task(), 123.0, 1, True)
    assert seen == [123.0]
    with pytest.raises(ValueError, match="reward_bounds"):
        TeacherController("random", STUMPS, 0, reward_bounds=(1, 1))


def test_adr_thresholds_follow_reward_scaling():
    c = TeacherController("adr", STUMPS, 0, profile=STUMP_TRACKS, scale_reward=True)
    assert (c.teacher.min_reward_thr, c.teacher.max_reward_thr) == pytest.approx((0.3, 0.66))
    c = TeacherController("adr", STUMPS, 0, profile=STUMP_TRACKS)
    assert (c.teacher.min_reward_thr, c.teacher.max_reward_thr) == (0.0, 180.0)


def test_adr_and_oracle_thresholds_come_from_the_profile_unless_the_run_sets_them():
    from acl3d.training import TrainConfig
    from acl3d.training.session import build_controller

    other = CurriculumProfile(
        reward_bounds=(-50.0, 150.0), success_return=120.0, adr_reward_thresholds=(10.0, 90.0)
    )

    def thresholds(teacher, profile, **options):
        config = TrainConfig.from_dict({"teacher": teacher, "out": "unused", **options})
        t = build_controller(config, STUMPS, profile).teacher
        return (t.min_reward_thr, t.max_reward_thr) if teacher == "adr" else t.reward_thr

    assert thresholds("adr", other) == (10.0, 90.0)
    assert thresholds("oracle", other) == 120.0
    assert thresholds("adr", None) == CurriculumProfile().adr_reward_thresholds
    assert thresholds("oracle", None) == CurriculumProfile().success_return
    # the run's explicit values win over the profile, and are scaled with the returns
    assert thresholds("oracle", other, teacher_params={"reward_thr": 40.0}) == 40.0
    explicit = {"min_reward_thr": 0.0, "max_reward_thr": 50.0}
    assert thresholds("adr", other, teacher_params=explicit) == (0.0, 50.0)
    assert thresholds("oracle", other, scale_reward=True) == pytest.approx(0.85)
    assert thresholds("adr", other, scale_reward=True) == pytest.approx((0.3, 0.7))


@pytest.mark.parametrize(
    "bad",
    [
        {"env_task": np.zeros(3)},
        {"env_task": np.array([np.nan, 1.0])},
        {"episode_return": float("inf")},
        {"episode_return": "high"},
        {"length": -1},
        {"length": 2.5},
        {"success": 0.3},
        {"initial_obs": np.array([np.nan])},
    ],
)
def test_bad_episode_raises_and_changes_nothing(bad):
    c = TeacherController("alp-gmm", STUMPS, 0, teacher_params={"fit_rate": 10})
    play(c, 12)
    before = json.dumps(_jsonable(c.state_dict()))
    args = {
        "env_task": c.sample_task(),
        "episode_return": 1.0,
        "length": 3,
        "success": True,
        "initial_obs": None,
    }
    before_sampled = json.dumps(_jsonable(c.state_dict()))
    assert before != before_sampled  # sampling is recorded
    args.update(bad)
    with pytest.raises(ValueError):
        c.record_episode(**args)
    assert json.dumps(_jsonable(c.state_dict())) == before_sampled


def _jsonable(obj):
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def test_spdl_gets_steps_per_worker_and_initial_states():
    c = TeacherController(
        "self-paced", STUMPS, 0, teacher_params={"update_frequency": 4, "update_offset": 0}
    )
    assert c.needs == {"step_rewards", "initial_states", "value_estimator"}
    states = []
    c.set_value_estimator(lambda s: states.append(s.copy()) or np.ones(len(s)))
    t0, t1 = c.sample_task(), c.sample_task()
    for step in range(2):
        c.record_step(t0, None, 1.0, t0, step == 1, worker=0)
        c.record_step(t1, None, 5.0, t1, step == 1, worker=1)
        if step == 0:
            continue
        c.record_episode(t0, 1.99, 2, False, initial_obs=np.array([0.0, 1.0]))
        c.record_episode(t1, 9.95, 2, False, initial_obs=np.array([2.0, 3.0]))
    assert c.teacher.steps == 4
    c.record_step(t0, None, 0.0, t0, True)  # 5th step: no update (update_frequency 4) ...
    for _ in range(3):
        c.record_step(
            t0, None, 0.0, t0, False
        )  # ... the 8th triggers it, on the 2 buffered episodes
    np.testing.assert_array_equal(states[0], [[0.0, 1.0], [2.0, 3.0]])


def test_periodical_samples_every_k_steps():
    c = TeacherController("random", MIXED, 0, keep_periodical_task_samples=1000)
    taken = [
        c.maybe_sample_periodically(s) is not None for s in (0, 999, 1000, 1500, 2100, 2200, 5000)
    ]
    assert taken == [False, False, True, False, True, False, True]
    records = c.state_dict()["records"]
    samples = records["periodical_samples"]
    assert len(samples) == 3 and samples[0].shape == (100, 4) and samples[0].dtype == np.float32
    assert records["periodical_steps"].tolist() == [1000, 2100, 5000]
    assert TeacherController("random", MIXED, 0).maybe_sample_periodically(10**9) is None


SMALL_TORCH = {
    "self-paced": {"update_frequency": 10, "update_offset": 0},
    "goal-gan": FAST_GAN,
    "setter-solver": {"update_frequency": 5, "setter_hidden_size": 8},
}


@pytest.mark.parametrize("name", [*NAMES, *SMALL_TORCH])
def test_periodical_samples_leave_the_run_alone(name):
    """Showing the curriculum draws from streams of its own: a run taking periodical samples
    proposes what a run without them does, and the samples depend on the seed and step only."""
    params = {**FAST, **SMALL_TORCH}[name]

    def build(every: int) -> TeacherController:
        return TeacherController(
            name, STUMPS, 4, teacher_params=params, keep_periodical_task_samples=every
        )

    shown, plain, twin, later = build(100), build(0), build(100), build(100)
    for c in (shown, plain, twin, later):
        play(c, 60, seed=1)
    samples = shown.maybe_sample_periodically(100)
    assert samples.shape == (100, 2)
    np.testing.assert_array_equal(samples, twin.maybe_sample_periodically(100))
    assert not np.array_equal(samples, later.maybe_sample_periodically(200))
    np.testing.assert_array_equal(play(shown, 30, seed=2), play(plain, 30, seed=2))


def test_shuffled_controller_round_trips_tasks_to_the_teacher():
    c = TeacherController("goal-gan", MIXED, 2, shuffle_dimensions=True, teacher_params=FAST_GAN)
    raw = []
    original_sample = c.teacher.sample_task

    def spy():
        raw.append(original_sample())
        return raw[-1]

    c.teacher.sample_task = spy
    got = []
    original_update = c.teacher.episodic_update
    c.teacher.episodic_update = lambda task, reward, success=False: (
        got.append(task),
        original_update(task, reward, success),
    )
    play(c, 20)
    np.testing.assert_allclose(np.array(got), np.array(raw), atol=1e-5)
    env_tasks = c.state_dict()["records"]["sampled_tasks"]
    assert not np.allclose(env_tasks, np.array(raw))  # the environment saw shuffled tasks
    assert TaskSpace.coerce(MIXED).contains(env_tasks.max(axis=0)) and np.all(
        env_tasks.min(axis=0) >= -1
    )
    assert len(c.teacher._pending) <= 1  # every played GAN goal was matched back


# ---------------------------------------------------------------------- every teacher
def test_every_registered_teacher_runs_under_the_controller():
    for name in TEACHERS:
        params = {
            "lessons": {
                "curriculum": {"thresholds": [0.5], "parameters": {"stump_height": [0, 1]}}
            },
            "goal-gan": FAST_GAN,
        }.get(name)
        c = TeacherController(
            name,
            STUMPS,
            1,
            teacher_params=params,
            profile=STUMP_TRACKS,
            expert_knowledge="high",
            scale_reward=True,
        )
        tasks = np.array(play(c, 8))
        assert tasks.dtype == np.float32 and np.all(tasks >= 0) and np.all(tasks <= [3, 6]), name
    with pytest.raises(ValueError, match="unknown teacher"):
        TeacherController("curious", STUMPS, 0)


# ---------------------------------------------------------------------- dump and resume
def test_dump_is_readable_without_pickle(tmp_path):
    c = TeacherController(
        "alp-gmm", STUMPS, 0, teacher_params={"fit_rate": 10}, keep_periodical_task_samples=5
    )
    tasks = play(c, 25)
    c.maybe_sample_periodically(5)
    c.record_test_episode(c.test_tasks()[0], 10.0, 5, False)
    c.dump(tmp_path / "teacher_dump")
    meta = json.loads((tmp_path / "teacher_dump.json").read_text())
    with np.load(tmp_path / "teacher_dump.npz", allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    assert meta["teacher"] == "alp-gmm" and meta["names"] == ["stump_height", "obstacle_spacing"]
    assert meta["reward_bounds"] == [-100.0, 100.0]
    train = arrays[meta["train_tasks"]["__array__"]]
    np.testing.assert_array_equal(train, np.array(tasks))
    assert arrays[meta["train_success"]["__array__"]].dtype == bool
    assert arrays[meta["test_tasks"]["__array__"]].shape == (100, 2)
    assert len(meta["periodical_samples"]) == 1
    assert "tasks_origin" in meta["teacher_bk"]
    full = load_state(tmp_path / "teacher_dump")  # the same files through the library's reader
    np.testing.assert_array_equal(full["train_returns"], c.state_dict()["records"]["train_returns"])


@pytest.mark.parametrize("name", ["alp-gmm", "self-paced", "goal-gan", "setter-solver"])
def test_controller_resumes_exactly(tmp_path, name):
    kwargs = {
        "alp-gmm": {"fit_rate": 10},
        "self-paced": {"update_frequency": 10, "update_offset": 0},
        "goal-gan": FAST_GAN,
        "setter-solver": {"update_frequency": 5, "setter_hidden_size": 8},
    }[name]

    def build():
        return TeacherController(
            name,
            MIXED,
            3,
            teacher_params=kwargs,
            shuffle_dimensions=True,
            scale_reward=True,
            keep_periodical_task_samples=7,
        )

    a = build()
    play(a, 17, seed=1)
    a.maybe_sample_periodically(7)
    a.save(tmp_path / "ckpt")
    b = build()
    b.load(tmp_path / "ckpt")
    np.testing.assert_array_equal(play(a, 15, seed=2), play(b, 15, seed=2))
    assert json.dumps(_jsonable(a.state_dict())) == json.dumps(_jsonable(b.state_dict()))
    with pytest.raises(ValueError, match="controller state"):
        TeacherController("random", MIXED, 3).load_state_dict(a.state_dict())
