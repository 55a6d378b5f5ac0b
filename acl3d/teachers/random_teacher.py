"""Random curriculum: tasks drawn uniformly in the task-space bounds, ignoring all feedback."""

from __future__ import annotations

import numpy as np

from acl3d.teachers.base import Teacher


class RandomTeacher(Teacher):
    """The baseline every curriculum must beat (TeachMyAgent's `RandomTeacher`)."""

    name = "random"

    def __init__(self, task_space, seed: int | None = None):
        super().__init__(task_space, seed)

    def _sample(self) -> np.ndarray:
        return self.uniform_task()

    def _sample_batch(self, n: int) -> np.ndarray:
        # one (n, dim) draw consumes the stream as n single draws do: the same tasks
        return self.rng.uniform(self.mins, self.maxs, size=(n, self.dim))

    def _update_batch(self, tasks, returns, successes) -> None:
        self.nb_episodes += len(tasks)
