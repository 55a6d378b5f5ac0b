"""Robust PLR, ACCEL and terrain levels: the rules that define them (the generic teacher checks
— bounds, seeding, resume, bad input — run in test_teachers_classic.py)."""

from __future__ import annotations

import numpy as np
import pytest

from acl3d.teachers import make
from acl3d.teachers.expert_knowledge import toy_teacher_params
from acl3d.teachers.plr import positive_value_loss
from acl3d.toy import ToyEnv, run_teacher

SPACE = {"x": [0.0, 1.0], "y": [0.0, 2.0]}


def _play(teacher, episodes, reward_fn, steps=3):
    """Episodes of `steps` steps on stream 0 whose step rewards sum to reward_fn(task)."""
    for _ in range(episodes):
        task = teacher.sample_task()
        r = reward_fn(task)
        for k in range(steps):
            teacher.step_update(task, [0.0], r / steps, task, k == steps - 1)
        teacher.episodic_update(task, r)


def test_positive_value_loss_is_mean_positive_gae():
    # V = 0: advantages are the (gamma*lambda)-discounted rewards-to-go
    assert positive_value_loss([1.0, 1.0], [0.0, 0.0], 1.0, 1.0) == pytest.approx(1.5)
    # a perfect critic has no positive advantage; an optimistic one neither
    assert positive_value_loss([1.0, 1.0], [2.0, 1.0], 1.0, 1.0) == 0.0
    assert positive_value_loss([0.0], [5.0], 0.99, 0.95) == 0.0
    assert positive_value_loss([], [], 0.99, 0.95) == 0.0


def test_positive_value_loss_equals_the_step_by_step_recursion_bit_for_bit():
    """Scores decide which levels replay: the filter must give the loop's floats exactly."""

    def by_steps(rewards, values, gamma, lam):
        adv, running, next_v = np.zeros(len(rewards)), 0.0, 0.0
        for t in range(len(rewards) - 1, -1, -1):
            running = rewards[t] + gamma * next_v - values[t] + gamma * lam * running
            adv[t], next_v = running, values[t]
        return float(np.maximum(adv, 0.0).mean())

    rng = np.random.default_rng(0)
    for _ in range(300):
        n = int(rng.integers(1, 400))
        rewards, values = rng.normal(size=n) * 10.0 ** rng.integers(-2, 3), rng.normal(size=n) * 10
        gamma, lam = rng.choice([0.9, 0.99, 0.995]), rng.choice([0.9, 0.95, 1.0])
        assert positive_value_loss(rewards, values, gamma, lam) == by_steps(
            rewards, values, gamma, lam
        )


def test_rank_and_staleness_replay_distribution():
    plr = make("robust-plr", SPACE, seed=0, buffer_size=4, temperature=0.5, staleness_coef=0.25)
    plr.levels = np.zeros((3, 2))
    plr.scores = np.array([0.1, 0.3, 0.2])
    plr.last_played = np.array([5, 9, 10])
    plr.nb_episodes = 10
    h = np.array([1 / 3, 1.0, 1 / 2]) ** 2  # ranks 3, 1, 2 at temperature 0.5
    stale = np.array([5.0, 1.0, 0.0])
    expected = 0.75 * h / h.sum() + 0.25 * stale / stale.sum()
    np.testing.assert_allclose(plr.replay_distribution(), expected)
    # equal (even all-zero) scores and no staleness: a proper distribution, no division by zero
    plr.scores[:] = 0.0
    plr.last_played[:] = 10
    p = plr.replay_distribution()
    assert np.all(np.isfinite(p)) and p.sum() == pytest.approx(1.0)


def test_plr_fills_then_replays_and_keeps_high_scoring_levels():
    plr = make("robust-plr", SPACE, seed=1, buffer_size=10, minimum_fill_ratio=1.0)
    plr.set_value_estimator(lambda states: np.zeros(len(states)))
    # positive value loss with V = 0 grows with the reward: levels with large x score high
    _play(plr, 10, lambda t: float(t[0]))
    assert len(plr.scores) == 10 and not any(plr.bk["kinds"][i] == 1 for i in range(10))
    assert all(plr.bk["exploratory"])  # new levels: PLR-perp would not train on them
    first_scores = plr.scores.copy()
    _play(plr, 300, lambda t: float(t[0]))
    kinds = np.asarray(plr.bk["kinds"][10:])
    assert 0.35 < (kinds == 1).mean() < 0.65  # replay_prob 0.5 once full
    # levels are replaced only by better ones (a level's score is fixed here): scores only went up
    assert plr.scores.min() >= first_scores.min() and len(plr.scores) == 10
    assert plr.levels[:, 0].mean() > 0.7  # high-x levels (high score) took over the buffer


def test_plr_scores_come_from_the_value_estimator_per_stream():
    plr = make("robust-plr", SPACE, seed=2, buffer_size=5, discount=1.0, gae_lambda=1.0)
    plr.set_value_estimator(lambda states: np.asarray(states)[:, 0] * 0.0 + 0.25)
    a, b = plr.sample_task(), plr.sample_task()
    # two interleaved streams; stream 1 finishes first and is reported first
    plr.step_update(a, [0.0], 1.0, a, False, stream=0)
    plr.step_update(b, [0.0], 0.0, b, True, stream=1)
    plr.episodic_update(b, 0.0)
    plr.step_update(a, [0.0], 1.0, a, True, stream=0)
    plr.episodic_update(a, 2.0)
    # b: one step, reward 0, V 0.25 -> advantage -0.25 -> score 0; a: advantages 1.75, 0.75
    assert plr.bk["scores"] == [0.0, pytest.approx(1.25)]
    with pytest.raises(ValueError, match="stream"):
        plr.step_update(a, [0.0], 1.0, a, True, stream="0")


def test_maxmc_score_uses_the_best_return_of_the_level():
    plr = make("robust-plr", SPACE, seed=3, score_function="maxmc", buffer_size=2)
    plr.set_value_estimator(lambda states: np.full(len(states), 0.5))
    _play(plr, 1, lambda t: 2.0, steps=2)
    assert plr.bk["scores"] == [pytest.approx(1.5)]  # best return 2 minus V 0.5


def test_accel_edits_the_replayed_level_by_small_clipped_steps():
    accel = make(
        "accel", SPACE, seed=4, buffer_size=6, nb_edits=1, edit_step=0.1, minimum_fill_ratio=0.5
    )
    span = np.array([1.0, 2.0])
    seen = []
    for _ in range(200):
        task = accel.sample_task()
        kind = accel.bk["kinds"][-1]
        if seen and seen[-1][1] == 1:  # the episode after a replay plays its edited child
            assert kind == 2
            moved = np.abs(task - np.clip(seen[-1][0], 0, [1, 2]))
            assert np.count_nonzero(moved > 1e-6) <= 1
            assert np.all(moved <= 0.1 * span + 1e-6)
        seen.append((task, kind))
        accel.episodic_update(task, float(task.sum()))
    kinds = [k for _, k in seen]
    assert kinds.count(1) > 20 and kinds.count(2) > 20
    assert len(accel.scores) <= 6


def test_accel_starts_from_the_easy_task():
    accel = make("accel", SPACE, seed=5, easy_task=[0.0, 0.0], buffer_size=4)
    first = accel.sample_task()
    np.testing.assert_array_equal(first, [0.0, 0.0])
    with pytest.raises(ValueError, match="easy_task"):
        make("accel", SPACE, easy_task=[3.0, 0.0])
    with pytest.raises(ValueError, match="easy_task"):
        make("accel", SPACE, easy_task=["0", "0"])


def test_accel_from_the_easy_task_replays_it_and_grows_its_buffer_by_edits():
    """New levels from `easy_task` are all one level, so a buffer counted in distinct levels
    never reaches `minimum_fill_ratio`: replay (and with it editing) starts once that level is
    in, and the buffer fills with its edited descendants."""
    accel = make("accel", SPACE, seed=7, easy_task=[0.0, 0.0], buffer_size=20)
    _play(accel, 200, lambda t: float(t.sum()))
    kinds = accel.bk["kinds"]
    assert kinds[0] == 0 and kinds.count(1) > 50 and kinds.count(2) > 50
    assert len(accel.scores) == 20
    assert np.ptp(accel.levels, axis=0).min() > 0.1  # edits moved away from the easy corner


def test_terrain_levels_promote_demote_and_wrap_past_the_top():
    tl = make(
        "terrain-levels",
        SPACE,
        seed=6,
        dimensions=["y"],
        hard_end=["min"],
        nb_levels=4,
        max_init_level=0,
        nb_workers=2,
        promote_return=1.0,
        demote_return=0.0,
    )
    assert list(tl.levels) == [0, 0]
    t0, t1 = tl.sample_task(), tl.sample_task()
    assert 1.5 <= t0[1] <= 2.0 and 1.5 <= t1[1] <= 2.0  # level 0 of "y" hard at its min
    tl.episodic_update(t1, 5.0)  # robot 1 promoted, reported out of order
    tl.episodic_update(t0, -1.0)  # robot 0 demoted (stays at 0)
    assert list(tl.levels) == [0, 1]
    for _ in range(3):  # robot 1 climbs to the top, then past it
        t0, t1 = tl.sample_task(), tl.sample_task()
        tl.episodic_update(t0, 0.5)  # between the thresholds: robot 0 stays
        tl.episodic_update(t1, 5.0)
    assert tl.levels[0] == 0 and tl.levels[1] in range(4)
    assert tl.bk["mean_level"][-1] == tl.levels.mean()


@pytest.mark.parametrize(
    "params, pattern",
    [
        ({"dimensions": ["z"]}, "dimensions"),
        ({"dimensions": "x"}, "dimensions"),
        ({"hard_end": ["up", "max"]}, "hard_end"),
        ({"max_init_level": 10}, "max_init_level"),
        ({"promote_return": 0.0, "demote_return": 1.0}, "demote_return"),
        ({"nb_workers": True}, "nb_workers"),
    ],
)
def test_terrain_levels_validation(params, pattern):
    with pytest.raises(ValueError, match=pattern):
        make("terrain-levels", SPACE, **params)


@pytest.mark.parametrize(
    "params, pattern",
    [
        ({"replay_prob": 1.5}, "replay_prob"),
        ({"temperature": 0.0}, "temperature"),
        ({"score_function": "gae"}, "score_function"),
        ({"buffer_size": "10"}, "buffer_size"),
    ],
)
def test_plr_validation(params, pattern):
    with pytest.raises(ValueError, match=pattern):
        make("robust-plr", SPACE, **params)


@pytest.mark.parametrize("name", ["robust-plr", "accel"])
def test_value_driven_teachers_beat_random_on_the_toy(name):
    scores = {}
    for teacher_name in ("random", name):
        env = ToyEnv(seed=0)
        params = {"buffer_size": 200} if teacher_name != "random" else {}
        teacher = make(teacher_name, env.task_space(), seed=0, **params)
        scores[teacher_name] = run_teacher(teacher, env, 3000).scores[-1]
    assert scores[name] > scores["random"] + 3.0, scores


def test_terrain_levels_climb_the_toy_diagonal():
    env = ToyEnv(seed=0)
    tl = make(
        "terrain-levels",
        env.task_space(),
        seed=0,
        **toy_teacher_params("terrain-levels", env.curriculum_profile, env.task_space()),
    )
    run_teacher(tl, env, 3000)
    assert tl.levels.mean() >= 2 and env.score() >= 3.0


@pytest.mark.parametrize("name", ["robust-plr", "accel"])
def test_resume_with_episodes_in_flight_is_exact(name, tmp_path):
    def run(teacher, n):
        out = []
        for _ in range(n):
            a, b = teacher.sample_task(), teacher.sample_task()
            teacher.step_update(a, [0.0], float(a[0]), a, False, stream=0)
            teacher.step_update(b, [0.0], float(b[1]), b, True, stream=1)
            teacher.episodic_update(b, float(b[1]))
            teacher.step_update(a, [0.0], 0.5, a, True, stream=0)
            teacher.episodic_update(a, float(a[0]) + 0.5)
            out += [a, b]
        return np.asarray(out)

    def critic(states):
        return np.asarray(states)[:, 0] * 0.3

    teacher = make(name, SPACE, seed=8, buffer_size=12)
    teacher.set_value_estimator(critic)
    run(teacher, 20)
    pending = teacher.sample_task()
    teacher.step_update(pending, [0.0], 1.0, pending, False, stream=3)  # mid-episode
    teacher.save(tmp_path / "t")
    restored = make(name, SPACE, seed=0, buffer_size=12)
    restored.set_value_estimator(critic)
    restored.load(tmp_path / "t")
    for t in (teacher, restored):
        t.step_update(pending, [0.0], 1.0, pending, True, stream=3)
        t.episodic_update(pending, 2.0)
    np.testing.assert_array_equal(run(restored, 15), run(teacher, 15))
    assert restored.bk["scores"] == teacher.bk["scores"]


def _older_form(extra: dict) -> dict:
    """A teacher's extra state as checkpoints wrote it before proposals, edits and running
    episodes were kept as columns: a list entry per proposal, an array per edit, a dict entry
    per stream."""
    older = dict(extra)
    columns = older.pop("proposals")
    fields = [columns[k].tolist() for k in columns if k != "tasks"]
    older["pending"] = [[t, *row] for t, row in zip(columns["tasks"], zip(*fields))]
    if "edits" in older:
        older["edits"] = list(older["edits"])
    if "traces" in older:
        traces = older.pop("traces")
        bounds = np.cumsum(traces["lengths"])[:-1]
        parts = zip(np.split(traces["states"], bounds), np.split(traces["rewards"], bounds))
        older["streams"] = {
            str(s): [states, rewards.tolist()]
            for s, (states, rewards) in zip(traces["streams"].tolist(), parts)
        }
    return older


@pytest.mark.parametrize("name", ["robust-plr", "accel", "terrain-levels"])
def test_a_checkpoint_of_the_older_form_resumes_as_the_current_one(name, tmp_path):
    """Proposals in flight, a running episode and (ACCEL) edits, saved in the older form: the
    teacher loaded from it continues as the one loaded from the current form."""
    params = {"nb_workers": 4} if name == "terrain-levels" else {"buffer_size": 12}
    teacher = make(name, SPACE, seed=8, **params)
    teacher.set_value_estimator(lambda states: np.asarray(states)[:, 0] * 0.3)
    for k in range(30):
        task = teacher.sample_task()
        teacher.step_update(task, [0.0], float(task[0]), task, True, stream=k % 4)
        teacher.episodic_update(task, float(task[0]))
    tasks = [teacher.sample_task() for _ in range(10)]  # in flight, replays among them
    teacher.step_update(tasks[0], [0.0], 1.0, tasks[0], False, stream=5)  # mid-episode
    state = teacher.state_dict()
    assert len(state["extra"]["proposals"]["tasks"]) >= 9
    older = dict(state, extra=_older_form(state["extra"]))
    copies = []
    for form in (state, older):
        copy = make(name, SPACE, seed=0, **params)
        copy.set_value_estimator(lambda states: np.asarray(states)[:, 0] * 0.3)
        copy.load_state_dict(form)
        copies.append(copy)
    for copy in copies:
        for task in tasks:
            copy.step_update(task, [0.0], 2.0, task, True, stream=5)
            copy.episodic_update(task, 2.0)
    current, loaded_older = copies
    np.testing.assert_array_equal(
        [loaded_older.sample_task() for _ in range(10)], [current.sample_task() for _ in range(10)]
    )
    assert loaded_older.bk == current.bk
