"""Parkour test sets: seeded walking, climbing and swimming sets, loadable by name.

TeachMyAgent evaluates Parkour students on three fixed 100-task sets (§4.1 of the reference)
whose files are not available and which leave the training space (CPPN scale 20, inputs over
[-1, 1], creepers_width away from its fixed 0.25). acl3d rebuilds the same families INSIDE the
training space, so "% mastered" measures what the curriculum could have taught:

* walking:  CPPN input uniform in the input box; water 0 except one task at 0.65 and one at
            0.75; no creepers (height 0); scale 10 (the original: scale 20, wider inputs).
* climbing: input uniform; water U(0, 0.8); creepers_height U(0, 4), creepers_spacing U(0, 5);
            creepers_width 0.25 (the original varies it in [0, 0.5]).
* swimming: input uniform; water 1; no creepers; scale 10 (the original mixes 10 and 20).

Each set is drawn from `numpy.random.default_rng(seed)` with the seed below, so it is the same
on every machine. The Parkour environment's curriculum profile (acl3d.envs.profiles) offers
them by name, so `test_set="walking"` (or "walking_test_set_v1") selects one for training and
evaluation, and `acl3d.teachers.test_sets.save` writes one as JSON or CSV.
"""

from __future__ import annotations

import numpy as np

from acl3d import validation
from acl3d.task_space import TaskSpace
from acl3d.terrain.parkour import parkour_task_space

SEEDS = {"walking": 1001, "climbing": 1002, "swimming": 1003}
NB_TASKS = 100
ALIASES = {f"{name}_test_set_v1": name for name in SEEDS}


def _in_bounds(space: TaskSpace, rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.uniform(space.low, space.high, size=(n, space.dim))


def build(name: str, task_space: TaskSpace | None = None, nb_tasks: int = NB_TASKS) -> np.ndarray:
    """The named set, (nb_tasks, 8) in task-space order, inside `task_space` (default: medium)."""
    name = ALIASES.get(name, name)
    if name not in SEEDS:
        raise ValueError(
            f"unknown Parkour test set {name!r}; valid: {list(SEEDS)} or {list(ALIASES)}"
        )
    validation.integer("nb_tasks", nb_tasks, 2)
    space = task_space or parkour_task_space("medium")
    rng = np.random.default_rng(SEEDS[name])
    tasks = _in_bounds(space, rng, nb_tasks)
    col = {n: space.slice(n) for n in space.names}
    width = space.low[col["creepers_width"]]
    if name == "walking":
        tasks[:, col["water_level"]] = 0.0
        tasks[-2:, col["water_level"]] = [[0.65], [0.75]]
        tasks[:, col["creepers_height"]] = 0.0
        tasks[:, col["creepers_spacing"]] = 0.0
    elif name == "climbing":
        tasks[:, col["water_level"]] = rng.uniform(0.0, 0.8, size=(nb_tasks, 1))
    else:
        tasks[:, col["water_level"]] = 1.0
        tasks[:, col["creepers_height"]] = 0.0
        tasks[:, col["creepers_spacing"]] = 0.0
    tasks[:, col["creepers_width"]] = width
    return np.clip(tasks, space.low, space.high)
