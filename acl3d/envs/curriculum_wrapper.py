"""A teacher driving acl3d envs from your own training loop.

* `CurriculumWrapper(env, teacher)`: a Gymnasium wrapper for one env. Each `reset()` without a
  task in its options plays `teacher.sample_task()`; each finished episode is reported with
  `teacher.episodic_update(task, return, success)` before the wrapper returns its last step, and
  described in `info["curriculum"]` (see `episode_report`). The episode is summed by the one
  episode-statistics layer (`acl3d.envs.episode_statistics`), as in every vec env.
* `TaskQueue` / `CurriculumWorker`: a training worker's side of the curriculum (queued tasks,
  the episode report), shared by the SB3 workers.

A teacher is any acl3d teacher, or any object with `sample_task()` and
`episodic_update(task, reward, is_success)` (a vector of worlds drives a teacher through
`acl3d.envs.episode_statistics.TeacherSync`, which needs the batched calls). A task passed in `reset(options={"task": ...})`
(evaluation, a replay) is played without asking or telling the teacher.
"""

from __future__ import annotations

import time
from collections import deque

import gymnasium as gym
import numpy as np

from acl3d import validation
from acl3d.envs.episode_statistics import EpisodeStatistics, check_methods

INFO_KEY = "curriculum"


def episode_report(
    task, episode_return: float, length: int, success: bool, truncated: bool, initial_obs
) -> dict:
    """The record of one finished episode, as found in `info["curriculum"]`: the task it played
    (float32 vector), its return, length, success, whether the time limit cut it, and its first
    observation (for teachers that score initial states)."""
    return {
        "task": np.array(task, dtype=np.float32),  # a copy: the caller may reuse its array
        "return": float(episode_return),
        "length": int(length),
        "success": bool(success),
        "truncated": bool(truncated),
        "initial_obs": initial_obs,
    }


class CurriculumWrapper(gym.Wrapper):
    """One env whose tasks come from `teacher` (see the module docstring)."""

    def __init__(self, env: gym.Env, teacher):
        super().__init__(env)
        check_methods("teacher", teacher, ("sample_task", "episodic_update"))
        self.teacher = teacher
        self.stats: EpisodeStatistics | None = None  # sized at the first reset (the task's length)
        self._from_teacher = False

    def reset(self, *, seed=None, options=None):
        if options is not None and not isinstance(options, dict):
            raise validation.fail("options", options, "None or a dict")
        options = dict(options or {})
        from_teacher = "task" not in options
        if from_teacher:
            options["task"] = np.asarray(self.teacher.sample_task(), dtype=np.float32)
        obs, info = self.env.reset(seed=seed, options=options)
        task = played_task(self.env, options["task"])
        if self.stats is None or self.stats.task_dim != len(task):
            self.stats = EpisodeStatistics(1, len(task))
        self.stats.begin(np.zeros(1, np.int64), task[None], np.asarray(obs)[None])
        self._from_teacher = from_teacher
        return obs, info

    def step(self, action):
        if self.stats is None:
            raise RuntimeError("CurriculumWrapper.step() before reset()")
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.stats.step(
            np.array([reward], np.float64), np.array([terminated]), np.array([truncated]),
            np.array([info.get("success", False)]),
        )  # fmt: skip
        if terminated or truncated:
            ep = self.stats.pop()
            info[INFO_KEY] = report = episode_report(
                ep.tasks[0], ep.returns[0], ep.lengths[0], ep.successes[0], ep.truncated[0],
                ep.initial_obs[0].reshape(np.shape(obs)),
            )  # fmt: skip
            if self._from_teacher:
                self.teacher.episodic_update(report["task"], report["return"], report["success"])
        return obs, reward, terminated, truncated, info


def played_task(env: gym.Env, task) -> np.ndarray:
    """The task vector an episode played: `task` as given in the reset options, or, for a
    named task ({name: value}), the vector the env built from it."""
    if isinstance(task, dict):
        return env.unwrapped.task_vector
    return np.asarray(task, dtype=np.float32)


class TaskQueue:
    """One curriculum worker's side of the protocol: the tasks queued for it and its running
    episode, reported when the episode ends.

    Shared by a single env behind `acl3d.training.curriculum.CurriculumEnv` and by each sub-env
    of the batched SB3 vec env. A reset that names no task plays the queue's head; the episode
    report (`episode_report`, in `info["curriculum"]`, plus SB3's `info["episode"]`) takes its
    success from the env's info, else from the return against the curriculum profile.
    """

    def __init__(self, success_return: float):
        self.success_return = success_return
        self.tasks: deque[np.ndarray] = deque()
        self.task: np.ndarray | None = None  # of the running episode
        self.initial_obs = None
        self._start_time = 0.0

    def push(self, task) -> int:
        """Queue a task (flat vector in task-space order); returns the queue length."""
        self.tasks.append(np.array(task, dtype=np.float32).reshape(-1))
        return len(self.tasks)

    def options(self, options) -> dict:
        """Reset options naming a task: the given one, else the queue's head (RuntimeError if
        the queue is empty)."""
        options = dict(options or {})
        if "task" not in options:
            if not self.tasks:
                raise RuntimeError(
                    "no task queued: push_task() before every reset that does not pass "
                    "options={'task': ...}"
                )
            options["task"] = self.tasks.popleft()
        return options

    def begin(self, task, obs) -> None:
        """An episode started on `task` with first observation `obs`."""
        self.task = task
        self.initial_obs = np.array(obs, copy=True)
        self._start_time = time.perf_counter()

    def report(self, info: dict, episode_return: float, length: int, terminated, truncated):
        """Describe the episode that just ended in its last step's `info`."""
        success = info.get("success", episode_return > self.success_return)
        info[INFO_KEY] = episode_report(
            self.task,
            episode_return,
            length,
            success,
            bool(truncated and not terminated),
            self.initial_obs,
        )
        # SB3 reads this key (as Monitor writes it) for rollout/ep_rew_mean
        elapsed = round(time.perf_counter() - self._start_time, 6)
        info["episode"] = {"r": float(episode_return), "l": int(length), "t": elapsed}

    def get_state(self, episode_return: float, length: int, last_obs, env_state, size: int):
        """The worker's checkpoint layout (the same for every kind of worker, so a run may
        resume on another vec env kind); `size` is the task vector's length."""
        return {
            "queue": np.array(list(self.tasks), dtype=np.float32).reshape(len(self.tasks), size),
            "task": None if self.task is None else np.asarray(self.task, dtype=np.float32),
            "return": float(episode_return),
            "length": int(length),
            "initial_obs": self.initial_obs,
            "last_obs": last_obs,
            "env": env_state,
        }

    def set_state(self, state: dict) -> None:
        """The queue and running episode of a `get_state()` (the caller restores the rest)."""
        self.tasks = deque(np.asarray(t, dtype=np.float32) for t in state["queue"])
        self.task = None if state["task"] is None else np.asarray(state["task"], np.float32)
        self.initial_obs = state["initial_obs"]


class CurriculumWorker:
    """The methods a main-side curriculum calls on each worker (through SB3's `env_method`);
    the worker keeps its protocol state in `self.queue` (a `TaskQueue`)."""

    queue: TaskQueue

    def push_task(self, task) -> int:
        """Queue a task (flat vector in task-space order); returns the queue length."""
        return self.queue.push(task)

    def queued_tasks(self) -> int:
        return len(self.queue.tasks)

    def clear_tasks(self) -> None:
        """Drop queued tasks (an evaluation env starting a new test pass)."""
        self.queue.tasks.clear()

    def success_return(self) -> float:
        """The return above which an episode masters its task (the env's curriculum profile)."""
        return self.queue.success_return
