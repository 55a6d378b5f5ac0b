"""Behaviour of each curriculum teacher on a simulated learner over Stump Tracks' task space.

The learner's skill grows only with practice near its frontier: an episode on a task of
difficulty d returns -100 + 400 sigmoid((skill - d) / 0.03) plus noise of std 10 and succeeds
above 230: almost surely below d = skill - 0.05, almost never above skill - 0.04 (success
rates between 0.25 and 0.75 only within 0.007 of difficulty), and playing a task just past the frontier raises
the skill. A teacher that does what its paper says proposes harder tasks as
the skill grows; one stuck on a fixed region (a window on the hard corner, a box around one
random task) fails these tests. The main ones play seeds 0-2; each runs in a few seconds
(Setter-Solver's in about 12; the file in about 25 s of CPU).

Teachers that need more than returns get what a training loop gives them (their `needs`): each
stub episode is STEPS steps sharing its return, its states are (task, fraction of the episode
left), and the value estimator is a critic whose skill estimate lags the learner's (a critic
that is always exact leaves no advantage for Robust PLR to score). Episodes a teacher marks
exploratory do not train the learner, as in acl3d's training.
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

    def play(self, task: np.ndarray, learn: bool = True) -> tuple[float, bool]:
        d = difficulty(task)
        episode_return = expected_return(self.skill, d) + self.rng.normal(0.0, 10.0)
        if learn:
            gain = self.rate * np.exp(-(((d - self.skill) / 0.1) ** 2))
            self.skill = min(1.0, self.skill + gain)
        return episode_return, bool(episode_return > STUMP_TRACKS.success_return)


def expected_return(skill, d):
    return -100.0 + 400.0 / (1.0 + np.exp(-(skill - d) / 0.03))


STEPS = 10  # steps per stub episode, for teachers that take step rewards


class LaggingCritic:
    """V(state) from a skill estimate that follows the learner's skill with a lag."""

    def __init__(self, skill: float, rate: float = 0.05):
        self.skill, self.rate = skill, rate

    def __call__(self, states: np.ndarray) -> np.ndarray:
        d = np.array([difficulty(s[:2]) for s in states])
        return expected_return(self.skill, d) * states[:, 2]

    def follow(self, skill: float) -> None:
        self.skill += self.rate * (skill - self.skill)


# small, fast settings where a teacher's defaults take minutes (GAN sizes, fit rates)
FAST = {
    "goal-gan": {
        "generator_hidden": (32, 32),
        "discriminator_hidden": (32, 32),
        "nb_pretrain_samples": 200,
        "pretrain_iters": 500,  # the default: at 50 the generator is half pretrained (below)
        "gan_train_iters": 25,
        "batch_size": 32,
        "update_size": 40,
    },
    "alp-gmm": {"fit_rate": 100, "potential_ks": [2, 3, 4]},
    "covar-gmm": {"fit_rate": 100, "potential_ks": [2, 3, 4]},
    "riac": {"max_region_size": 60},
    "self-paced": {"update_frequency": 200, "update_offset": 1000},  # steps: every 20 episodes
    "robust-plr": {"buffer_size": 100},
    "accel": {"buffer_size": 100},
}


@pytest.fixture(autouse=True)
def one_torch_thread():
    """The GAN's small batches: threads only add overhead on a shared machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def run(name: str, episodes: int, seed: int = 0, level: str = "low", rate: float = 0.004, **extra):
    """Proposed difficulties, the learner's skill after each episode and whether each episode
    was exploratory."""
    params = {**teacher_params(name, STUMP_TRACKS, SPACE, level), **FAST.get(name, {}), **extra}
    teacher = make(name, SPACE, seed=seed, **params)
    learner = StubLearner(seed, rate=rate)
    critic = LaggingCritic(learner.skill)
    if "value_estimator" in teacher.needs:
        teacher.set_value_estimator(critic)
    difficulties, skills, exploratory = [], [], []
    for _ in range(episodes):
        task = teacher.sample_task()
        explore = teacher.is_exploratory(task)
        teacher.record_initial_state(task, np.array([*task, 1.0]))
        episode_return, success = learner.play(task, learn=not explore)
        if "step_rewards" in teacher.needs:
            for t in range(STEPS):
                state = np.array([*task, 1.0 - t / STEPS])
                done = t == STEPS - 1
                teacher.step_update(state, None, episode_return / STEPS, state, done)
        teacher.episodic_update(task, episode_return, success)
        critic.follow(learner.skill)
        difficulties.append(difficulty(task))
        skills.append(learner.skill)
        exploratory.append(explore)
    return np.array(difficulties), np.array(skills), np.array(exploratory)


SEEDS = (0, 1, 2)
MASTERED = 0.99  # the learner's skill at which every task of the space succeeds


def movement(name, episodes, seed, until_mastered=False, **extra) -> tuple[float, float, float]:
    """Mean proposed difficulty of the first and of the last fifth of a run, and the learner's
    skill gain. With `until_mastered` the last fifth ends where the learner masters the space:
    from there every return is the same, and a teacher that follows progress has none left to
    follow."""
    difficulties, skills, _ = run(name, episodes, seed=seed, **extra)
    window = episodes // 5
    end = len(skills)
    if until_mastered and skills[-1] >= MASTERED:
        end = int(np.argmax(skills >= MASTERED)) + 1
    assert end >= 2 * window, f"{name} seed {seed}: the space is mastered at episode {end}"
    early, late = difficulties[:window].mean(), difficulties[end - window : end].mean()
    return early, late, skills[-1] - skills[0]


def assert_moves(name, episodes, at_least, threshold=0.1, **extra) -> None:
    """The learner improves and the proposals get harder by `threshold` on `at_least` of SEEDS
    (seeds are played in order until that many have moved)."""
    results, moved = {}, 0
    for seed in SEEDS:
        early, late, gain = results[seed] = movement(name, episodes, seed, **extra)
        moved += gain > 0.2 and late > early + threshold
        if moved >= at_least:
            return
    report = ", ".join(
        f"seed {s}: {early:.2f} -> {late:.2f} (skill +{gain:.2f})"
        for s, (early, late, gain) in results.items()
    )
    raise AssertionError(f"{name} moved on {moved} of {len(SEEDS)} seeds: {report}")


@pytest.mark.parametrize(
    "name, episodes, at_least, extra",
    [
        ("oracle", 2000, 3, {}),
        ("adr", 2000, 3, {}),
        # stalls where no goal is of intermediate difficulty (3 of seeds 0-19; docs/teachers.md)
        ("goal-gan", 800, 2, {}),
        ("alp-gmm", 2000, 3, {}),
        # progress = Cov(time, return): flat once the space is mastered, so measured until then
        ("covar-gmm", 2000, 3, {"rate": 0.002, "until_mastered": True}),
        ("riac", 2000, 3, {}),
        ("terrain-levels", 2000, 3, {}),
    ],
)
def test_proposed_tasks_get_harder_as_the_learner_improves(name, episodes, at_least, extra):
    assert_moves(name, episodes, at_least, **extra)


@pytest.mark.parametrize("extra", [{}, {"rate": 0.002, "until_mastered": True}])
def test_random_fails_the_same_assertion_on_every_seed(extra):
    """The assertion above can fail: uniform proposals move on none of the seeds."""
    with pytest.raises(AssertionError, match="moved on 0 of"):
        assert_moves("random", 2000, at_least=1, **extra)


@pytest.mark.parametrize("name", ["oracle", "adr", "goal-gan"])
def test_the_first_tasks_are_on_the_environments_easy_side(name):
    difficulties, _, _ = run(name, 50)
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


def windows(values: np.ndarray, n: int = 5) -> np.ndarray:
    return values.reshape(n, -1).mean(axis=1)


def test_random_proposals_do_not_move_though_the_learner_improves():
    """The control: the same learner improves under Random, whose proposals stay uniform."""
    difficulties, skills, _ = run("random", 2000)
    early, late = windows(difficulties)[[0, -1]]
    assert skills[-1] > skills[0] + 0.2
    assert abs(late - early) < 0.05, f"random moved: {early:.2f} -> {late:.2f}"


@pytest.mark.parametrize(
    "name, extra",
    [("robust-plr", {}), ("accel", {}), ("accel", {"easy_task": [0.0, 6.0]})],
    ids=["robust-plr", "accel", "accel-from-easy-corner"],
)
def test_replayed_levels_get_harder_as_the_learner_improves(name, extra):
    """Half of PLR's proposals are new levels (exploratory: they do not train the learner), uniform
    or, for ACCEL given `easy_task`, that one easy level, which ACCEL edits its way up from; the
    replayed ones, which train the learner, follow its frontier. A slower learner keeps the
    frontier inside the space for the whole run."""
    difficulties, skills, exploratory = run(name, 2000, rate=0.002, **extra)
    replayed = ~exploratory
    window = np.arange(len(difficulties)) // 400
    early = difficulties[replayed & (window == 0)].mean()
    late = difficulties[replayed & (window == 4)].mean()
    assert skills[-1] > skills[0] + 0.2, f"{name}: the learner did not improve ({skills[-1]:.2f})"
    assert late > early + 0.1, f"{name}: replayed difficulty {early:.2f} -> {late:.2f}"


def test_self_paced_climbs_from_its_easy_start():
    """SPDL starts at its initial (easy) distribution, given at expert knowledge "high"; with
    "low" it starts at a random mean, which on a hard task leaves the learner nothing to learn.
    It climbs slowly on this learner (see docs/teachers.md)."""
    difficulties, skills, _ = run("self-paced", 2000, level="high")
    early, late = windows(difficulties)[[0, -1]]
    assert skills[-1] > skills[0] + 0.15, f"the learner did not improve ({skills[-1]:.2f})"
    assert late > early + 0.03, f"self-paced: proposed difficulty {early:.2f} -> {late:.2f}"


# Setter-Solver's defaults (TeachMyAgent's) take one Adam step at 3e-4 every 50 episodes: over
# the 2000 episodes of the tests above that is 40 small steps, the flow barely leaves its initial
# near-uniform cover, and the proposals do not move (difficulty 0.51 -> 0.48). Five times as many
# steps, each ten times larger, for the setter and the judge alike, move them within 1000.
FAST_SETTER = {"update_frequency": 10, "setter_lr": 3e-3, "judge_lr": 3e-3}


def test_setter_solver_proposals_get_harder_with_a_faster_setter():
    """With non-default update settings (FAST_SETTER): the defaults are sized for the tens of
    thousands of episodes of a real run and do not move within a unit test's episodes (see
    docs/teachers.md). The setter first narrows onto feasible (easier) goals, then follows the
    learner up: the proposals of the last 200 episodes are harder than those of the first 200 by
    0.26-0.40 on seeds 0-2. Over seeds 0-15 by more than 0.2 on 9 (six lag, +0.04 to +0.17;
    seed 6 collapses onto a corner, below), hence 2 of 3. About 5 s a seed."""
    assert_moves("setter-solver", 1000, at_least=2, threshold=0.2, **FAST_SETTER)


def test_setter_solver_without_early_successes_collapses_onto_a_corner():
    """What the paper's losses do when nothing succeeds (docs/teachers.md): on seed 6 one of the
    first 400 episodes succeeds, the judge learns that every goal fails, the feasibility term
    pulls the goals to the judge's highest (arbitrary) logit, a corner of the box (stumps of
    height 0 at spacing 0, difficulty 0.5, too hard for this learner), and the coverage term
    only holds them at a small spread there."""
    difficulties, skills, _ = run("setter-solver", 400, seed=6, **FAST_SETTER)
    late = difficulties[-100:]
    assert abs(late.mean() - 0.5) < 0.02 and late.std() < 0.02, (late.mean(), late.std())
    assert skills[-1] < skills[0] + 0.1


LESSONS = {
    "measure": "reward",
    "thresholds": [150.0, 150.0, 150.0],
    "min_lesson_length": 20,
    "parameters": {"stump_height": [0.0, 0.6, 1.2, 1.8], "obstacle_spacing": [6.0, 4.8, 3.6, 2.4]},
}


def test_lessons_advance_when_the_learner_passes_each_threshold():
    difficulties, skills, _ = run("lessons", 1500, curriculum=LESSONS)
    lessons = np.round(difficulties / 0.2).astype(int)  # lesson l sits at difficulty 0.2 l
    assert lessons[0] == 0 and lessons[-1] == 3, f"lessons {lessons[0]} -> {lessons[-1]}"
    assert np.all(np.diff(lessons) >= 0), "a lesson went back"
    assert skills[-1] > 0.6, f"the learner did not improve ({skills[-1]:.2f})"
