"""A teacher driving acl3d envs from your own training loop.

* `CurriculumWrapper(env, teacher)`: a Gymnasium wrapper for one env. Each `reset()` without a
  task in its options plays `teacher.sample_task()`; each finished episode is reported with
  `teacher.episodic_update(task, return, success)` before the wrapper returns its last step, and
  described in `info["curriculum"]` (see `episode_report`).
* `TaskSource`: the per-sub-env hook of the batched vector env
  (`acl3d.envs.batched_vector.BatchedVectorEnv(task_source=...)`): `next_task(i)` is asked at
  sub-env i's reset, `episode_finished(i, report)` at the step its episode ends, so a source
  always learns an episode's outcome before it chooses that sub-env's next task.
  `TeacherTaskSource(teacher)` is that hook for any teacher.

A teacher is any acl3d teacher, or any object with `sample_task()` and
`episodic_update(task, reward, is_success)`. A task passed in `reset(options={"task": ...})`
(evaluation, a replay) is played without asking or telling the teacher.
"""

from __future__ import annotations

from typing import Protocol

import gymnasium as gym
import numpy as np

from acl3d import validation

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


def check_teacher(teacher) -> None:
    """ValueError unless `teacher` can propose tasks and learn from episodes."""
    missing = [
        m for m in ("sample_task", "episodic_update") if not callable(getattr(teacher, m, None))
    ]
    if missing:
        raise validation.fail(
            "teacher",
            teacher,
            f"an object with sample_task() and episodic_update(); {missing} missing",
        )


class TaskSource(Protocol):
    """Chooses each sub-env's task at its reset and hears how each episode went."""

    def next_task(self, index: int):
        """The task sub-env `index` plays next (a flat vector or a {name: value} dict)."""

    def episode_finished(self, index: int, report: dict) -> None:
        """Sub-env `index` finished an episode (`report`: see `episode_report`)."""


class TeacherTaskSource:
    """`TaskSource` of one teacher shared by all sub-envs."""

    def __init__(self, teacher):
        check_teacher(teacher)
        self.teacher = teacher

    def next_task(self, index: int) -> np.ndarray:
        return np.asarray(self.teacher.sample_task(), dtype=np.float32)

    def episode_finished(self, index: int, report: dict) -> None:
        self.teacher.episodic_update(report["task"], report["return"], report["success"])


class CurriculumWrapper(gym.Wrapper):
    """One env whose tasks come from `teacher` (see the module docstring)."""

    def __init__(self, env: gym.Env, teacher):
        super().__init__(env)
        check_teacher(teacher)
        self.teacher = teacher
        self._task: np.ndarray | None = None
        self._from_teacher = False
        self._return = 0.0
        self._length = 0
        self._initial_obs = None

    def reset(self, *, seed=None, options=None):
        if options is not None and not isinstance(options, dict):
            raise validation.fail("options", options, "None or a dict")
        options = dict(options or {})
        from_teacher = "task" not in options
        if from_teacher:
            options["task"] = np.asarray(self.teacher.sample_task(), dtype=np.float32)
        obs, info = self.env.reset(seed=seed, options=options)
        task = options["task"]
        if isinstance(task, dict):  # a named task: report the vector the env built
            task = self.env.unwrapped.task_vector
        self._task, self._from_teacher = np.asarray(task, dtype=np.float32), from_teacher
        self._return, self._length = 0.0, 0
        self._initial_obs = np.array(obs, copy=True)
        return obs, info

    def step(self, action):
        if self._task is None:
            raise RuntimeError("CurriculumWrapper.step() before reset()")
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._return += float(reward)
        self._length += 1
        if terminated or truncated:
            report = episode_report(
                self._task,
                self._return,
                self._length,
                info.get("success", False),
                truncated and not terminated,
                self._initial_obs,
            )
            info[INFO_KEY] = report
            if self._from_teacher:
                self.teacher.episodic_update(report["task"], report["return"], report["success"])
        return obs, reward, terminated, truncated, info
