"""Curriculum sync between a teacher in the main process and environments in worker processes.

SB3 vector envs reset finished episodes inside `step()` with no options, so a task pushed after
the fact would arrive one episode late. Two ways keep the teacher ahead, both through the one
verb of `acl3d.envs.episode_statistics.CurriculumSync` (`CurriculumVecEnv.sync`: learn from the
finished episodes, return the next tasks), so data flow one way: teacher -> tasks -> worlds ->
episode results -> teacher.

* In-process batched env (`acl3d.vec.batched_sb3.BatchedVecEnv`): it sums episodes with its
  `EpisodeStatistics` and calls `sync` during the step that ends them, before the sub-envs
  reset, so the teacher knows an episode's outcome before it samples that sub-env's next task.
* Worker processes (`CurriculumEnv` in each): each worker plays the task at the head of its
  queue at every reset that names none, sums its episode with an `EpisodeStatistics` of one and
  reports it (task played, return, length, success, initial observation, truncation) in the
  last step's `info["curriculum"]`; the main side hands the step's reports to `sync` and pushes
  the tasks it returns, one ahead, before the next `step_async`. With one task of prefetch the
  teacher learns episode k of a worker before it samples that worker's task k + 2. A teacher
  that learns from every step ("step_rewards": SPDL) is driven this way on any vec env, so
  its step records precede the episode they end.

Errors raised inside a worker env are caught and carried back with their traceback, so a crash
stops training with a readable message on both vec env types. Exploratory levels (Robust PLR /
ACCEL's new or edited ones, on which the student must not learn) are flagged when their task is
sampled; the flag follows the task and `step_exploratory` tells, for each stepped transition,
whether its episode is exploratory.
"""

from __future__ import annotations

import traceback
from collections import deque
from dataclasses import replace
from typing import Protocol

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import SubprocVecEnv, VecEnv, VecEnvWrapper

from acl3d.envs.curriculum_wrapper import INFO_KEY, CurriculumWorker, TaskQueue, played_task
from acl3d.envs.env_state import restore_wrappers
from acl3d.envs.episode_statistics import EpisodeBatch, EpisodeStatistics
from acl3d.envs.task_env import SnapshotEnv, task_env
from acl3d.vec.batched_sb3 import BatchedVecEnv

ERROR_KEY = "acl3d_worker_error"


class WorkerError(RuntimeError):
    """An environment raised inside a worker; the message carries the worker's traceback."""


class Controller(Protocol):
    """What `CurriculumVecEnv` needs of the curriculum (`TeacherController` has it)."""

    needs: frozenset[str]

    def sample_training_tasks(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(n, d) float32 tasks and their (n,) exploratory flags."""

    def record_episodes(self, finished: EpisodeBatch) -> None: ...

    def record_step(self, state, action, reward, next_state, done, worker: int = 0) -> None: ...

    def maybe_sample_periodically(self, total_steps: int): ...


class CurriculumEnv(gym.Wrapper, CurriculumWorker):
    """Worker-side wrapper: pulls queued tasks at reset, reports episode outcomes in `info`.

    A reset whose `options` already hold a `"task"` (evaluation, rendering) plays that task and
    leaves the queue alone; any other reset needs a queued task and fails loudly without one, so a
    curriculum can never silently run an environment's default task. The queue and the episode
    report are the protocol every worker shares (`acl3d.envs.curriculum_wrapper.TaskQueue`).
    """

    def __init__(self, env: gym.Env):
        super().__init__(env)
        inner = task_env(env)  # a ValueError naming an env no curriculum can drive
        self.queue = TaskQueue(inner.curriculum_profile.success_return)
        # its snapshots continue a checkpoint's running episode exactly
        self._snapshots = inner if isinstance(inner, SnapshotEnv) else None
        self.stats: EpisodeStatistics | None = None  # sized at the first reset (task length)
        self._last_obs = None
        self._error: str | None = None

    def reset(self, *, seed=None, options=None):
        if self._error is not None:  # stay inert after a crash: the main side stops the run
            return self._placeholder_obs(), {ERROR_KEY: self._error}
        try:
            options = self.queue.options(options)
            obs, info = self.env.reset(seed=seed, options=options)
        except Exception:
            self._error = traceback.format_exc()
            return self._placeholder_obs(), {ERROR_KEY: self._error}
        task = played_task(self.env, options["task"])
        self.queue.begin(task, obs)
        self._begin(task, 0.0, 0)
        self._last_obs = self.queue.initial_obs
        return obs, info

    def step(self, action):
        if self._error is not None:
            return self._placeholder_obs(), 0.0, True, False, {ERROR_KEY: self._error}
        try:
            obs, reward, terminated, truncated, info = self.env.step(action)
        except Exception:
            self._error = traceback.format_exc()
            return self._placeholder_obs(), 0.0, True, False, {ERROR_KEY: self._error}
        self._last_obs = obs
        self.stats.step(
            np.array([reward], np.float64), np.array([terminated]), np.array([truncated])
        )
        if terminated or truncated:
            ep = self.stats.pop()
            self.queue.report(info, float(ep.returns[0]), int(ep.lengths[0]), terminated, truncated)
        return obs, reward, terminated, truncated, info

    def _begin(self, task, episode_return: float, length: int) -> None:
        """The running episode: on `task`, with this return and length so far."""
        task = np.asarray(task, dtype=np.float32).reshape(1, -1)
        if self.stats is None or self.stats.task_dim != task.shape[1]:
            self.stats = EpisodeStatistics(1, task.shape[1])
        self.stats.begin(np.zeros(1, np.int64), task)
        self.stats.returns[0], self.stats.lengths[0] = episode_return, length

    def get_state(self) -> dict:
        """Queue, running episode and the env's own `get_state()`: what a checkpoint needs to
        continue this worker's episode exactly (the same layout as a batched sub-env's, so a run
        may resume on another vec env kind). JSON scalars and numpy arrays; `"env"` is None for
        an env that is no `SnapshotEnv` (its episode then cannot be continued)."""
        size = len(self.queue.tasks[0]) if self.queue.tasks else 0
        running = self.stats is not None
        return self.queue.get_state(
            float(self.stats.returns[0]) if running else 0.0,
            int(self.stats.lengths[0]) if running else 0,
            self._last_obs,
            None if self._snapshots is None else self._snapshots.get_state(),
            size,
        )

    def set_state(self, state: dict) -> None:
        """Inverse of `get_state()` (on a worker built with the same arguments)."""
        if state["env"] is not None:
            self.env.unwrapped.set_state(state["env"])
            restore_wrappers(self.env, int(state["length"]))
        self.queue.set_state(state)
        if state["task"] is not None:
            self._begin(state["task"], float(state["return"]), int(state["length"]))
        self._last_obs = state["last_obs"]
        self._error = None

    def _placeholder_obs(self):
        if self._last_obs is not None:
            return self._last_obs
        return np.zeros(self.observation_space.shape, dtype=self.observation_space.dtype)


def raise_worker_errors(infos, where: str) -> None:
    for i, info in enumerate(infos):
        if info and ERROR_KEY in info:
            raise WorkerError(f"environment worker {i} crashed during {where}:\n{info[ERROR_KEY]}")


class CurriculumVecEnv(VecEnvWrapper):
    """Main-side wrapper: the run's `CurriculumSync`, keeping every worker one task ahead.

    `controller` is a `Controller` (`acl3d.teachers.controller.TeacherController`). It must sit
    directly on the worker `VecEnv` (below any VecNormalize) so that it sees raw observations
    and rewards. On an in-process `BatchedVecEnv` (and a teacher without "step_rewards") the
    batched env calls `sync` itself and nothing is queued; otherwise tasks are pushed to the
    workers' queues (module docstring).
    """

    def __init__(self, venv: VecEnv, controller: Controller, total_steps: int = 0):
        super().__init__(venv)
        self.controller = controller
        self.total_steps = int(total_steps)
        self.episodes_done = 0
        self._pending = np.zeros(self.num_envs, dtype=np.int64)
        # exploratory flags: of each env's running episode, of its queued tasks, of the last step
        self._running_exploratory = np.zeros(self.num_envs, dtype=bool)
        self._queued_exploratory: list[deque[bool]] = [deque() for _ in range(self.num_envs)]
        self._step_exploratory = np.zeros(self.num_envs, dtype=bool)
        self._finished: list[EpisodeBatch] = []
        self._last_obs = None
        self._actions = None
        self._record_steps = "step_rewards" in controller.needs
        self._pull = isinstance(venv, BatchedVecEnv) and not self._record_steps
        if self._pull:
            venv.curriculum_sync = self

    # -------------------------------------------------------------- the one curriculum verb
    def sync(self, finished: EpisodeBatch, env_ids) -> np.ndarray:
        """`CurriculumSync`: the teacher learns `finished`, then samples one task per env of
        `env_ids` (in one call each); pulling envs start them now (their exploratory flags)."""
        tasks, exploratory = self._sync(finished, len(env_ids))
        self._running_exploratory[np.asarray(env_ids, dtype=np.int64)] = exploratory
        return tasks

    def _sync(self, finished: EpisodeBatch, n: int) -> tuple[np.ndarray, np.ndarray]:
        if len(finished):
            finished = replace(
                finished.numpy(), total_steps=np.full(len(finished), self.total_steps)
            )
            self.controller.record_episodes(finished)
            self.episodes_done += len(finished)
            self._finished.append(finished)
        return self.controller.sample_training_tasks(n)

    @property
    def step_exploratory(self) -> np.ndarray:
        """Read-only (n_envs,) bools: whether each env's transition of the latest step belongs to
        an exploratory episode (flags taken at `step_async`, before any auto-reset)."""
        flags = self._step_exploratory.copy()
        flags.flags.writeable = False
        return flags

    # -------------------------------------------------------------- queue management
    def _push(self, ids, finished: EpisodeBatch) -> None:
        """Learn `finished`, then queue one new task on each worker of `ids`."""
        tasks, exploratory = self._sync(finished, len(ids))
        for i, task, flag in zip(ids, tasks, exploratory):
            self.venv.env_method("push_task", task, indices=[int(i)])
            self._queued_exploratory[int(i)].append(bool(flag))
            self._pending[int(i)] += 1

    def _start_queued(self, index: int) -> None:
        """Worker `index` began an episode on the head of its queue."""
        self._pending[index] -= 1
        self._running_exploratory[index] = self._queued_exploratory[index].popleft()

    def reset(self):
        if self._pull:
            self._last_obs = self.venv.reset()
            return self._last_obs
        empty = EpisodeBatch.empty(0)
        self._push(np.flatnonzero(self._pending == 0), empty)
        obs = self.venv.reset()
        raise_worker_errors(self.venv.reset_infos, "reset")
        for i in range(self.num_envs):
            self._start_queued(i)  # every worker consumed one queued task
        self._push(np.arange(self.num_envs), empty)
        self._last_obs = obs
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions
        self._step_exploratory = self._running_exploratory.copy()
        self.total_steps += self.num_envs  # this step's episodes end at this count
        self.venv.step_async(actions)

    def step_wait(self):
        try:
            obs, rewards, dones, infos = self.venv.step_wait()
        except (EOFError, ConnectionError) as exc:  # a worker process died without a traceback
            # SB3's workers (the batched env's workers report their own deaths: WorkerCrash)
            processes = self.venv.processes if isinstance(self.venv, SubprocVecEnv) else []
            codes = [p.exitcode for p in processes]
            raise WorkerError(f"an environment worker process died (exit codes {codes})") from exc
        if not self._pull:
            raise_worker_errors(infos, "step")
            self._record_step(obs, rewards, dones, infos)
            ended = np.flatnonzero(dones)
            for i in ended:
                self._start_queued(int(i))  # the auto-reset consumed the prefetched task
            self._push(ended, _reported(ended, infos))
        self.controller.maybe_sample_periodically(self.total_steps)
        self._last_obs = obs
        return obs, rewards, dones, infos

    def _record_step(self, obs, rewards, dones, infos) -> None:
        """Every env's step to a teacher that learns from steps (before the episodes end)."""
        if not self._record_steps:
            return
        next_obs = obs.copy()
        for i in np.flatnonzero(dones):
            next_obs[i] = infos[i]["terminal_observation"]
        self.controller.record_steps(self._last_obs, self._actions, rewards, next_obs, dones)

    def get_state(self) -> dict:
        """Counters, prefetch book-keeping and every worker's `get_state()` (for checkpoints;
        episodes not yet popped with `pop_finished` are not part of it)."""
        return {
            "total_steps": self.total_steps,
            "episodes_done": self.episodes_done,
            "pending": self._pending.copy(),
            "running_exploratory": self._running_exploratory.copy(),
            "queued_exploratory": [np.array(q, dtype=bool) for q in self._queued_exploratory],
            "last_obs": self._last_obs,
            "workers": self.venv.env_method("get_state"),
        }

    def set_state(self, state: dict) -> None:
        """Inverse of `get_state()` on a vec env with the same number of workers."""
        workers = state["workers"]
        if len(workers) != self.num_envs:
            raise ValueError(
                f"state holds {len(workers)} workers; this vec env has {self.num_envs}"
            )
        for i, worker in enumerate(workers):
            self.venv.env_method("set_state", worker, indices=[i])
        self.total_steps = int(state["total_steps"])
        self.episodes_done = int(state["episodes_done"])
        self._pending = np.asarray(state["pending"], dtype=np.int64).copy()
        self._running_exploratory = np.asarray(state["running_exploratory"], dtype=bool).copy()
        self._queued_exploratory = [deque(bool(f) for f in q) for q in state["queued_exploratory"]]
        self._last_obs = state["last_obs"]
        self._finished = []

    def pop_finished(self) -> EpisodeBatch | None:
        """Episodes finished since the last call (for logging), oldest first, as one numpy
        `EpisodeBatch` (`env_ids`: the workers; `total_steps`: the run's steps at the end of
        each); None if there were none."""
        batches, self._finished = self._finished, []
        if not batches:
            return None
        return EpisodeBatch(
            *(np.concatenate([getattr(b, f) for b in batches]) for f in _LOGGED),
            initial_obs=None,
        )


_LOGGED = ("env_ids", "tasks", "returns", "lengths", "successes", "truncated", "total_steps")


def _reported(ended: np.ndarray, infos) -> EpisodeBatch:
    """The workers' reports of the episodes that ended (`info["curriculum"]`) as one batch."""
    reports = [infos[i][INFO_KEY] for i in ended]
    if not reports:
        return EpisodeBatch.empty(0)
    return EpisodeBatch(
        env_ids=ended.astype(np.int64),
        tasks=np.stack([r["task"] for r in reports]),
        returns=np.array([r["return"] for r in reports], dtype=np.float64),
        lengths=np.array([r["length"] for r in reports], dtype=np.int64),
        successes=np.array([r["success"] for r in reports], dtype=bool),
        truncated=np.array([r["truncated"] for r in reports], dtype=bool),
        total_steps=np.zeros(len(reports), dtype=np.int64),
        initial_obs=np.stack([np.asarray(r["initial_obs"], np.float32) for r in reports]),
    )
