"""Test sets: the default rule (the stump grid, else seeded uniform tasks), named sets, grids,
files (matched by column name) and their checks, and the test episodes a controller records."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_controller import MIXED, STUMPS

from acl3d.envs.profiles import PARKOUR, STUMP_TRACKS
from acl3d.task_space import TaskSpace
from acl3d.teachers import test_sets as ts
from acl3d.teachers.controller import TeacherController
from acl3d.terrain import parkour_test_sets
from acl3d.terrain.parkour import parkour_task_space


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
