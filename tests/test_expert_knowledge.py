"""Expert knowledge: what each level gives each teacher (the environment's facts at every level,
its prior at "high"), accepted by every teacher's constructor and reaching it in teacher space."""

from __future__ import annotations

import inspect

import numpy as np
import pytest
from test_controller import STUMPS

from acl3d.envs.profiles import HEXAGON_TRACKS, PARKOUR, STUMP_TRACKS
from acl3d.task_space import TaskSpace
from acl3d.teachers import TEACHERS, teacher_class
from acl3d.teachers.controller import TeacherController
from acl3d.teachers.expert_knowledge import expert_knowledge


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
