"""What a curriculum needs of an env, declared once for training, evaluation and the CLI.

Every acl3d env (`TrackEnv` and the envs built on it) is a `TaskEnv` and a `SnapshotEnv`. Another
Gymnasium env takes part in a curriculum by offering the `TaskEnv` members on its unwrapped env;
without `get_state`/`set_state` its runs still resume, but the episodes running at a
checkpoint restart from a reset.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import gymnasium as gym
import numpy as np

from acl3d.curriculum_profile import CurriculumProfile
from acl3d.task_space import TaskSpace


@runtime_checkable
class TaskEnv(Protocol):
    """An env a teacher drives: the tasks it takes and the facts a curriculum reads."""

    task_space: TaskSpace

    @property
    def curriculum_profile(self) -> CurriculumProfile:
        """Reward bounds, success return, prior and test sets of this env."""

    @property
    def task_vector(self) -> np.ndarray:
        """The task the env plays, as a flat vector of `task_space`."""

    def set_task(self, task) -> None:
        """Play `task` (a vector or {name: value}) from the next reset; a ValueError if the
        env cannot build it."""


@runtime_checkable
class SnapshotEnv(Protocol):
    """An env whose exact state a checkpoint holds, so a resumed run continues its episodes."""

    def get_state(self) -> dict: ...

    def set_state(self, state: dict) -> None: ...


def task_env(env: gym.Env) -> TaskEnv:
    """`env.unwrapped`, checked to be a `TaskEnv`: a ValueError naming the env otherwise."""
    inner = env.unwrapped
    if not isinstance(inner, TaskEnv):
        name = type(inner).__name__ if env.spec is None else env.spec.id
        raise ValueError(
            f"environment {name!r} cannot run a curriculum: its unwrapped env "
            f"({type(inner).__name__}) needs task_space, curriculum_profile, task_vector and "
            "set_task(task), as every acl3d env has (acl3d.envs.task_env.TaskEnv)"
        )
    return inner
