"""SPDL, GoalGAN and Setter-Solver: bounds, determinism, exact resume, and that they learn."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from acl3d.task_space import TaskSpace
from acl3d.teachers import make
from acl3d.teachers.goal_gan import GoalGAN
from acl3d.teachers.self_paced import SelfPaced
from acl3d.teachers.setter_solver import SetterSolver
from acl3d.teachers.state_files import save_state

torch.set_num_threads(1)

SPACES = {
    "2d": {"stump_height": [0.0, 3.0], "obstacle_spacing": [0.0, 6.0]},
    "degenerate": {"a": [-1.0, 2.0], "const": [0.25, 0.25], "b": [[0.0, 1.0], [5.0, 5.0]]},
    "20d": {"x": [0.0, 4.0, 20]},
}

# small and fast versions of each teacher (the defaults are the TeachMyAgent benchmark values)
FAST = {
    "self-paced": {"update_frequency": 30, "update_offset": 0, "alpha_offset": 2},
    "goal-gan": {
        "pretrain_iters": 5,
        "nb_pretrain_samples": 64,
        "gan_train_iters": 5,
        "update_size": 6,
        "p_old": 0.3,
    },
    "setter-solver": {"update_frequency": 5, "setter_hidden_size": 16},
}


def drive(teacher, n: int) -> np.ndarray:
    """Play n episodes: 3 steps each, return = sum of the task; success when normalised
    coordinate 0 (even episodes) or the last coordinate (odd episodes) is below 0.5, so goals
    repeated twice in a row can be of intermediate difficulty."""
    tasks = []
    for i in range(n):
        task = teacher.sample_task()
        tasks.append(task)
        teacher.record_initial_state(task, task)
        for s in range(3):
            teacher.step_update(task, None, float(task.sum()) / 3, task, s == 2)
        unit = teacher.normalise(task)
        teacher.episodic_update(task, float(task.sum()), bool(unit[0 if i % 2 == 0 else -1] < 0.5))
    return np.array(tasks)


@pytest.mark.parametrize("space", list(SPACES))
@pytest.mark.parametrize("name", list(FAST))
def test_tasks_in_bounds_float32_and_constant_dims(name, space):
    teacher = make(name, SPACES[space], seed=3, **FAST[name])
    tasks = drive(teacher, 40)
    ts = TaskSpace.coerce(SPACES[space])
    assert tasks.dtype == np.float32 and tasks.shape == (40, ts.dim)
    assert np.all(tasks >= ts.low.astype(np.float32)) and np.all(
        tasks <= ts.high.astype(np.float32)
    )
    constant = ts.low == ts.high
    assert np.all(tasks[:, constant] == ts.low[constant].astype(np.float32))
    varying = ~constant
    assert np.all(tasks[:, varying].std(axis=0) > 0), "varying dimensions must actually vary"
    extra = teacher.non_exploratory_task_sampling()["task"]
    assert extra.dtype == np.float32 and ts.contains(extra)


@pytest.mark.parametrize("name", list(FAST))
def test_same_seed_same_sequence_other_seed_differs(name):
    a = drive(make(name, SPACES["degenerate"], seed=7, **FAST[name]), 30)
    b = drive(make(name, SPACES["degenerate"], seed=7, **FAST[name]), 30)
    c = drive(make(name, SPACES["degenerate"], seed=8, **FAST[name]), 30)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


@pytest.mark.parametrize("name", list(FAST))
def test_save_load_resumes_exactly(name, tmp_path):
    original = make(name, SPACES["degenerate"], seed=11, **FAST[name])
    drive(original, 23)  # mid-way: pending goals, queued repeats, partial buffers
    original.save(tmp_path / "teacher")
    resumed = make(name, SPACES["degenerate"], seed=999, **FAST[name])
    resumed.load(tmp_path / "teacher")
    np.testing.assert_array_equal(drive(original, 30), drive(resumed, 30))
    assert original.dump().keys() == resumed.dump().keys()
    for key, values in original.dump().items():
        np.testing.assert_allclose(
            np.asarray(values, dtype=float),
            np.asarray(resumed.dump()[key], dtype=float),
            err_msg=key,
        )


def test_setter_solver_checkpoint_of_the_older_form_resumes_as_the_current_one(tmp_path):
    """Proposals in flight and outcomes awaiting the next update, saved as the entries older
    checkpoints hold ({task, goal, f} a proposal, {goal, f, success} an outcome): the teacher
    loaded from them continues as the one loaded from the current columns."""
    teacher = make("setter-solver", SPACES["2d"], seed=11, **FAST["setter-solver"])
    drive(teacher, 23)
    waiting = [teacher.sample_task() for _ in range(4)]
    state = teacher.state_dict()
    extra = dict(state["extra"])
    proposals, outcomes = extra.pop("proposals"), extra.pop("outcomes")
    assert len(proposals["tasks"]) == 4 and len(outcomes["f"]) == 3
    extra["pending"] = [
        {"task": t, "goal": g, "f": float(f)}
        for t, g, f in zip(proposals["tasks"], proposals["goals"], proposals["f"])
    ]
    extra["buffer"] = [
        {"goal": g, "f": float(f), "success": float(v)}
        for g, f, v in zip(outcomes["goals"], outcomes["f"], outcomes["success"])
    ]
    # written to files first, as checkpoints are: the state shares the teacher's tensors
    save_state(tmp_path / "current", state)
    save_state(tmp_path / "older", dict(state, extra=extra))
    played = []
    for form in ("current", "older"):
        copy = make("setter-solver", SPACES["2d"], seed=0, **FAST["setter-solver"])
        copy.load(tmp_path / form)
        for k, task in enumerate(waiting):
            copy.episodic_update(task, float(task.sum()), k % 2 == 0)
        played.append(drive(copy, 20))
    np.testing.assert_array_equal(played[0], played[1])


@pytest.mark.parametrize("name", list(FAST))
def test_plot_state_leaves_the_task_sequence_alone(name):
    a, b = (make(name, SPACES["2d"], seed=2, **FAST[name]) for _ in range(2))
    drive(a, 7)
    drive(b, 7)
    assert isinstance(b.plot_state(), dict)
    np.testing.assert_array_equal(drive(a, 10), drive(b, 10))


def test_resume_does_not_touch_global_rngs():
    torch.manual_seed(0)
    np.random.seed(0)
    expected_torch, expected_np = torch.rand(1), np.random.rand()
    torch.manual_seed(0)
    np.random.seed(0)
    for name in FAST:
        drive(make(name, SPACES["2d"], seed=1, **FAST[name]), 12)
    assert torch.rand(1) == expected_torch and np.random.rand() == expected_np


# ---------------------------------------------------------------------- SPDL
def _spdl_run(value_estimator, n_episodes=300, **kw):
    params = {
        "update_frequency": 150,
        "update_offset": 0,
        "alpha_offset": 1000,
        "initial_dist": {"mean": [1.5, 3.0], "variance": [0.25, 0.25]},
    }
    params.update(kw)
    teacher = SelfPaced(SPACES["2d"], seed=0, **params)
    if value_estimator is not None:
        teacher.set_value_estimator(value_estimator)
    drive(teacher, n_episodes)
    return teacher


def test_spdl_moves_towards_high_value_contexts():
    # the initial state is the task itself; value grows with stump_height, ignores spacing
    teacher = _spdl_run(lambda states: 10.0 * states[:, 0])
    mean, cov = teacher.mean_covariance()
    assert teacher.algo_iterations == 6
    assert mean[0] > 1.5 + 0.3, mean
    assert len(teacher.bk["mean"]) == 6 and teacher.bk["steps"] == [150 * i for i in range(1, 7)]


def test_spdl_without_value_estimator_uses_measured_discounted_returns():
    # drive() pays task.sum()/3 per step: the discounted return grows with both coordinates
    teacher = _spdl_run(None)
    mean, _ = teacher.mean_covariance()
    assert mean[0] > 1.5 and mean[1] > 3.0


def test_spdl_pulled_to_target_once_alpha_is_on():
    # with zero values only the KL-to-target term acts: the distribution moves towards the target
    teacher = _spdl_run(lambda s: np.zeros(len(s)), alpha_offset=0, use_avg_performance=True)
    kls = teacher.bk["kl"]
    assert kls[-1] < kls[0]


def test_spdl_std_lower_bound_applies_only_far_from_the_target():
    # values reward a narrow region: the distribution shrinks, but not below the floor
    def value(states):
        return -np.abs(states[:, 0] - 1.5)

    floor = _spdl_run(value, n_episodes=450, std_lower_bound=0.4, kl_threshold=0.0)
    free = _spdl_run(value, n_episodes=450)
    assert np.sqrt(np.diag(free.mean_covariance()[1])).min() < 0.4
    assert np.sqrt(np.diag(floor.mean_covariance()[1])).min() >= 0.4 - 1e-9
    never = _spdl_run(value, n_episodes=450, std_lower_bound=0.4, kl_threshold=1e9)
    np.testing.assert_allclose(never.mean_covariance()[1], free.mean_covariance()[1])


def test_spdl_interleaved_streams_match_sequential_episodes():
    def play(interleave: bool):
        t = SelfPaced(SPACES["2d"], seed=5, update_frequency=8, update_offset=0)
        rewards = [[1.0, 2.0, 3.0, 4.0], [10.0, 20.0, 30.0, 40.0]]
        tasks = [t.sample_task(), t.sample_task()]
        order = [(0, i) for i in range(4)] + [(1, i) for i in range(4)]
        if interleave:
            order = [(w, i) for i in range(4) for w in (0, 1)]
        for w, i in order:
            t.step_update(None, None, rewards[w][i], None, i == 3, stream=w)
            if i == 3:
                t.episodic_update(tasks[w], sum(rewards[w]))
        return t.bk["mean"], t.steps

    (m_seq, s_seq), (m_int, s_int) = play(False), play(True)
    assert s_seq == s_int == 8
    np.testing.assert_allclose(m_seq, m_int)


def test_spdl_plot_state_and_validation():
    t = SelfPaced(SPACES["degenerate"], seed=0)
    state = t.plot_state()
    assert (
        state["kind"] == "gaussian"
        and state["mean"].shape == (4,)
        and state["covariance"].shape == (4, 4)
    )
    assert state["covariance"][1, 1] == 0 and state["mean"][1] == 0.25
    with pytest.raises(ValueError, match="max_kl"):
        SelfPaced(SPACES["2d"], max_kl=0)
    with pytest.raises(ValueError, match="std_lower_bound and kl_threshold"):
        SelfPaced(SPACES["2d"], std_lower_bound=0.1)
    with pytest.raises(ValueError, match="initial_dist"):
        SelfPaced(SPACES["2d"], initial_dist={"mean": [0, 0, 0], "variance": [1, 1, 1]})
    with pytest.raises(ValueError, match="positive definite"):
        SelfPaced(SPACES["2d"], initial_dist={"mean": [0, 0], "variance": [1, 0]})
    with pytest.raises(ValueError, match="cg_parameters"):
        SelfPaced(SPACES["2d"], cg_parameters={"n_epochs": 3})
    with pytest.raises(ValueError, match="value_estimator"):
        bad = SelfPaced(SPACES["2d"], seed=0, update_frequency=3, update_offset=0)
        bad.set_value_estimator(lambda s: np.zeros(len(s) + 1))
        drive(bad, 2)


# ---------------------------------------------------------------------- GoalGAN
def test_goal_gan_generator_reaches_the_bounds_without_saturating():
    """The bounds sit at tanh = +-0.5 (the paper's twice-the-space map, clipped): goals at an
    easy corner on a bound keep gradients; at +-1 the generator collapsed there."""
    t = GoalGAN(SPACES["degenerate"], seed=0, use_pretrained_samples=False)
    np.testing.assert_allclose(t._from_unit(np.full(4, 0.5)), t.maxs)
    np.testing.assert_allclose(t._from_unit(np.full(4, -0.5)), t.mins)
    np.testing.assert_allclose(t._from_unit(np.ones(4)), t.maxs)
    np.testing.assert_allclose(t._to_unit(t.maxs)[t.maxs > t.mins], 0.5)


def test_goal_gan_plays_each_goal_n_rollouts_times_and_learns():
    # pretrained around a random centre: drive()'s successes split the space through the middle,
    # and goals at the easy corner all succeed (no intermediate goal, no update: the paper's rule)
    params = {**FAST["goal-gan"], "p_old": 0.0, "pretrain_around": "random"}
    t = GoalGAN(SPACES["2d"], seed=0, **params)
    z = torch.randn(16, 2, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        before = t.generator(z).clone()
    tasks = drive(t, 60)
    np.testing.assert_array_equal(tasks[0::2], tasks[1::2])  # n_rollouts = 2, back to back
    assert len(t.bk["dis_log_loss"]) >= 2  # pretraining + at least one update
    with torch.no_grad():
        assert (t.generator(z) - before).abs().max() > 1e-3


def test_goal_gan_labels_and_success_buffer():
    t = GoalGAN(SPACES["2d"], seed=0, use_pretrained_samples=False, update_size=1000, p_old=0.0)
    goal = t.sample_task()
    assert np.array_equal(t.sample_task(), goal)
    t.episodic_update(goal, 0.0, True)
    t.episodic_update(goal + np.float32(1e-6), 0.0, True)  # float32 round trip tolerance
    assert t._labels == [0.0] and len(t.success_buffer) == 1  # 2/2 successes: too easy, mastered
    goal = t.sample_task()
    t.sample_task()
    t.episodic_update(goal, 0.0, True)
    t.episodic_update(goal, 0.0, False)
    assert t._labels == [0.0, 1.0]  # 1/2 is of intermediate difficulty


def test_goal_gan_validation():
    with pytest.raises(ValueError, match="goid_lb"):
        GoalGAN(SPACES["2d"], goid_lb=0.8, goid_ub=0.2, use_pretrained_samples=False)
    with pytest.raises(ValueError, match="p_old"):
        GoalGAN(SPACES["2d"], p_old=1.5, use_pretrained_samples=False)
    with pytest.raises(ValueError, match="n_rollouts"):
        GoalGAN(SPACES["2d"], n_rollouts=0, use_pretrained_samples=False)


# ---------------------------------------------------------------------- Setter-Solver
def test_setter_solver_judge_has_three_hidden_layers_and_flow_is_invertible():
    t = SetterSolver(SPACES["20d"], seed=0, setter_hidden_size=16)
    linears = [m for m in t.judge if isinstance(m, torch.nn.Linear)]
    assert [layer.out_features for layer in linears] == [64, 64, 64, 1]
    z = torch.randn(8, 20, generator=torch.Generator().manual_seed(0))
    f = torch.rand(8, 1, generator=torch.Generator().manual_seed(1))
    goals, log_p = t.setter.sample(z, f)
    torch.testing.assert_close(
        t.setter.log_prob(goals.clamp(1e-6, 1 - 1e-6), f), log_p, atol=1e-3, rtol=1e-4
    )


def test_setter_solver_updates_change_the_distribution():
    t = SetterSolver(SPACES["2d"], seed=0, **FAST["setter-solver"])
    z = torch.randn(16, 2, generator=torch.Generator().manual_seed(0))
    f = torch.linspace(0.05, 0.95, 16).reshape(-1, 1)
    with torch.no_grad():
        before, _ = t.setter.sample(z, f)
        judged_before = t.judge(before)
    drive(t, 50)
    assert len(t.bk["judge_loss"]) == 10 and len(t.bk["setter_loss"]) == 10
    assert all(np.isfinite(t.bk["setter_loss"]))
    with torch.no_grad():
        after, _ = t.setter.sample(z, f)
        assert (after - before).abs().max() > 1e-4
        assert (t.judge(before) - judged_before).abs().max() > 1e-4


def test_setter_solver_ignores_tasks_it_did_not_propose():
    t = SetterSolver(SPACES["2d"], seed=0, update_frequency=1000)
    t.sample_task()
    t.episodic_update(np.array([2.9, 0.1]), 1.0, True)
    assert t._buffer == [] and len(t._pending) == 1


def test_setter_solver_proposes_a_batch_in_one_pass_and_matches_each_back():
    """Many worlds reset at once: n goals come from one pass of the flow, reproducibly, each
    matched back to its goal and feasibility when its episode is reported (a pass per task
    took ~2 ms)."""
    a, b = (SetterSolver(SPACES["2d"], seed=3, **FAST["setter-solver"]) for _ in range(2))
    tasks = a.sample_tasks(64)
    np.testing.assert_array_equal(tasks, b.sample_tasks(64))
    assert tasks.dtype == np.float32 and np.all(tasks >= a.mins) and np.all(tasks <= a.maxs)
    assert len(a._pending) == 64
    a.update_batch(tasks[::-1], np.zeros(64), np.arange(64) % 2 == 0)
    assert len(a._pending) == 0 and len(a.bk["judge_loss"]) > 0
