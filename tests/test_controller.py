"""TeacherController, DimensionsShuffler, curriculum profiles, expert knowledge and test sets."""

from __future__ import annotations

import inspect
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
from acl3d.teachers import TEACHERS, load_state, teacher_class
from acl3d.teachers import test_sets as ts
from acl3d.teachers.controller import TeacherController
from acl3d.teachers.dimensions_shuffler import DimensionsShuffler
from acl3d.teachers.expert_knowledge import expert_knowledge
from acl3d.terrain import parkour_test_sets
from acl3d.terrain.parkour import parkour_task_space

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


# ---------------------------------------------------------------------- expert knowledge
def test_expert_knowledge_table():
    space = TaskSpace.coerce({"stump_height": [-3.0, 3.0], "obstacle_spacing": [0.0, 6.0]})
    high = expert_knowledge(STUMP_TRACKS, space, "high")
    dist = STUMP_TRACKS.initial_distribution(space)
    np.testing.assert_allclose(dist["mean"], [0.0, 6.0])
    np.testing.assert_allclose(dist["variance"], np.diag([0.6**2, 0.6**2]))
    for name in ("alp-gmm", "covar-gmm", "adr", "self-paced", "goal-gan"):
        assert high[name]["initial_dist"] is not None, name
    for name in ("random", "riac", "setter-solver", "oracle", "lessons"):
        assert "initial_dist" not in high[name]
    assert expert_knowledge(STUMP_TRACKS, space, "no") == expert_knowledge(
        STUMP_TRACKS, space, "low"
    )
    low = expert_knowledge(STUMP_TRACKS, space, "low")
    assert all("initial_dist" not in kw for kw in low.values())
    # the easy side is the environment's fact, given at every level (where ADR starts)
    easy = ["obstacle_spacing"]
    assert low["adr"] == {"min_reward_thr": 0.0, "max_reward_thr": 180.0, "easy_at_high": easy}
    assert low["oracle"]["easy_at_high"] == easy and low["goal-gan"]["easy_at_high"] == easy
    for profile in (PARKOUR, None):  # no prior for Parkour, nor for an env without a profile
        assert expert_knowledge(profile, space, "high") == expert_knowledge(profile, space, "low")
        assert all(
            "initial_dist" not in kw for kw in expert_knowledge(profile, space, "high").values()
        )
    np.testing.assert_allclose(
        STUMP_TRACKS.initial_distribution({"stump_height": [1, 3], "obstacle_spacing": [0, 6]})[
            "mean"
        ],
        [1, 6],
    )
    hexa = HEXAGON_TRACKS.initial_distribution({"poly_shape": [0.0, 4.0, 12]})
    np.testing.assert_allclose(hexa["mean"], np.zeros(12))
    np.testing.assert_allclose(np.diag(hexa["variance"]), np.full(12, 0.01))
    with pytest.raises(ValueError, match="expert_knowledge level"):
        expert_knowledge(PARKOUR, space, "original")


def test_expert_knowledge_kwargs_are_accepted_by_every_teacher():
    space = TaskSpace.coerce(STUMPS)
    for level in ("no", "low", "high"):
        knowledge = expert_knowledge(STUMP_TRACKS, space, level)
        assert set(TEACHERS) <= set(knowledge)  # every built-in (and any registered by then)
        for name, kwargs in knowledge.items():
            params = inspect.signature(teacher_class(name).__init__).parameters
            assert set(kwargs) <= set(params), (name, set(kwargs) - set(params))


def test_high_knowledge_reaches_teachers_in_teacher_space():
    c = TeacherController(
        "self-paced",
        STUMPS,
        5,
        profile=STUMP_TRACKS,
        expert_knowledge="high",
        shuffle_dimensions=True,
    )
    mean, cov = c.teacher.mean_covariance()
    np.testing.assert_allclose(mean, c.shuffler.inverse(np.array([0.0, 6.0])))
    np.testing.assert_allclose(np.diag(cov), [0.3**2, 0.6**2])
    c = TeacherController("adr", STUMPS, 5, profile=STUMP_TRACKS, expert_knowledge="high")
    np.testing.assert_allclose(c.sample_task(), [0.0, 6.0])  # ADR starts at the easy corner


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


# ---------------------------------------------------------------------- test sets
def test_default_test_set_is_the_stump_grid():
    space = {"stump_height": [0.0, 9.0], "obstacle_spacing": [0.0, 6.0]}
    c = TeacherController("random", space, 0, profile=STUMP_TRACKS)
    tasks = c.test_tasks()
    assert tasks.shape == (100, 2) and tasks.dtype == np.float32 and c.nb_test_episodes == 100
    np.testing.assert_allclose(tasks[:10, 0], np.linspace(0, 3, 10), rtol=1e-6)  # first dim fastest
    np.testing.assert_allclose(tasks[::10, 1], np.linspace(0, 6, 10), rtol=1e-6)
    np.testing.assert_allclose(tasks[:10, 1], 0.0)
    # the grid is the stump profile's: one stump dimension, or no profile, gives uniform tasks
    one_dim = TeacherController("random", {"stump_height": [0.0, 9.0]}, 0, profile=STUMP_TRACKS)
    np.testing.assert_allclose(one_dim.test_tasks(), ts.uniform({"stump_height": [0, 9]}, 100))
    np.testing.assert_allclose(
        TeacherController("random", space, 0).test_tasks(), ts.uniform(space)
    )


def test_named_test_sets_come_from_the_profile():
    space = parkour_task_space()
    for name in ("climbing", "climbing_test_set_v1"):
        c = TeacherController("random", space, 0, profile=PARKOUR, test_set=name)
        np.testing.assert_array_equal(
            c.test_tasks(), parkour_test_sets.build("climbing", space).astype(np.float32)
        )
    with pytest.raises(ValueError, match="named set of this environment \\(none\\)"):
        TeacherController("random", STUMPS, 0, profile=STUMP_TRACKS, test_set="walking")


def test_default_test_set_elsewhere_is_seeded_uniform():
    a = TeacherController("random", MIXED, 0, nb_test_episodes=30).test_tasks()
    b = TeacherController("random", MIXED, 9, nb_test_episodes=30).test_tasks()
    np.testing.assert_array_equal(a, b)  # seed 31, not the run seed
    np.testing.assert_allclose(
        a,
        np.random.default_rng(31).uniform(
            TaskSpace.coerce(MIXED).low, TaskSpace.coerce(MIXED).high, (30, 4)
        ),
        rtol=1e-6,
    )


def test_grid_over_varying_dimensions():
    tasks = ts.grid(MIXED, 125)
    assert tasks.shape == (125, 4)
    np.testing.assert_array_equal(tasks[:, 1], 0.5)
    assert len(np.unique(tasks[:, 0])) == 5 and len(np.unique(tasks, axis=0)) == 125
    with pytest.raises(ValueError, match="fewer than 2 points"):
        ts.grid({"x": [0, 1, 12]}, 100)


@pytest.mark.parametrize("suffix", [".json", ".csv"])
def test_test_set_file_round_trip(tmp_path, suffix):
    tasks = ts.uniform(MIXED, 7, seed=3)
    path = tmp_path / f"set{suffix}"
    ts.save(path, tasks, MIXED)
    np.testing.assert_array_equal(ts.load(path, MIXED), tasks)
    c = TeacherController("random", MIXED, 0, test_set=str(path))
    assert c.nb_test_episodes == 7
    np.testing.assert_allclose(c.test_tasks(), tasks.astype(np.float32))


def test_test_set_files_match_columns_by_name(tmp_path):
    (tmp_path / "a.json").write_text(
        json.dumps(
            {"names": ["obstacle_spacing", "stump_height"], "tasks": [[5.0, 1.0], [4.0, 9.0]]}
        )
    )
    np.testing.assert_array_equal(
        ts.load(tmp_path / "a.json", STUMPS), [[1.0, 5.0], [9.0, 4.0]]
    )  # outside bounds is fine
    (tmp_path / "b.json").write_text(json.dumps([{"stump_height": 1.0, "obstacle_spacing": 2.0}]))
    np.testing.assert_array_equal(ts.load(tmp_path / "b.json", STUMPS), [[1.0, 2.0]])
    (tmp_path / "c.csv").write_text("obstacle_spacing,stump_height\n1,2\n3,4\n")
    np.testing.assert_array_equal(ts.load(tmp_path / "c.csv", STUMPS), [[2.0, 1.0], [4.0, 3.0]])


def test_bad_test_sets_raise(tmp_path):
    with pytest.raises(ValueError, match="expected shape"):
        TeacherController("random", STUMPS, 0, test_set=np.zeros((5, 3)))
    with pytest.raises(ValueError, match="non-finite"):
        ts.validate([[1.0, np.nan]], STUMPS)
    (tmp_path / "a.json").write_text(
        json.dumps({"names": ["stump_height", "gap"], "tasks": [[1.0, 2.0]]})
    )
    with pytest.raises(ValueError, match="unknown \\['gap'\\]"):
        ts.load(tmp_path / "a.json", STUMPS)
    (tmp_path / "b.csv").write_text("stump_height,obstacle_spacing\n1,x\n")
    with pytest.raises(ValueError, match="b.csv"):
        ts.load(tmp_path / "b.csv", STUMPS)
    with pytest.raises(ValueError, match="missing.json': no such file"):
        ts.load(tmp_path / "missing.json", STUMPS)


def test_test_episodes_are_recorded():
    c = TeacherController("random", STUMPS, 0)
    for task in c.test_tasks()[:3]:
        c.record_test_episode(task, 240.0, 2000, True)
    assert c.state_dict()["records"]["test_returns"].tolist() == [240.0] * 3
    with pytest.raises(ValueError, match="env_task"):
        c.record_test_episode([1.0], 0.0, 1)


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
