"""A torch-native run's curriculum in rounds: the tasks it hands out, what waits, exact resume."""

from __future__ import annotations

import numpy as np
import pytest

from acl3d.envs.episode_statistics import EpisodeBatch
from acl3d.teachers.controller import TeacherController
from acl3d.training.torch_student.curriculum_rounds import CurriculumRounds, reserve_for
from acl3d.training.torch_student.phase_times import PhaseTimes

SPACE = {"stump_height": (0.0, 3.0), "obstacle_spacing": (0.0, 6.0)}
PARAMS = {"fit_rate": 10, "nb_bootstrap": 10, "potential_ks": [2, 3]}


def controller() -> TeacherController:
    return TeacherController("alp-gmm", SPACE, 3, teacher_params=PARAMS)


def episodes(tasks: np.ndarray, ids: np.ndarray, step: int) -> EpisodeBatch:
    """Episodes on `tasks` whose returns grow with the step (a learner that improves)."""
    m = len(ids)
    returns = step / 10.0 - 20.0 * tasks[:, 0] + np.arange(m)
    return EpisodeBatch(
        ids.astype(np.int64), tasks.astype(np.float32), returns, np.full(m, 50, np.int64),
        returns > 100.0, np.zeros(m, bool), np.full(m, step, np.int64),
    )  # fmt: skip


WORLDS = 12


class EndingWorlds:
    """Worlds that end episodes at a varying pace (the same pace for every sync they meet)."""

    def __init__(self, sync: CurriculumRounds, worlds: int = WORLDS):
        self.rng = np.random.default_rng(0)
        self.current = sync.sync(EpisodeBatch.empty(2), np.arange(worlds))

    def run(self, sync: CurriculumRounds, steps: range) -> list[np.ndarray]:
        """Every step's handed-out tasks."""
        handed = []
        for step in steps:
            done = np.flatnonzero(self.rng.random(len(self.current)) < 0.3)
            if len(done):
                tasks = sync.sync(episodes(self.current[done], done, step), done)
                self.current[done] = tasks
                handed.append(tasks.copy())
        return handed


def test_without_a_reserve_each_sync_learns_then_draws_what_is_needed():
    direct, rounds = controller(), controller()
    sync = CurriculumRounds(rounds, PhaseTimes(), reserve=0, num_envs=5)
    first = sync.sync(EpisodeBatch.empty(2), np.arange(5))
    np.testing.assert_array_equal(first, direct.sample_training_tasks(5)[0])
    batch = episodes(first[:2], np.arange(2), 100)
    tasks = sync.sync(batch, np.arange(2))
    direct.record_episodes(batch)
    np.testing.assert_array_equal(tasks, direct.sample_training_tasks(2)[0])
    assert sync.state()["drawn"].shape == (0, 2) and "waiting" not in sync.state()


def test_rounds_draw_ahead_and_learn_what_waited():
    c = controller()
    sync = CurriculumRounds(c, PhaseTimes(), reserve=4, num_envs=3)
    first = sync.sync(EpisodeBatch.empty(2), np.arange(3))
    assert first.shape == (3, 2) and len(sync.state()["drawn"]) == 4
    drawn = sync.state()["drawn"]
    # two episodes end: served from the tasks drawn ahead, learnt at the next round
    tasks = sync.sync(episodes(first[:2], np.arange(2), 10), np.arange(2))
    np.testing.assert_array_equal(tasks, drawn[:2])
    assert len(c.teacher.bk["tasks_alps"]) == 0 and len(sync.state()["waiting"]["returns"]) == 2
    # three more: one left, so a round learns the two waiting and these three, then draws
    tasks = sync.sync(episodes(first[:3], np.arange(3), 20), np.arange(3))
    np.testing.assert_array_equal(tasks[0], drawn[2])
    assert len(c.teacher.bk["tasks_alps"]) == 5 and "waiting" not in sync.state()
    assert len(sync.state()["drawn"]) == 4  # 2 more than needed, then the reserve
    assert sync.episodes_done == 5 and sum(len(b) for b in sync.finished) == 5
    sync.sync(episodes(tasks[:1], np.arange(1), 30), np.arange(1))
    sync.learn_waiting()
    assert len(c.teacher.bk["tasks_alps"]) == 6


def test_a_run_resumed_from_a_rounds_state_equals_the_uninterrupted_one():
    whole = CurriculumRounds(controller(), PhaseTimes(), reserve=5, num_envs=WORLDS)
    handed = EndingWorlds(whole).run(whole, range(0, 400, 10))
    first = CurriculumRounds(controller(), PhaseTimes(), reserve=5, num_envs=WORLDS)
    worlds = EndingWorlds(first)
    before = worlds.run(first, range(0, 200, 10))
    assert "waiting" in first.state() and len(first.state()["drawn"])  # both in flight
    again = CurriculumRounds(controller(), PhaseTimes(), reserve=5, num_envs=WORLDS)
    again.controller.load_state_dict(first.controller.state_dict())
    again.load_state(first.state())
    after = worlds.run(again, range(200, 400, 10))
    assert len(before) + len(after) == len(handed)
    for a, b in zip(before + after, handed):
        np.testing.assert_array_equal(a, b)
    whole.learn_waiting()
    again.learn_waiting()
    assert whole.controller.teacher.bk["tasks_alps"] == again.controller.teacher.bk["tasks_alps"]


@pytest.mark.parametrize(
    ("n_envs", "many_worlds", "reserve"),
    [(4, True, 1), (4096, True, 64), (16384, True, 256), (64, False, 0), (4096, False, 0)],
)
def test_the_reserve_grows_with_the_worlds_on_the_many_world_simulation(
    n_envs, many_worlds, reserve
):
    assert reserve_for(n_envs, many_worlds) == reserve
