"""3D Terrain test sets: a graded set from flat ground to the hardest corner, by name.

"graded": task k of n has difficulty d = k / (n - 1); every parameter of the space moves from
its easy end to its hard end with d (heights, slopes and roughness up, spacing down, blocks
wider), each jittered by U(-0.05, 0.05) of its range from `numpy.random.default_rng(2101)` and
clipped into the bounds. The fraction of it a student masters reads as how far along the
difficulty axis it got, whatever the teacher.
"""

from __future__ import annotations

import numpy as np

from acl3d import validation
from acl3d.task_space import TaskSpace
from acl3d.terrain.terrain3d import terrain3d_task_space

SEED = 2101
NB_TASKS = 100
JITTER = 0.05  # of each parameter's range
EASY_AT_HIGH = ("block_spacing",)  # parameters that are easiest at their upper bound


def easy_corner(space: TaskSpace) -> np.ndarray:
    """The easiest task of `space`: every parameter at its easy end."""
    easy = space.low.copy()
    for name in EASY_AT_HIGH:
        if name in space.names:
            easy[space.slice(name)] = space.high[space.slice(name)]
    return easy


def graded(task_space: TaskSpace | None = None, nb_tasks: int = NB_TASKS) -> np.ndarray:
    """(nb_tasks, d) tasks in task-space order, difficulty rising from the first to the last."""
    validation.integer("nb_tasks", nb_tasks, 2)
    space = task_space or terrain3d_task_space()
    easy = easy_corner(space)
    hard = space.low + space.high - easy
    d = np.linspace(0.0, 1.0, nb_tasks)[:, None]
    rng = np.random.default_rng(SEED)
    jitter = rng.uniform(-JITTER, JITTER, size=(nb_tasks, space.dim)) * (space.high - space.low)
    return np.clip(easy + d * (hard - easy) + jitter, space.low, space.high)
