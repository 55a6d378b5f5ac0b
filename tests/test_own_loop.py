"""acl3d from a user's own loop: the curriculum wrapper, the batched vector env's task hook and
Gymnasium's vector wrappers on it, task spaces as Gymnasium Boxes."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from gymnasium.wrappers.vector import (
    ClipAction,
    NormalizeObservation,
    RecordEpisodeStatistics,
    TransformObservation,
)
from stable_baselines3.common.env_checker import check_env

import acl3d  # noqa: F401  (registers the ids)
from acl3d.envs.batched_vector import BatchedVectorEnv
from acl3d.envs.curriculum_wrapper import CurriculumWrapper
from acl3d.task_space import TaskSpace
from acl3d.teachers import Teacher, register
from acl3d.teachers import make as make_teacher
from acl3d.teachers.controller import TeacherController

SPACE = TaskSpace.from_bounds({"stump_height": [0.0, 3.0], "obstacle_spacing": [0.0, 6.0]})


class RecordingSync:
    """A curriculum sync that logs every episode and task, with tasks from a seeded generator."""

    def __init__(self, seed=0):
        self.rng = np.random.default_rng(seed)
        self.log: list[tuple] = []

    def sync(self, finished, env_ids):
        for k, index in enumerate(finished.env_ids):
            report = {"task": finished.tasks[k], "return": finished.returns[k]}
            self.log.append(("finished", int(index), report))
        tasks = self.rng.uniform(SPACE.low, SPACE.high, (len(env_ids), 2)).astype(np.float32)
        for index, task in zip(env_ids, tasks):
            self.log.append(("next", int(index), task))
        return tasks


def vector(n=3, limit=25, **kw) -> BatchedVectorEnv:
    return gym.make_vec(
        "acl3d/StumpTracks-v0",
        num_envs=n,
        vectorization_mode="vector_entry_point",
        max_episode_steps=limit,
        threads=1,
        **kw,
    )


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_curriculum_sync_hears_every_episode_once_before_choosing_again(mode):
    source = RecordingSync()
    vec = vector(autoreset_mode=mode, curriculum_sync=source)
    vec.reset(seed=0)
    rng = np.random.default_rng(1)
    returns = np.zeros(3)
    reported = 0
    for _ in range(90):
        obs, rewards, terminated, truncated, infos = vec.step(rng.uniform(-1, 1, (3, 4)))
        returns += rewards
        for i in np.flatnonzero(terminated | truncated):
            report = infos["curriculum"][i]
            assert report["return"] == pytest.approx(returns[i])
            returns[i] = 0.0
            reported += 1
    vec.close()
    # per sub-env: next, finished, next, finished, ... and each report names the task it played
    for i in range(3):
        calls = [(kind, payload) for kind, index, payload in source.log if index == i]
        kinds = [kind for kind, _ in calls]
        assert kinds[::2] == ["next"] * len(kinds[::2])
        assert kinds[1::2] == ["finished"] * len(kinds[1::2])
        for (_, task), (_, report) in zip(calls[::2], calls[1::2]):
            np.testing.assert_array_equal(report["task"], task)
    finished = sum(kind == "finished" for kind, _, _ in source.log)
    assert finished == reported >= 9


def test_teacher_on_the_vector_env_learns_from_each_episode():
    teacher = make_teacher("alp-gmm", SPACE.gym_space, seed=0)
    vec = vector(teacher=teacher)
    vec.reset(seed=0)
    ends = 0
    for _ in range(60):
        *_, terminated, truncated, _ = vec.step(np.zeros((3, 4)))
        ends += int((terminated | truncated).sum())
    assert ends >= 6 and teacher.nb_episodes == ends


def test_gymnasium_vector_wrappers_work_on_the_batched_env():
    def wrapped():
        vec = vector()
        inner = TransformObservation(vec, lambda o: 2.0 * o, vec.observation_space)
        return vec, RecordEpisodeStatistics(NormalizeObservation(ClipAction(inner)))

    vec, env = wrapped()
    raw = vector()
    obs, _ = env.reset(seed=3)
    raw_obs, _ = raw.reset(seed=3)
    rng = np.random.default_rng(0)
    returns, lengths, episodes = np.zeros(3), np.zeros(3, dtype=int), []
    for _ in range(70):
        actions = rng.uniform(-3, 3, (3, 4)).astype(
            np.float32
        )  # ClipAction: the env sees them clipped to [-1, 1]
        obs, rewards, terminated, truncated, infos = env.step(actions)
        raw_obs, raw_rewards, *_ = raw.step(np.clip(actions, -1, 1))
        np.testing.assert_array_equal(rewards, raw_rewards)
        assert obs.shape == raw_obs.shape and np.all(np.isfinite(obs))
        returns += rewards
        lengths += 1
        if "episode" in infos:
            for i in np.flatnonzero(infos["_episode"]):
                assert infos["episode"]["r"][i] == pytest.approx(returns[i])
                assert infos["episode"]["l"][i] == lengths[i] == infos["curriculum"][i]["length"]
                episodes.append(i)
        done = terminated | truncated
        returns[done], lengths[done] = 0.0, -1  # the next step resets (reward 0, not counted)
    assert len(episodes) >= 6
    normalizer = env.env  # NormalizeObservation saw the doubled observations
    assert normalizer.obs_rms.count > 70 * 3 and np.any(normalizer.obs_rms.var != 1.0)
    env.close()
    raw.close()


def test_curriculum_wrapper_plays_teacher_tasks_and_reports_them():
    teacher = make_teacher("random", SPACE, seed=0)
    env = CurriculumWrapper(gym.make("acl3d/StumpTracks-v0", max_episode_steps=20), teacher)
    check_env(env, warn=False)  # Stable-Baselines3's checks (Gymnasium's expect reset(seed) to
    # repeat an observation: each reset here plays the teacher's next task)
    reported = []
    teacher.episodic_update = lambda task, ret, success: reported.append((task, ret, success))
    env.reset(seed=0)
    played, total = env.unwrapped.task_vector, 0.0
    for _ in range(20):
        _, reward, terminated, truncated, info = env.step(env.action_space.sample())
        total += reward
    assert truncated and not terminated
    ((task, ret, success),) = reported
    np.testing.assert_array_equal(task, np.float32(played))
    report = info["curriculum"]
    assert ret == pytest.approx(total) == report["return"] and report["truncated"]
    assert report["length"] == 20 and success is False
    env.reset(options={"task": {"stump_height": 0.0}})  # an explicit task: not the teacher's
    for _ in range(20):
        env.step(env.action_space.sample())
    assert len(reported) == 1


def test_task_space_converts_to_and_from_a_gymnasium_box():
    box = SPACE.gym_space
    assert isinstance(box, gym.spaces.Box) and box.dtype == np.float32 and box.shape == (2,)
    np.testing.assert_array_equal(box.high, [3.0, 6.0])
    back = TaskSpace.from_gym(box, names=SPACE.names)
    assert back == SPACE
    teacher = make_teacher("adr", box, seed=0)
    assert teacher.task_space.names == ("x0", "x1") and box.contains(teacher.sample_task())


@pytest.mark.parametrize(
    "space, match",
    [
        (gym.spaces.Box(0, 1, (2, 2)), "1-d"),
        (gym.spaces.Box(-np.inf, 1, (2,)), "finite"),
        (gym.spaces.Discrete(3), "task_space"),
    ],
)
def test_bad_gymnasium_task_spaces_raise(space, match):
    with pytest.raises(ValueError, match=match):
        TaskSpace.coerce(space)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"autoreset_mode": "Disabled"}, "autoreset_mode"),
        ({"curriculum_sync": object()}, "curriculum_sync"),
        ({"teacher": object()}, "teacher"),
        (
            {"teacher": make_teacher("random", SPACE), "curriculum_sync": RecordingSync()},
            "exclusive",
        ),
    ],
)
def test_bad_vector_env_arguments_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        BatchedVectorEnv("stump-tracks", 2, **kwargs)


class HalfHeight(Teacher):
    """A user's teacher: uniform tasks, stump height capped at half its range once the mean
    return of the last 3 episodes is below 0."""

    name = "test-half-height"
    uses_initial_dist = False

    def __init__(self, task_space, seed=None, window: int = 3):
        super().__init__(task_space, seed)
        self.window, self.returns = window, []

    def _sample(self):
        task = self.uniform_task()
        if len(self.returns) >= self.window and np.mean(self.returns[-self.window :]) < 0:
            task[0] = self.mins[0] + 0.5 * (task[0] - self.mins[0])
        return task

    def _episodic_update(self, task, reward, is_success):
        self.returns.append(reward)

    def _extra_state(self):
        return {"returns": list(self.returns)}

    def _load_extra_state(self, extra):
        self.returns = [float(r) for r in extra["returns"]]


@pytest.fixture
def registry(monkeypatch):
    """Registrations made by a test are undone after it."""
    import acl3d.teachers as teachers

    monkeypatch.setattr(teachers, "_REGISTRY", dict(teachers._REGISTRY))


def test_a_users_teacher_is_one_class_and_one_registration(registry):
    register(HalfHeight)
    register(HalfHeight)  # idempotent for the same class
    controller = TeacherController("test-half-height", SPACE, seed=0, expert_knowledge="high")
    task = controller.sample_task()
    controller.record_episode(task, -5.0, 10, False)
    assert controller.teacher.returns == [-5.0] and not controller.marks_exploratory
    assert make_teacher("test-half-height", SPACE, seed=0, window=2).window == 2
    by_path = make_teacher("acl3d.teachers.random_teacher:RandomTeacher", SPACE, seed=0)
    assert by_path.name == "random"


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: register(type("Dup", (HalfHeight,), {})), "already registered"),
        (lambda: register(dict), "subclass of Teacher"),
        (lambda: make_teacher("nope:Nothing", SPACE), "cannot import"),
        (lambda: make_teacher("acl3d.task_space:TaskSpace", SPACE), "not a subclass"),
        (lambda: make_teacher("random", SPACE).step_update(0, 0, np.nan, 0, True), "reward"),
        (lambda: make_teacher("random", SPACE).step_update(0, 0, 1.0, 0, True, -1), "stream"),
    ],
)
def test_bad_teacher_registrations_and_calls_raise(registry, call, match):
    register(HalfHeight)
    with pytest.raises(ValueError, match=match):
        call()


def test_only_teachers_that_declare_it_mark_exploratory_levels():
    for name, marks in [("random", False), ("alp-gmm", False), ("robust-plr", True)]:
        teacher = make_teacher(name, SPACE, seed=0)
        assert teacher.marks_exploratory is marks
        assert teacher.is_exploratory(teacher.sample_task()) is marks  # PLR: a new level
