"""Curriculum sync: every episode plays a teacher task, every outcome reaches the teacher once."""

from __future__ import annotations

import functools

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.wrappers import TimeLimit
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

from acl3d.curriculum_profile import CurriculumProfile
from acl3d.task_space import TaskSpace
from acl3d.training.curriculum import CurriculumEnv, CurriculumVecEnv, WorkerError

MAX_STEPS = 9


def episode_length(task) -> int:
    """Deterministic length of the stand-in env's episode; > MAX_STEPS means truncated."""
    return 1 + (int(round(float(task[0]))) * 7) % 13


class CountingEnv(gym.Env):
    """Stand-in track: the task fixes the episode length and the per-step reward (task[1])."""

    observation_space = gym.spaces.Box(-np.inf, np.inf, (3,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    # what a curriculum reads of an env (acl3d.envs.task_env.TaskEnv), as a track has it
    task_space = TaskSpace.from_bounds({"length": [0.0, 1000.0], "reward": [-1.0, 1.0]})
    curriculum_profile = CurriculumProfile()

    def __init__(self, crash_at_task: int | None = None):
        self.crash_at_task = crash_at_task
        self.task = np.zeros(2)
        self.t = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.task = np.asarray(options["task"], dtype=np.float64)
        if self.crash_at_task is not None and round(self.task[0]) == self.crash_at_task:
            raise FloatingPointError("stand-in env exploded on purpose")
        self.t = 0
        return self._obs(), {}

    def set_task(self, task) -> None:
        self.task = np.asarray(task, dtype=np.float64)

    @property
    def task_vector(self) -> np.ndarray:
        return self.task.astype(np.float32)

    def _obs(self):
        return np.array([self.task[0], self.task[1], self.t], dtype=np.float32)

    def step(self, action):
        self.t += 1
        terminated = self.t >= episode_length(self.task)
        return self._obs(), float(self.task[1]), terminated, False, {"success": self.t % 2 == 0}


def make_counting_env(crash_at_task=None):
    return CurriculumEnv(TimeLimit(CountingEnv(crash_at_task), max_episode_steps=MAX_STEPS))


class RecordingController:
    """Stand-in TeacherController: numbered tasks, remembers what it sampled and was told."""

    def __init__(self, needs=()):
        self.needs = frozenset(needs)
        self.sampled: list[np.ndarray] = []
        self.recorded: list[tuple] = []
        self.steps = 0
        self.rng = np.random.default_rng(0)

    def sample_task(self):
        task = np.array([len(self.sampled), self.rng.uniform(-1, 1)], dtype=np.float32)
        self.sampled.append(task)
        return task

    def sample_training_tasks(self, n):
        tasks = np.array([self.sample_task() for _ in range(n)], np.float32).reshape(n, 2)
        return tasks, np.zeros(n, bool)

    def record_episodes(self, finished):
        for k in range(len(finished)):
            self.recorded.append(
                (
                    np.asarray(finished.tasks[k]),
                    float(finished.returns[k]),
                    int(finished.lengths[k]),
                    bool(finished.successes[k]),
                    None if finished.initial_obs is None else finished.initial_obs[k],
                )
            )

    def record_steps(self, states, actions, rewards, next_states, dones, workers=None):
        self.steps += len(rewards)

    def maybe_sample_periodically(self, total_steps):
        return None


def run_random_steps(venv, n_steps: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    venv.reset()
    infos_seen = []
    for _ in range(n_steps):
        _, _, dones, infos = venv.step(rng.uniform(-1, 1, (venv.num_envs, 1)).astype(np.float32))
        infos_seen.append((dones, infos))
    return infos_seen


def vec_env(kind: str, n_envs: int, crash_at_task=None):
    fns = [functools.partial(make_counting_env, crash_at_task) for _ in range(n_envs)]
    if kind == "dummy":
        return DummyVecEnv(fns)
    return SubprocVecEnv(fns, start_method=kind)


@pytest.mark.parametrize(
    "kind", ["dummy", "forkserver", pytest.param("spawn", marks=pytest.mark.slow)]
)
def test_every_episode_plays_a_sampled_task_and_reports_once(kind):
    n_envs, n_steps = 3, 60
    controller = RecordingController(needs={"step_rewards"})
    venv = CurriculumVecEnv(vec_env(kind, n_envs), controller)
    try:
        history = run_random_steps(venv, n_steps)
    finally:
        venv.close()
    finished = sum(int(d.sum()) for d, _ in history)
    assert finished == len(controller.recorded) == venv.episodes_done > 0
    # Each worker holds one running and one prefetched task: nothing lost, nothing extra.
    assert len(controller.sampled) == finished + 2 * n_envs
    played_ids = [int(round(r[0][0])) for r in controller.recorded]
    assert len(set(played_ids)) == len(played_ids), "an episode was reported twice"
    assert set(played_ids) <= set(range(len(controller.sampled)))
    truncated = 0
    for task, ret, length, success, initial_obs in controller.recorded:
        sampled = controller.sampled[int(round(task[0]))]
        np.testing.assert_array_equal(task, sampled)  # the task the env played, unchanged
        expected_len = min(episode_length(task), MAX_STEPS)
        truncated += episode_length(task) > MAX_STEPS
        assert length == expected_len
        assert success == (expected_len % 2 == 0)  # the env's own flag at the last step
        assert ret == pytest.approx(float(task[1]) * expected_len, rel=1e-5)
        np.testing.assert_allclose(initial_obs, [task[0], task[1], 0.0], rtol=1e-6)
    assert truncated > 0, "the run must include time-limit truncations"
    assert controller.steps == n_steps * n_envs


def test_each_worker_plays_its_own_tasks_in_order():
    """Per worker, the reported tasks are the ones pushed to it, in push order."""
    controller = RecordingController()
    venv = CurriculumVecEnv(vec_env("dummy", 2), controller)
    pushed: dict[int, list[int]] = {0: [], 1: []}
    original_push = venv._push

    def spy(ids, finished):
        original_push(ids, finished)
        first = len(controller.sampled) - len(ids)
        for k, index in enumerate(ids):
            pushed[int(index)].append(first + k)

    venv._push = spy
    history = run_random_steps(venv, 40)
    per_worker: dict[int, list[int]] = {0: [], 1: []}
    for dones, infos in history:
        for i in np.flatnonzero(dones):
            per_worker[int(i)].append(int(round(infos[i]["curriculum"]["task"][0])))
    for worker in (0, 1):
        assert per_worker[worker] == pushed[worker][: len(per_worker[worker])]
        assert len(pushed[worker]) == len(per_worker[worker]) + 2


def test_reset_without_queued_task_fails_loudly():
    env = make_counting_env()
    obs, info = env.reset(options={"task": [1.0, 0.5]})  # explicit tasks bypass the queue
    assert obs[0] == 1.0
    with pytest.raises(WorkerError, match="no task queued"):
        from acl3d.training.curriculum import raise_worker_errors

        raise_worker_errors([env.reset()[1]], "reset")


@pytest.mark.parametrize("kind", ["dummy", "forkserver"])
def test_crashing_worker_stops_with_its_traceback(kind):
    controller = RecordingController()
    venv = CurriculumVecEnv(vec_env(kind, 2, crash_at_task=5), controller)
    try:
        with pytest.raises(WorkerError, match="(?s)worker .* crashed.*FloatingPointError"):
            run_random_steps(venv, 100)
    finally:
        venv.close()


@pytest.mark.parametrize("kind", ["dummy", "forkserver"])
def test_evaluation_spreads_test_tasks_over_workers_and_pairs_results(kind):
    from acl3d.training.evaluation import evaluate

    tasks = np.array([[k, 0.1 * k - 0.3] for k in range(7)], dtype=np.float32)
    venv = vec_env(kind, 3)
    try:
        result = evaluate(lambda obs: np.zeros((len(obs), 1)), venv, tasks, episodes_per_task=2)
        again = evaluate(
            lambda obs: np.zeros((len(obs), 1)), venv, tasks[:2]
        )  # stale queue ignored
    finally:
        venv.close()
    np.testing.assert_array_equal(result.tasks, np.repeat(tasks, 2, axis=0))
    lengths = np.array([min(episode_length(t), MAX_STEPS) for t in result.tasks])
    np.testing.assert_array_equal(result.lengths, lengths)
    np.testing.assert_allclose(result.returns, result.tasks[:, 1] * lengths, rtol=1e-5)
    assert result.mastered_pct == 0.0
    np.testing.assert_array_equal(again.tasks, tasks[:2])


class StumpController(RecordingController):
    """Numbered Stump Tracks tasks (the number in stump_height); logs sample/record order."""

    def __init__(self, needs=()):
        super().__init__(needs)
        self.most_ahead = 0  # max over time of (sampled - recorded)

    def sample_task(self):
        task = np.array([len(self.sampled) * 1e-3, self.rng.uniform(0, 6)], dtype=np.float32)
        self.sampled.append(task)
        self.most_ahead = max(self.most_ahead, len(self.sampled) - len(self.recorded))
        return task


def check_batched_counts(venv, controller, n_steps: int, tasks_ahead: int) -> int:
    """Every finished episode reported once with the task it played; none lost."""
    cvenv, rng = CurriculumVecEnv(venv, controller), np.random.default_rng(0)
    cvenv.reset()
    history = []
    for _ in range(n_steps):
        _, _, dones, infos = cvenv.step(rng.uniform(-1, 1, (venv.num_envs, 4)))
        history.append((dones, infos))
    finished = sum(int(d.sum()) for d, _ in history)
    assert finished == len(controller.recorded) > 0
    assert len(controller.sampled) == finished + tasks_ahead
    ids = [int(round(r[0][0] * 1e3)) for r in controller.recorded]
    assert len(set(ids)) == len(ids), "an episode was reported twice"
    for (task, _, length, _, _), k in zip(controller.recorded, ids):
        np.testing.assert_array_equal(task, controller.sampled[k])
        assert 1 <= length
    return sum(info.get("TimeLimit.truncated", False) for d, infos in history for info in infos)


def test_batched_sub_envs_pull_tasks_at_their_own_reset():
    from acl3d.vec.batched_sb3 import BatchedVecEnv

    n = 3
    controller = StumpController()
    venv = BatchedVecEnv("stump-tracks", n, curriculum=True, max_episode_steps=12)
    try:
        truncated = check_batched_counts(venv, controller, 50, tasks_ahead=n)
    finally:
        venv.close()
    assert truncated > 0
    # pulled at reset: never more than one task per sub-env handed out ahead of the reports
    assert controller.most_ahead == n


def test_a_teacher_of_steps_gets_every_step_before_the_episode_it_ends():
    """On the batched env too, a "step_rewards" teacher is fed through the worker queues, so
    each episode's last step is recorded before the episode."""
    from acl3d.vec.batched_sb3 import BatchedVecEnv

    n = 3
    controller = StumpController(needs={"step_rewards"})
    order = []
    controller.record_steps = lambda *a, **k: order.extend(["step"] * len(a[2])) or None
    record_episodes = controller.record_episodes
    controller.record_episodes = lambda f: order.append("episodes") or record_episodes(f)
    venv = BatchedVecEnv("stump-tracks", n, curriculum=True, max_episode_steps=12)
    try:
        check_batched_counts(venv, controller, 50, tasks_ahead=2 * n)  # running + prefetched
    finally:
        venv.close()
    assert order.count("step") == 50 * n
    ends = [k for k, what in enumerate(order) if what == "episodes"]
    assert ends and all(order[k - 1] == "step" for k in ends)


def test_batched_workers_keep_every_sub_env_queue_exact():
    from acl3d.training.workers import make_vec_env

    controller = StumpController()
    venv = make_vec_env("stump-tracks", None, 4, vec_env="batched", envs_per_worker=2)
    try:
        assert type(venv).__name__ == "BatchedSubprocVecEnv" and venv.num_envs == 4
        check_batched_counts(venv, controller, 120, tasks_ahead=2 * 4)  # running + prefetched
    finally:
        venv.close()
