"""Teachers that learn from steps take a whole vector of envs' steps in one call: the result is
that of one call per env in env order, a checkpoint between steps resumes exactly, a bad batch
changes nothing, and proposals of more worlds than any run had before stay matched."""

from __future__ import annotations

import numpy as np
import pytest
from test_teachers_classic import SPACES

from acl3d.teachers import make
from acl3d.teachers.lessons import Lessons
from acl3d.teachers.state_files import load_state, save_state
from acl3d.teachers.terrain_levels import TerrainLevels

SPACE = SPACES["2d"]
STEP_TEACHERS = {
    "robust-plr": {"buffer_size": 8},
    "accel": {"buffer_size": 8, "nb_edits": 2},
    "self-paced": {"update_frequency": 7, "update_offset": 10, "alpha_offset": 2},
}
N, STEPS = 6, 120


def _critic(states) -> np.ndarray:
    return np.tanh(np.asarray(states, dtype=np.float64) @ np.array([0.3, -0.2, 0.1]))


def _make(name: str):
    teacher = make(name, SPACE, seed=4, **STEP_TEACHERS[name])
    teacher.set_value_estimator(_critic)
    return teacher


def _play(teacher, batched: bool, steps: range, running: dict, tmp_path=None, name=None):
    """Six envs stepping together for `steps`; each ended episode is learnt after its step
    (its first state recorded for SPDL). With `tmp_path`, the teacher is saved and reloaded
    into a fresh one halfway. Returns the teacher (possibly the reloaded one)."""
    rng = np.random.default_rng(steps.start)
    for t in steps:
        for i in range(N):
            if i not in running:
                task = teacher.sample_task()
                running[i] = (task, rng.normal(size=3).astype(np.float32))
        states = np.stack([running[i][1] for i in range(N)]) + np.float32(t % 5)
        rewards = rng.normal(size=N) * 3
        dones = rng.random(N) < 0.08
        actions = rng.normal(size=(N, 2))
        if batched:
            teacher.step_updates(states, actions, rewards, states, dones)
        else:
            for i in range(N):
                teacher.step_update(states[i], actions[i], rewards[i], states[i], dones[i], i)
        for i in np.flatnonzero(dones):
            task, first = running.pop(int(i))
            teacher.record_initial_state(task, first)
            teacher.episodic_update(task, float(rewards[i] * 10))
        if tmp_path is not None and t == steps.start + len(steps) // 2:
            save_state(tmp_path / name, teacher.state_dict())
            teacher = _make(name)
            teacher.load_state_dict(load_state(tmp_path / name))
    return teacher


@pytest.mark.parametrize("name", list(STEP_TEACHERS))
def test_a_batch_of_steps_is_one_step_call_per_env_in_env_order(name, tmp_path):
    singly = _play(_make(name), False, range(STEPS), {})
    batched = _play(_make(name), True, range(STEPS), {})
    resumed = _play(_make(name), True, range(STEPS), {}, tmp_path, name)
    assert batched.nb_episodes > 20
    for other in (batched, resumed):
        np.testing.assert_equal(other.state_dict(), singly.state_dict())
        np.testing.assert_equal(other.dump(), singly.dump())
    if name == "self-paced":
        assert batched.algo_iterations > 5  # updates fell inside batches


@pytest.mark.parametrize("name", ["robust-plr", "accel"])
def test_a_batch_of_episodes_asks_the_critic_once_and_scores_as_one_at_a_time(name):
    """The episodes a batch learns get their critic values in one call to `episodes` (one
    copy to a GPU and back); the teacher ends as with an `episodic_update` each."""
    calls = []

    def episodes(states: list) -> list:
        calls.append(len(states))
        return [_critic(s) for s in states]

    def play(batched: bool):
        teacher = _make(name)
        if batched:
            teacher.set_value_estimator(_critic, episodes)
        rng = np.random.default_rng(0)
        for _ in range(6):
            tasks = teacher.sample_tasks(N)
            for _ in range(rng.integers(3, 9)):  # the episodes' steps, the last one ending them
                teacher.step_updates(rng.normal(size=(N, 3)).astype(np.float32), None,
                                     rng.normal(size=N), None, np.zeros(N, bool))  # fmt: skip
            teacher.step_updates(rng.normal(size=(N, 3)).astype(np.float32), None,
                                 rng.normal(size=N), None, np.ones(N, bool))  # fmt: skip
            returns = rng.normal(size=N) * 10
            if batched:
                teacher.update_batch(tasks, returns)
            else:
                for task, ret in zip(tasks, returns):
                    teacher.episodic_update(task, float(ret))
        return teacher

    one_by_one, together = play(False), play(True)
    assert calls == [N] * 6
    np.testing.assert_equal(together.state_dict(), one_by_one.state_dict())
    np.testing.assert_equal(together.dump(), one_by_one.dump())


def test_lessons_count_a_batch_as_its_steps():
    def lessons(batched: bool) -> Lessons:
        t = make(
            "lessons", SPACE, seed=0, max_steps=100,
            curriculum={"measure": "progress", "thresholds": [0.5, 0.9], "parameters": {
                "stump_height": [0.0, 1.0, 2.0]}},
        )  # fmt: skip
        for _ in range(3):
            task = t.sample_task()
            if batched:
                t.step_updates(None, None, np.zeros(40), None, np.zeros(40, bool), np.arange(40))
            else:
                for i in range(40):
                    t.step_update(None, None, 0.0, None, False, i)
            t.episodic_update(task, 0.0)
        return t

    assert lessons(True).state_dict() == lessons(False).state_dict()
    assert lessons(True).lesson == 2


@pytest.mark.parametrize(
    "bad, match",
    [
        ({"rewards": np.array([1.0, np.nan, 0.0])}, "rewards"),
        ({"rewards": np.zeros((3, 1))}, "rewards"),
        ({"dones": np.array([0, 2, 0])}, "dones"),
        ({"streams": np.array([0, 1, 1])}, "streams"),
        ({"streams": np.array([0, 1, 1 << 20])}, "streams"),
        ({"states": np.full((3, 3), np.inf, np.float32)}, "states"),
        ({"states": np.zeros((2, 3), np.float32)}, "states"),
    ],
)
def test_a_bad_batch_of_steps_names_its_argument_and_changes_nothing(bad, match):
    teacher = _make("robust-plr")
    good = {
        "states": np.zeros((3, 3), np.float32),
        "actions": np.zeros((3, 2)),
        "rewards": np.ones(3),
        "next_states": np.zeros((3, 3), np.float32),
        "dones": np.array([False, True, False]),
        "streams": np.array([0, 5, 2]),
    }
    teacher.step_updates(**good)
    before = teacher.state_dict()
    with pytest.raises(ValueError, match=match):
        teacher.step_updates(**{**good, **bad})
    np.testing.assert_equal(teacher.state_dict(), before)
    with pytest.raises(ValueError, match="stream"):
        teacher.step_update(np.zeros(3), None, 0.0, None, False, stream=1 << 20)


def test_proposals_of_more_worlds_than_four_thousand_stay_matched():
    """Every world holds a proposal until its episode ends: 10,000 in flight are all matched
    back (their robot's level and their level's kind), oldest first."""
    levels = TerrainLevels(SPACE, seed=0, nb_workers=10_000, promote_return=0.5, demote_return=0)
    tasks = levels.sample_tasks(10_000)
    before = levels.levels.copy()
    levels.update_batch(tasks, np.ones(10_000))
    assert np.all(levels.levels == np.minimum(before + 1, levels.nb_levels - 1))
    assert len(levels._pending) == 0
    plr = make("robust-plr", SPACE, seed=0, buffer_size=8)
    tasks = plr.sample_tasks(10_000)
    assert plr.is_exploratory(tasks[0])  # a new level, not forgotten
    plr.update_batch(tasks, np.zeros(10_000))
    assert len(plr._pending) == 0


@pytest.mark.parametrize(
    "name, params",
    [
        ("self-paced", {"update_frequency": 5, "update_offset": 0}),
        ("setter-solver", {"update_frequency": 10}),
    ],
)
def test_a_teacher_trains_the_same_inside_a_students_inference_mode(name, params):
    """Students collect under torch.inference_mode and teachers learn in the middle of a step:
    the networks and distributions they train must not notice."""
    import torch

    def play(inference: bool):
        teacher = make(name, SPACE, seed=0, **params)
        with torch.inference_mode(inference):
            for i in range(120):
                task = teacher.sample_task()
                teacher.step_update(np.zeros(3), None, 1.0, None, True, 0)
                teacher.episodic_update(task, float(i % 3), is_success=bool(i % 2))
        return teacher.state_dict()

    np.testing.assert_equal(play(True), play(False))


def test_pending_proposals_match_as_the_whole_comparison_does():
    """Candidates come from a hash of the task (the whole task, or the first dimension's bucket
    of one tolerance's width); the oldest and newest matches are those of comparing every
    dimension of every proposal (exactly, or within a tolerance per dimension), before and
    after proposals go."""
    from acl3d.teachers.pending import PendingTasks

    rng = np.random.default_rng(0)
    tasks = rng.random((500, 3)).astype(np.float32).astype(np.float64)
    tasks[50:60, 0] = tasks[5, 0]  # candidates on the first dimension that differ elsewhere
    tasks[70] = tasks[5]
    span = np.array([3.0, 6.0, 1.0])
    tasks[80:90] = tasks[6]  # across neighbouring buckets, the older ones in the higher
    tasks[80:90, 0] += np.linspace(2e-5, -2e-5, 10) * span[0]
    for within in ((1.0, 0.0), (span, 1e-5), (1.0, 1e-4 * span)):
        pending, kept = PendingTasks(3, *within), np.ones(len(tasks), bool)
        for task in tasks:
            pending.add(task, None)
        for k in range(300):
            query = tasks[rng.integers(500)] + (rng.random(3) - 0.5) * [0, 1e-6, 1e-4][k % 3]
            if k % 7 == 0:
                query = tasks[6].copy()
                query[0] += (rng.random() - 0.5) * 5e-5 * span[0]
            whole = (np.abs(tasks - query) / within[0] <= within[1]).all(axis=1) & kept
            found = np.flatnonzero(whole)
            assert pending.oldest(query) == (found[0] if len(found) else None)
            assert pending.newest(query) == (found[-1] if len(found) else None)
            if k % 3 == 0 and len(found):  # the oldest match goes, as a teacher pops it
                gone = int(found[0])
                np.testing.assert_array_equal(pending.pop(gone)[0], tasks[gone])
                kept[gone] = False
        assert [t.tolist() for t, _ in pending.items()] == tasks[kept].tolist()
    pending = PendingTasks(3)
    for task in tasks:
        pending.add(task, None)
    assert (pending.oldest(tasks[5]), pending.newest(tasks[5])) == (5, 70)


def test_running_episodes_kept_in_pages_come_back_whole():
    """Robust PLR's running episodes, kept in pages of a shared pool, come back as a record of
    every step would give them: streams stepping in any subset and order, episodes across many
    pages, a checkpoint's state reloaded midway; pages in use are those of the running
    episodes' steps."""
    from acl3d.teachers.step_streams import StepTraces

    rng = np.random.default_rng(0)
    traces, reference, page = StepTraces(), {}, StepTraces.PAGE
    for step in range(600):
        streams = rng.permutation(40)[: rng.integers(1, 40)]
        states = rng.normal(size=(len(streams), 3)).astype(np.float32)
        rewards, dones = rng.normal(size=len(streams)), rng.random(len(streams)) < 0.01
        ended = traces.add(streams, states, rewards, dones)
        expected = []
        for k, s in enumerate(streams.tolist()):
            reference.setdefault(s, []).append((states[k], rewards[k]))
            if dones[k]:
                expected.append(reference.pop(s))
        assert len(ended) == len(expected)
        for (got_states, got_rewards), steps in zip(ended, expected):
            np.testing.assert_array_equal(got_states, np.stack([st for st, _ in steps]))
            np.testing.assert_array_equal(got_rewards, [r for _, r in steps])
            assert got_states.dtype == np.float32
        if step % 150 == 149:  # a checkpoint's round trip
            state = traces.state()
            traces = StepTraces()
            traces.load_state(state)
        in_use = (traces.pages >= 0).sum()
        assert in_use == sum(-(-len(steps) // page) for steps in reference.values())
    assert max(len(steps) for steps in reference.values()) > 3 * page


def test_running_episodes_of_an_older_checkpoint_load_as_written():
    """A checkpoint written before the flat form ({stream: [states, rewards]}) loads to the
    same running episodes as the flat form."""
    from acl3d.teachers.step_streams import StepTraces

    rng = np.random.default_rng(1)
    traces = StepTraces()
    for _ in range(150):
        streams = rng.permutation(30)[: rng.integers(1, 30)]
        states = rng.normal(size=(len(streams), 5)).astype(np.float32)
        traces.add(streams, states, rng.normal(size=len(streams)), rng.random(len(streams)) < 0.02)
    flat = traces.state()
    bounds = np.cumsum(flat["lengths"])[:-1]
    older = {
        str(s): [states, rewards.tolist()]
        for s, states, rewards in zip(
            flat["streams"].tolist(),
            np.split(flat["states"], bounds),
            np.split(flat["rewards"], bounds),
        )
    }
    loaded = StepTraces()
    loaded.load_state(StepTraces.flat(older))
    again = loaded.state()
    assert again.keys() == flat.keys()
    for key, value in flat.items():
        np.testing.assert_array_equal(again[key], value)
        assert again[key].dtype == value.dtype
    everyone = flat["streams"]
    ones = np.ones(len(everyone), dtype=bool)
    for (a_states, a_rewards), (b_states, b_rewards) in zip(
        traces.add(
            everyone, np.zeros((len(everyone), 5), np.float32), np.zeros(len(everyone)), ones
        ),
        loaded.add(
            everyone, np.zeros((len(everyone), 5), np.float32), np.zeros(len(everyone)), ones
        ),
    ):
        np.testing.assert_array_equal(a_states, b_states)
        np.testing.assert_array_equal(a_rewards, b_rewards)
