"""Behaviour of the classic teachers: Random, ALP-GMM, Covar-GMM, RIAC, ADR, Oracle, and the
return/value-driven ones (Robust PLR, ACCEL, terrain levels) on the same generic checks."""

from __future__ import annotations

import numpy as np
import pytest

from acl3d.task_space import TaskSpace
from acl3d.teachers import RunFacts, make, teacher_class
from acl3d.teachers.mixture_fit import fit_gmm
from acl3d.teachers.presets import BENCHMARK, PRESETS, TEACHDEEPRL, preset_params
from acl3d.toy import ToyEnv, run_teacher

# Small, fast settings that still exercise every code path (fits, splits, box moves) in a few
# hundred episodes.
FAST = {
    "random": {},
    "alp-gmm": {"fit_rate": 40, "potential_ks": [2, 3, 4]},
    "covar-gmm": {"fit_rate": 40, "potential_ks": [2, 3, 4]},
    "riac": {"max_region_size": 30, "nb_split_attempts": 10},
    "adr": {"queue_len": 3, "min_reward_thr": 0.2, "max_reward_thr": 0.6},
    "oracle": {"step_rate": 10, "reward_thr": 0.3},
    "robust-plr": {"buffer_size": 20},
    "accel": {"buffer_size": 20, "nb_edits": 2},
    "terrain-levels": {"nb_workers": 3, "promote_return": 0.5, "demote_return": 0.02},
}
NAMES = list(FAST)

SPACES = {
    "2d": TaskSpace.from_bounds({"stump_height": [0.0, 3.0], "obstacle_spacing": [0.0, 6.0]}),
    # Parkour-like: 8 dimensions, two of them constant.
    "degenerate": TaskSpace.from_bounds(
        {
            "cppn": [-1.0, 1.0, 3],
            "creepers_width": [0.25, 0.25],
            "creepers_height": [0.0, 4.0],
            "spacing": [0.0, 5.0],
            "scale": [10.0, 10.0],
            "water": [0.0, 1.0],
        }
    ),
    "20d": TaskSpace.from_bounds({"x": [-2.0, 5.0, 20]}),
}


def _reward(task: np.ndarray, space: TaskSpace, i: int) -> float:
    """A learnable-looking signal: grows with time in the lower half of the first dimension."""
    u = (task[0] - space.low[0]) / (space.high[0] - space.low[0])
    return float(min(1.0, i / 300.0) if u < 0.5 else 0.05 * u)


def _drive(teacher, space: TaskSpace, n: int, start: int = 0) -> np.ndarray:
    tasks = []
    for i in range(start, start + n):
        task = teacher.sample_task()
        tasks.append(task)
        teacher.episodic_update(task, _reward(task, space, i), is_success=False)
    return np.asarray(tasks)


@pytest.mark.parametrize("space_name", list(SPACES))
@pytest.mark.parametrize("name", NAMES)
def test_samples_in_bounds_with_right_shape_and_dtype(name, space_name):
    space = SPACES[space_name]
    teacher = make(name, space, seed=3, **FAST[name])
    tasks = _drive(teacher, space, 300)
    assert tasks.dtype == np.float32 and tasks.shape == (300, space.dim)
    low, high = space.low.astype(np.float32), space.high.astype(np.float32)
    assert np.all(tasks >= low) and np.all(tasks <= high)
    const = space.low == space.high
    assert np.all(tasks[:, const] == low[const])
    nxt = teacher.non_exploratory_task_sampling()["task"]
    assert nxt.dtype == np.float32 and np.all(nxt >= low) and np.all(nxt <= high)


@pytest.mark.parametrize("name", NAMES)
def test_same_seed_same_sequence_and_seed_zero_is_a_seed(name):
    space = SPACES["degenerate"]
    a = _drive(make(name, space, seed=0, **FAST[name]), space, 200)
    b = _drive(make(name, space, seed=0, **FAST[name]), space, 200)
    c = _drive(make(name, space, seed=1, **FAST[name]), space, 200)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


@pytest.mark.parametrize("name", NAMES)
def test_state_dict_round_trip_through_files_resumes_exactly(name, tmp_path):
    space = SPACES["2d"]
    teacher = make(name, space, seed=5, **FAST[name])
    _drive(teacher, space, 170)
    teacher.save(tmp_path / "teacher")
    expected = _drive(teacher, space, 150, start=170)

    restored = make(name, space, seed=99, **FAST[name])
    restored.load(tmp_path / "teacher")
    np.testing.assert_array_equal(_drive(restored, space, 150, start=170), expected)
    assert restored.nb_episodes == teacher.nb_episodes


@pytest.mark.parametrize("name", NAMES)
def test_bad_input_raises_and_changes_nothing(name):
    space = SPACES["2d"]
    teacher = make(name, space, seed=2, **FAST[name])
    twin = make(name, space, seed=2, **FAST[name])
    _drive(teacher, space, 60)
    _drive(twin, space, 60)
    task = teacher.sample_task()
    twin.sample_task()
    for bad_task, bad_reward in (
        (task, np.nan),
        (task, np.inf),
        (task[:1], 1.0),
        (np.array([np.nan, 1.0]), 1.0),
    ):
        with pytest.raises(ValueError):
            teacher.episodic_update(bad_task, bad_reward)
    teacher.episodic_update(task, 0.5)
    twin.episodic_update(task, 0.5)
    np.testing.assert_array_equal(
        _drive(teacher, space, 80, start=61), _drive(twin, space, 80, start=61)
    )


@pytest.mark.parametrize("name", ["alp-gmm", "covar-gmm", "riac"])
def test_learning_progress_teachers_beat_random_on_the_toy(name):
    params = {
        "alp-gmm": {"fit_rate": 50, "random_task_ratio": 0.2},
        "covar-gmm": {"fit_rate": 50, "random_task_ratio": 0.2, "potential_ks": [2, 3, 4, 5, 6]},
        "riac": {"max_region_size": 50, "nb_split_attempts": 20},
    }[name]
    scores = {}
    for teacher_name, p in (("random", {}), (name, params)):
        env = ToyEnv(seed=0)
        run = run_teacher(make(teacher_name, env.task_space(), seed=0, **p), env, 3000)
        scores[teacher_name] = run.scores[-1]
    assert scores[name] >= 3.0 and scores[name] > scores["random"] + 2.0, scores


def test_unknown_parameter_lists_the_valid_ones():
    with pytest.raises(ValueError, match="bogus") as info:
        make("alp-gmm", SPACES["2d"], seed=0, bogus=1)
    assert "fit_rate" in str(info.value) and "random_task_ratio" in str(info.value)


@pytest.mark.parametrize(
    ("name", "params", "pattern"),
    [
        ("alp-gmm", {"fit_rate": 1}, "fit_rate"),
        ("alp-gmm", {"random_task_ratio": 1.5}, "random_task_ratio"),
        ("alp-gmm", {"potential_ks": []}, "potential_ks"),
        ("alp-gmm", {"gmm_fitness_func": "likelihood"}, "gmm_fitness_func"),
        ("alp-gmm", {"initial_dist": {"mean": [0.0]}}, "initial_dist"),
        ("covar-gmm", {"nb_em_init": 0}, "nb_em_init"),
        ("riac", {"max_region_size": 1}, "max_region_size"),
        ("riac", {"min_dims_range_ratio": 0.6}, "min_dims_range_ratio"),
        ("riac", {"discard_ratio": 0.0}, "discard_ratio"),
        ("adr", {"min_reward_thr": 5.0, "max_reward_thr": 1.0}, "min_reward_thr"),
        ("adr", {"step_size": -0.1}, "step_size"),
        ("oracle", {"window_step_vector": [0.1]}, "window_step_vector"),
    ],
)
def test_invalid_parameters_raise_naming_the_parameter(name, params, pattern):
    with pytest.raises(ValueError, match=pattern):
        make(name, SPACES["2d"], seed=0, **params)


def test_presets_build_every_teacher_and_benchmark_equals_class_defaults():
    space = SPACES["2d"]
    for preset in PRESETS:
        for name in NAMES:
            make(name, space, seed=0, **preset_params(preset, name))
    alp = make("alp-gmm", space, seed=0)
    assert (alp.fit_rate, alp.random_task_ratio, alp.potential_ks) == (
        150,
        0.05,
        list(range(2, 10)),
    )
    assert make("covar-gmm", space, seed=0).potential_ks == BENCHMARK["covar-gmm"]["potential_ks"]
    assert TEACHDEEPRL["alp-gmm"]["potential_ks"] == list(range(2, 11))
    with pytest.raises(ValueError, match="preset"):
        preset_params("fast", "riac")


def test_presets_leave_the_environment_facts_to_the_run():
    """A preset value would hide the env's curriculum profile from every run that uses it."""
    facts = RunFacts(initial_dist={"mean": np.zeros(2), "variance": np.eye(2)}, total_steps=10**6)
    for preset in PRESETS:
        for name in NAMES:
            from_run = set(teacher_class(name).run_params(facts))
            assert not from_run & set(preset_params(preset, name)), (preset, name)


def test_gmm_fit_recovers_separated_clusters():
    rng = np.random.default_rng(0)
    x = np.vstack([rng.normal([0, 0], 0.05, (200, 2)), rng.normal([1, 1], 0.05, (100, 2))])
    gmm, _ = fit_gmm(x, 2, np.random.default_rng(1))
    order = np.argsort(gmm.means[:, 0])
    np.testing.assert_allclose(gmm.means[order], [[0, 0], [1, 1]], atol=0.03)
    np.testing.assert_allclose(gmm.weights[order], [2 / 3, 1 / 3], atol=0.02)


@pytest.mark.parametrize("name", ["alp-gmm", "covar-gmm", "riac"])
def test_progress_teachers_focus_where_competence_grows(name):
    """Competence grows with practice in the lower half of stump_height only; elsewhere return 0."""
    space = SPACES["2d"]
    params = {
        "alp-gmm": {"fit_rate": 100},
        "covar-gmm": {"fit_rate": 100},
        "riac": {"max_region_size": 50},
    }[name]
    teacher = make(name, space, seed=0, **params)
    practice, tasks = 0, []
    for _ in range(1500):
        task = teacher.sample_task()
        tasks.append(task)
        if task[0] < 1.5:
            practice += 1
        teacher.episodic_update(task, min(1.0, practice / 1500) if task[0] < 1.5 else 0.0)
    late = np.asarray(tasks[-500:])
    assert np.mean(late[:, 0] < 1.5) > 0.7


def test_riac_splits_only_non_degenerate_dims_and_children_get_best_split_alps():
    space = SPACES["degenerate"]
    teacher = make("riac", space, seed=0, max_region_size=30, nb_split_attempts=10)
    _drive(teacher, space, 600)
    assert teacher.nb_regions > 3
    const = np.flatnonzero(space.low == space.high)
    cut_dims = {c[0] for c in teacher.cut if c is not None}
    assert cut_dims and not cut_dims & set(const.tolist())
    assert teacher.plot_state()["kind"] == "boxes"
    # a fresh split's children carry the ALPs of the winning cut, recomputed from their own data
    fresh = make("riac", space, seed=1, max_region_size=30, nb_split_attempts=10)
    for i in range(400):
        task = fresh.sample_task()
        fresh.episodic_update(task, _reward(task, space, i))
        if fresh.nb_regions == 3:
            break
    from acl3d.teachers.riac import _window_alp

    for child in fresh.children[0]:
        assert fresh.alps[child] == pytest.approx(
            _window_alp(fresh.rewards[child], fresh.alp_window_size)
        )


def test_adr_expands_on_success_and_contracts_on_failure():
    space = TaskSpace.from_bounds({"a": [0.0, 1.0], "b": [0.0, 1.0]})

    def centred_adr():
        return make(
            "adr",
            space,
            seed=0,
            step_size=0.1,
            queue_len=3,
            min_reward_thr=0.2,
            max_reward_thr=0.8,
            initial_dist={"mean": [0.5, 0.5]},
        )

    teacher = centred_adr()
    for _ in range(400):
        teacher.episodic_update(teacher.sample_task(), 1.0)
    np.testing.assert_allclose(teacher.cur_low, [0.0, 0.0])
    np.testing.assert_allclose(teacher.cur_high, [1.0, 1.0])
    assert teacher.plot_state()["kind"] == "box"

    teacher = centred_adr()
    for _ in range(60):
        teacher.episodic_update(teacher.sample_task(), 1.0)
    width = teacher.cur_high - teacher.cur_low
    assert np.all(width > 0.15)
    for _ in range(600):
        teacher.episodic_update(teacher.sample_task(), 0.0)
    assert np.all(teacher.cur_high - teacher.cur_low < width)


def test_adr_feeds_only_the_boundary_sampled_bound():
    space = TaskSpace.from_bounds({"a": [0.0, 1.0], "b": [0.0, 1.0]})
    teacher = make(
        "adr",
        space,
        seed=4,
        boundary_sampling_p=1.0,
        queue_len=1000,
        initial_dist={"mean": [0.5, 0.5]},
    )
    for _ in range(50):
        teacher.episodic_update(teacher.sample_task(), 1.0)
    lengths = [len(q) for side in teacher.queues for q in side]
    assert sum(lengths) == 50 and min(lengths) > 0
    teacher.episodic_update(
        np.array([0.5, 0.5], dtype=np.float32), 1.0
    )  # a task it did not propose
    assert sum(len(q) for side in teacher.queues for q in side) == 50


def test_oracle_window_moves_only_when_reward_threshold_is_reached():
    space = SPACES["2d"]
    teacher = make(
        "oracle", space, seed=0, step_rate=10, reward_thr=0.5, window_step_vector=[0.1, -0.2]
    )
    np.testing.assert_allclose(teacher.window_low, [0.0, 5.0])
    for _ in range(30):
        teacher.episodic_update(teacher.sample_task(), 0.4)
    np.testing.assert_allclose(teacher.window_low, [0.0, 5.0])
    for _ in range(20):
        teacher.episodic_update(teacher.sample_task(), 0.9)
    np.testing.assert_allclose(teacher.window_low, [0.2, 4.6])
    tasks = np.array([teacher.sample_task() for _ in range(100)])
    assert np.all(tasks[:, 0] >= 0.2 - 1e-6) and np.all(tasks[:, 0] <= 0.7 + 1e-6)


def test_gmm_fit_and_aic_match_sklearn():
    from sklearn.mixture import GaussianMixture

    from acl3d.teachers.mixture_fit import gmm_fitness

    rng = np.random.default_rng(1)
    x = np.vstack([rng.normal([0, 0, 0], 0.1, (150, 3)), rng.normal([1, 1, 0.5], 0.2, (100, 3))])
    ours, log_lik = fit_gmm(x, 2, np.random.default_rng(0))
    ref = GaussianMixture(2, covariance_type="full", random_state=0).fit(x)
    assert gmm_fitness("aic", log_lik, 2, len(x), 3) == pytest.approx(ref.aic(x), rel=1e-3)
    assert gmm_fitness("bic", log_lik, 2, len(x), 3) == pytest.approx(ref.bic(x), rel=1e-3)
