"""ML-Agents lesson curricula: exact advancement rule, smoothing, min length, file formats."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from acl3d.teachers import make
from acl3d.teachers.lessons import Lessons

SPACE = {"stump_height": [0.0, 3.0], "obstacle_spacing": [0.0, 6.0]}


def curriculum(**kw):
    base = {
        "measure": "reward",
        "thresholds": [10.0, 20.0],
        "min_lesson_length": 1,
        "signal_smoothing": False,
        "parameters": {"stump_height": [0.0, 1.0, 2.0]},
    }
    base.update(kw)
    return base


def feed(teacher, rewards):
    lessons = []
    for r in rewards:
        teacher.episodic_update(teacher.sample_task(), r)
        lessons.append(teacher.lesson)
    return lessons


def test_advances_strictly_above_threshold():
    t = Lessons(SPACE, seed=0, curriculum=curriculum())
    assert feed(t, [10.0]) == [0]  # equal to the threshold: stays
    assert feed(t, [10.0001]) == [1]
    assert feed(t, [20.0, 25.0, 1000.0]) == [1, 2, 2]  # the last lesson is final


def test_min_lesson_length_counts_episodes_in_the_lesson():
    t = Lessons(SPACE, seed=0, curriculum=curriculum(min_lesson_length=3))
    assert feed(t, [50, 50, 50, 50, 50, 50]) == [0, 0, 1, 1, 1, 2]
    assert t.bk["lesson"] == [0, 0, 0, 1, 1, 1]


def test_signal_smoothing_uses_ml_agents_weights():
    t = Lessons(SPACE, seed=0, curriculum=curriculum(signal_smoothing=True))
    # m1 = 0.75 * 12 = 9 (<= 10); m2 = 0.25 * 9 + 0.75 * 12 = 11.25 (> 10)
    assert feed(t, [12.0, 12.0]) == [0, 1]
    np.testing.assert_allclose(t.bk["measure"], [9.0, 11.25])
    # smoothing carries across lessons: m3 = 0.25 * 11.25 + 0.75 * 24 = 20.8125 > 20
    assert feed(t, [24.0]) == [2]


def test_exactly_at_threshold_after_smoothing():
    t = Lessons(SPACE, seed=0, curriculum=curriculum(signal_smoothing=True, thresholds=[9.0, 20.0]))
    assert feed(t, [12.0]) == [0]  # m = 9.0 == threshold


def test_progress_measure_counts_steps_over_max_steps():
    t = Lessons(
        SPACE,
        seed=0,
        curriculum=curriculum(measure="progress", thresholds=[0.5, 0.9]),
        max_steps=100,
    )
    assert "step_rewards" in t.needs
    lessons = []
    for _ in range(4):
        task = t.sample_task()
        for _ in range(25):
            t.step_update(None, None, 0.0, None, False)
        t.episodic_update(task, -1.0)
        lessons.append(t.lesson)
    assert lessons == [0, 0, 1, 2]  # progress 0.25, 0.5 (not > 0.5), 0.75, 1.0
    with pytest.raises(ValueError, match="max_steps"):
        Lessons(SPACE, curriculum=curriculum(measure="progress"))


def test_sampled_tasks_follow_the_lesson_and_randomise_the_rest():
    t = Lessons(SPACE, seed=0, curriculum=curriculum())
    tasks = np.array([t.sample_task() for _ in range(50)])
    assert tasks.dtype == np.float32
    assert np.all(tasks[:, 0] == 0.0)
    assert tasks[:, 1].min() >= 0 and tasks[:, 1].max() <= 6 and tasks[:, 1].std() > 1
    feed(t, [11.0])
    assert np.all(np.array([t.sample_task() for _ in range(5)])[:, 0] == 1.0)
    state = t.plot_state()
    assert (
        state["kind"] == "lesson"
        and state["index"] == 1
        and state["current"] == {"stump_height": 1.0}
    )
    np.testing.assert_array_equal(state["tasks"], [[0.0, 3.0], [1.0, 3.0], [2.0, 3.0]])


def test_multi_dimensional_parameters_and_constant_dims():
    space = {"poly": [0.0, 4.0, 3], "const": [1.0, 1.0]}
    t = Lessons(
        space, seed=0, curriculum=curriculum(parameters={"poly": [0.5, [1.0, 2.0, 3.0], 4.0]})
    )
    feed(t, [11.0])
    np.testing.assert_array_equal(t.sample_task(), np.array([1.0, 2.0, 3.0, 1.0], dtype=np.float32))


def test_top_level_parameters_and_files(tmp_path):
    original_style = {
        "measure": "reward",
        "thresholds": [10.0],
        "min_lesson_length": 2,
        "signal_smoothing": True,
        "obstacle_spacing": [6.0, 3.0],
    }
    (tmp_path / "c.json").write_text(json.dumps(original_style))
    (tmp_path / "c.yaml").write_text(yaml.safe_dump(original_style))
    for path in (tmp_path / "c.json", str(tmp_path / "c.yaml")):
        t = make("lessons", SPACE, seed=0, curriculum=path)
        assert t.current_values() == {"obstacle_spacing": 6.0} and t.min_lesson_length == 2


def test_same_seed_same_tasks_and_resume(tmp_path):
    a, b = (
        Lessons(SPACE, seed=4, curriculum=curriculum()),
        Lessons(SPACE, seed=4, curriculum=curriculum()),
    )
    assert feed(a, [5.0, 11.0, 5.0]) == feed(b, [5.0, 11.0, 5.0])
    a.save(tmp_path / "lessons")
    c = Lessons(SPACE, seed=0, curriculum=curriculum())
    c.load(tmp_path / "lessons")
    assert c.lesson == 1
    np.testing.assert_array_equal(
        [a.sample_task() for _ in range(5)], [c.sample_task() for _ in range(5)]
    )


@pytest.mark.parametrize(
    "change, message",
    [
        ({"measure": "steps"}, "measure"),
        ({"thresholds": [1.0, float("nan")]}, "thresholds"),
        ({"min_lesson_length": -1}, "min_lesson_length"),
        ({"signal_smoothing": "yes"}, "signal_smoothing"),
        ({"parameters": {"stump_height": [0.0, 1.0]}}, "expected 3 values"),
        ({"parameters": {"height": [0.0, 1.0, 2.0]}}, "not a task parameter"),
        ({"parameters": {"stump_height": [0.0, 1.0, 9.0]}}, "outside the bounds"),
        ({"parameters": {}}, "names no parameters"),
    ],
)
def test_invalid_curricula_raise_clear_errors(change, message):
    with pytest.raises(ValueError, match=message):
        Lessons(SPACE, curriculum=curriculum(**change))


def test_missing_or_bad_curriculum_source(tmp_path):
    with pytest.raises(ValueError, match="curriculum is required"):
        Lessons(SPACE)
    with pytest.raises(ValueError, match="does not exist"):
        Lessons(SPACE, curriculum=tmp_path / "nope.json")
    (tmp_path / "c.txt").write_text("{}")
    with pytest.raises(ValueError, match=".json, .yaml"):
        Lessons(SPACE, curriculum=tmp_path / "c.txt")
