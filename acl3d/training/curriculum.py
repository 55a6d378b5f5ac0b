"""Curriculum sync between a teacher in the main process and environments in worker processes.

SB3 vector envs reset finished episodes inside `step()` with no options, so a task pushed after
the fact would arrive one episode late. Instead each worker env *pulls* its next task at reset
from a small queue that the main process keeps filled (Syllabus' pattern):

* `CurriculumEnv` (worker side) plays the task at the head of its queue at every reset that
  does not name a task itself, and reports the finished episode (task actually played, return,
  length, success, initial observation, truncation) in the last step's `info["curriculum"]`.
* `CurriculumVecEnv` (main side) pushes one prefetched task per worker before the first reset
  and one more right after each finished episode, before the next `step_async`, so the step loop
  never waits for the teacher; it hands every finished episode to the teacher exactly once.

With one task of prefetch, the teacher learns the outcome of a worker's episode k before it
samples that worker's task k + 2. Errors raised inside a worker env are caught and carried back
with their traceback, so a crash stops training with a readable message on both vec env types.

Exploratory levels (Robust PLR / ACCEL's new or edited ones, on which the student must not
learn) are flagged when their task is sampled; the flag follows the task through the queue and
`step_exploratory` tells, for each stepped transition, whether its episode is exploratory.
"""

from __future__ import annotations

import traceback
from collections import deque
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

from acl3d.envs.curriculum_wrapper import (
    INFO_KEY,
    CurriculumWorker,
    TaskQueue,
    played_task,
    success_return,
)
from acl3d.envs.env_state import restore_wrappers

ERROR_KEY = "acl3d_worker_error"


class WorkerError(RuntimeError):
    """An environment raised inside a worker; the message carries the worker's traceback."""


@dataclass
class Episode:
    """One finished training episode as the teacher received it."""

    worker: int
    task: np.ndarray
    episode_return: float
    length: int
    success: bool
    truncated: bool
    initial_obs: np.ndarray
    total_steps: int


class CurriculumEnv(gym.Wrapper, CurriculumWorker):
    """Worker-side wrapper: pulls queued tasks at reset, reports episode outcomes in `info`.

    A reset whose `options` already hold a `"task"` (evaluation, rendering) plays that task and
    leaves the queue alone; any other reset needs a queued task and fails loudly without one, so a
    curriculum can never silently run an environment's default task. The queue and the episode
    report are the protocol every worker shares (`acl3d.envs.curriculum_wrapper.TaskQueue`).
    """

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.queue = TaskQueue(success_return(env))
        self._return = 0.0
        self._length = 0
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
        self.queue.begin(played_task(self.env, options["task"]), obs)
        self._return, self._length = 0.0, 0
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
        self._return += float(reward)
        self._length += 1
        self._last_obs = obs
        if terminated or truncated:
            self.queue.report(info, self._return, self._length, terminated, truncated)
        return obs, reward, terminated, truncated, info

    def get_state(self) -> dict:
        """Queue, running episode and the env's own `get_state()`: what a checkpoint needs to
        continue this worker's episode exactly (the same layout as a batched sub-env's, so a run
        may resume on another vec env kind). JSON scalars and numpy arrays; `"env"` is None for
        an env without `get_state()` (its episode then cannot be continued)."""
        inner = self.env.unwrapped
        size = len(self.queue.tasks[0]) if self.queue.tasks else 0
        return self.queue.get_state(
            self._return,
            self._length,
            self._last_obs,
            inner.get_state() if hasattr(inner, "get_state") else None,
            size,
        )

    def set_state(self, state: dict) -> None:
        """Inverse of `get_state()` (on a worker built with the same arguments)."""
        if state["env"] is not None:
            self.env.unwrapped.set_state(state["env"])
            restore_wrappers(self.env, int(state["length"]))
        self.queue.set_state(state)
        self._return, self._length = float(state["return"]), int(state["length"])
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
    """Main-side wrapper: keeps every worker's task queue one task ahead and feeds the teacher.

    `controller` is an `acl3d.teachers.controller.TeacherController` (anything with
    `sample_task`, `record_episode`, `needs` and optionally `record_step` /
    `maybe_sample_periodically`, `sample_training_task`). It must sit directly on the worker
    `VecEnv` (below any VecNormalize) so that it sees raw observations and rewards.

    On an in-process batched env (`acl3d.vec.batched_sb3.BatchedVecEnv`, which has a
    `task_source`) nothing is queued: each sub-env pulls its next task from `next_task` at its
    own reset, after this wrapper was handed the step's finished episodes
    (`episodes_finished`), so the teacher always knows an episode's outcome before it samples
    that sub-env's next task.
    """

    def __init__(self, venv: VecEnv, controller, total_steps: int = 0):
        super().__init__(venv)
        self.controller = controller
        self.total_steps = int(total_steps)
        self.episodes_done = 0
        self._pending = np.zeros(self.num_envs, dtype=np.int64)
        # exploratory flags: of each env's running episode, of its queued tasks, of the last step
        self._running_exploratory = np.zeros(self.num_envs, dtype=bool)
        self._queued_exploratory: list[deque[bool]] = [deque() for _ in range(self.num_envs)]
        self._step_exploratory = np.zeros(self.num_envs, dtype=bool)
        self._finished: list[Episode] = []
        self._last_obs = None
        self._actions = None
        needs = set(getattr(controller, "needs", ()))
        self._record_steps = "step_rewards" in needs
        self._pull = hasattr(venv, "task_source")
        if self._pull:
            venv.task_source = self

    def next_task(self, index: int) -> np.ndarray:
        """The teacher's next task for sub-env `index` (pulled at its reset)."""
        task, self._running_exploratory[index] = self._sample()
        return task

    def _sample(self) -> tuple[np.ndarray, bool]:
        """(task, exploratory); a controller without `sample_training_task` marks no level."""
        sample = getattr(self.controller, "sample_training_task", None)
        task, exploratory = sample() if sample else (self.controller.sample_task(), False)
        return np.asarray(task, dtype=np.float32), bool(exploratory)

    @property
    def step_exploratory(self) -> np.ndarray:
        """Read-only (n_envs,) bools: whether each env's transition of the latest step belongs to
        an exploratory episode (flags taken at `step_async`, before any auto-reset)."""
        flags = self._step_exploratory.copy()
        flags.flags.writeable = False
        return flags

    # -------------------------------------------------------------- queue management
    def _push(self, index: int) -> None:
        task, exploratory = self._sample()
        self.venv.env_method("push_task", task, indices=[index])
        self._queued_exploratory[index].append(exploratory)
        self._pending[index] += 1

    def _start_queued(self, index: int) -> None:
        """Worker `index` began an episode on the head of its queue."""
        self._pending[index] -= 1
        self._running_exploratory[index] = self._queued_exploratory[index].popleft()

    def reset(self):
        if self._pull:
            self._last_obs = self.venv.reset()
            return self._last_obs
        for i in range(self.num_envs):
            if self._pending[i] == 0:
                self._push(i)
        obs = self.venv.reset()
        raise_worker_errors(getattr(self.venv, "reset_infos", []), "reset")
        for i in range(self.num_envs):
            self._start_queued(i)  # every worker consumed one queued task
            self._push(i)
        self._last_obs = obs
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions
        self._step_exploratory = self._running_exploratory.copy()
        self.venv.step_async(actions)

    def step_wait(self):
        try:
            obs, rewards, dones, infos = self.venv.step_wait()
        except (EOFError, ConnectionError) as exc:  # a worker process died without a traceback
            codes = [p.exitcode for p in getattr(self.venv, "processes", [])]
            raise WorkerError(f"an environment worker process died (exit codes {codes})") from exc
        if not self._pull:
            raise_worker_errors(infos, "step")
            self.episodes_finished(obs, rewards, dones, infos)
        self._last_obs = obs
        return obs, rewards, dones, infos

    def episodes_finished(self, obs, rewards, dones, infos) -> None:
        """A step's book-keeping: step records, finished episodes to the teacher, and (pushing
        mode) the next task into each finished worker's queue; `obs` before any auto-reset."""
        self.total_steps += self.num_envs
        if self._record_steps:
            for i in range(self.num_envs):
                next_obs = infos[i]["terminal_observation"] if dones[i] else obs[i]
                self.controller.record_step(
                    self._last_obs[i],
                    self._actions[i],
                    float(rewards[i]),
                    next_obs,
                    bool(dones[i]),
                    worker=i,
                )
        for i in np.flatnonzero(dones):
            self._report(int(i), infos[i])
            if not self._pull:
                self._start_queued(int(i))  # the auto-reset consumed the prefetched task
                self._push(int(i))
        maybe_sample = getattr(self.controller, "maybe_sample_periodically", None)
        if maybe_sample is not None:
            maybe_sample(self.total_steps)

    def _report(self, worker: int, info: dict) -> None:
        ep = info[INFO_KEY]
        self.controller.record_episode(
            ep["task"], ep["return"], ep["length"], ep["success"], initial_obs=ep["initial_obs"]
        )
        self.episodes_done += 1
        self._finished.append(
            Episode(
                worker=worker,
                task=np.asarray(ep["task"], dtype=np.float32),
                episode_return=float(ep["return"]),
                length=int(ep["length"]),
                success=bool(ep["success"]),
                truncated=bool(ep["truncated"]),
                initial_obs=ep["initial_obs"],
                total_steps=self.total_steps,
            )
        )

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
        # checkpoints written before exploratory levels were tracked flag none
        self._running_exploratory = np.asarray(
            state.get("running_exploratory", np.zeros(self.num_envs)), dtype=bool
        ).copy()
        queued = state.get("queued_exploratory") or [[False] * int(n) for n in self._pending]
        self._queued_exploratory = [deque(bool(f) for f in q) for q in queued]
        self._last_obs = state["last_obs"]
        self._finished = []

    def pop_finished(self) -> list[Episode]:
        """Episodes finished since the last call (for logging), oldest first."""
        out, self._finished = self._finished, []
        return out
