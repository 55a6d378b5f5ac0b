"""Behaviour of each curriculum teacher on a simulated learner over Stump Tracks' task space.

The learner's skill grows only with practice near its frontier: an episode on a task of
difficulty d succeeds with probability sigmoid((skill - d) / 0.03), and playing a task just past
the frontier raises the skill. A teacher that does what its paper says proposes harder tasks as
the skill grows; one stuck on a fixed region (a window on the hard corner, a box around one
random task) fails these tests. Each test runs in about a second.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from acl3d.envs.profiles import STUMP_TRACKS
from acl3d.teachers import make
from acl3d.teachers.expert_knowledge import teacher_params
from acl3d.terrain.tracks import track_task_space

SPACE = track_task_space(("stump_height", "obstacle_spacing"))  # [0, 3] x [0, 6]


def difficulty(task: np.ndarray) -> float:
    """0 at the easy corner (height 0, spacing 6), 1 at the hard one (height 3, spacing 0)."""
    return float((task[0] / 3.0 + (6.0 - task[1]) / 6.0) / 2.0)


class StubLearner:
    """A student whose skill (the difficulty it masters) grows with practice at its frontier."""

    def __init__(self, seed: int, skill: float = 0.15, rate: float = 0.004):
        self.rng = np.random.default_rng(seed)
        self.skill, self.rate = skill, rate

    def play(self, task: np.ndarray) -> tuple[float, bool]:
        d = difficulty(task)
        p_success = 1.0 / (1.0 + np.exp(-(self.skill - d) / 0.03))
        episode_return = -100.0 + 400.0 * p_success + self.rng.normal(0.0, 10.0)
        self.skill = min(1.0, self.skill + self.rate * np.exp(-(((d - self.skill) / 0.1) ** 2)))
        return episode_return, bool(episode_return > STUMP_TRACKS.success_return)


# small, fast settings where a teacher's defaults take minutes (GAN sizes, fit rates)
FAST = {
    "goal-gan": {
        "generator_hidden": (32, 32),
        "discriminator_hidden": (32, 32),
        "nb_pretrain_samples": 200,
        "pretrain_iters": 50,
        "gan_train_iters": 25,
        "batch_size": 32,
        "update_size": 40,
    },
    "alp-gmm": {"fit_rate": 100, "potential_ks": [2, 3, 4]},
    "covar-gmm": {"fit_rate": 100, "potential_ks": [2, 3, 4]},
    "riac": {"max_region_size": 60},
}


@pytest.fixture(autouse=True)
def one_torch_thread():
    """The GAN's small batches: threads only add overhead on a shared machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def run(name: str, episodes: int, seed: int = 0):
    params = {**teacher_params(name, STUMP_TRACKS, SPACE, "low"), **FAST.get(name, {})}
    teacher = make(name, SPACE, seed=seed, **params)
    learner = StubLearner(seed)
    difficulties, skills = [], []
    for _ in range(episodes):
        task = teacher.sample_task()
        episode_return, success = learner.play(task)
        teacher.episodic_update(task, episode_return, success)
        difficulties.append(difficulty(task))
        skills.append(learner.skill)
    return np.array(difficulties), np.array(skills)


@pytest.mark.parametrize(
    "name, episodes",
    [
        ("oracle", 2000),
        ("adr", 2000),
        ("goal-gan", 800),
        ("alp-gmm", 2000),
        ("covar-gmm", 2000),
        ("riac", 2000),
    ],
)
def test_proposed_tasks_get_harder_as_the_learner_improves(name, episodes):
    difficulties, skills = run(name, episodes)
    window = episodes // 5
    early, late = difficulties[:window].mean(), difficulties[-window:].mean()
    assert skills[-1] > skills[0] + 0.2, f"{name}: the learner did not improve ({skills[-1]:.2f})"
    assert late > early + 0.1, f"{name}: proposed difficulty {early:.2f} -> {late:.2f}"


@pytest.mark.parametrize("name", ["oracle", "adr", "goal-gan"])
def test_the_first_tasks_are_on_the_environments_easy_side(name):
    difficulties, _ = run(name, 50)
    assert difficulties.mean() < 0.25, f"{name} starts at difficulty {difficulties.mean():.2f}"


def test_adr_random_start_is_teachmyagents_and_can_be_stuck():
    """TeachMyAgent's ADR under expert knowledge "low" starts at a random task: on a hard one
    the box is a single task for the whole run (stump-v1 seeds 0-2)."""
    params = {**teacher_params("adr", STUMP_TRACKS, SPACE, "low"), "start": "random"}
    for seed in range(20):
        teacher = make("adr", SPACE, seed=seed, **params)
        if difficulty(teacher.cur_low) > 0.5:
            break
    learner = StubLearner(0)
    for _ in range(500):
        task = teacher.sample_task()
        teacher.episodic_update(task, *learner.play(task))
    np.testing.assert_array_equal(teacher.cur_low, teacher.cur_high)
