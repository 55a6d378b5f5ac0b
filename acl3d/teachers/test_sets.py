"""Fixed evaluation task sets: build, load, save and check them against a task space.

A test set is an (N, d) float array of tasks in task-space order. Test tasks only need the right
dimension and finite values: like TeachMyAgent's sets they may lie outside the training bounds.

Files are open formats:
* JSON: {"names": [flat names], "tasks": [[...], ...]} or a list of {parameter: value} dicts
  (missing parameters take their default);
* CSV: a header of flat names (`name` or `name[i]`), one task per row.
Columns are matched by name, so their order in the file does not matter.

Named sets ("walking", ...) and the default set's fixed grid belong to the environment: they come
from its `CurriculumProfile` (`resolve(..., profile=env.unwrapped.curriculum_profile)`).
"""

from __future__ import annotations

import csv
import itertools
import json
import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from acl3d.curriculum_profile import CurriculumProfile
from acl3d.task_space import TaskSpace

UNIFORM_SEED = 31
# Bounds that protect the machine: a test pass of this many episodes already costs up to 2e8 env
# steps, and a file is read whole before its tasks are counted.
MAX_TASKS = 100_000
MAX_FILE_BYTES = 256 * 2**20


def validate(tasks, task_space) -> np.ndarray:
    """Check an (N, d) array of finite tasks; return it as float64."""
    space = TaskSpace.coerce(task_space)
    try:
        arr = np.asarray(tasks, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("test set: expected an (N, d) array of numbers") from None
    if arr.ndim != 2 or arr.shape[1] != space.dim or arr.shape[0] == 0:
        raise ValueError(
            f"test set: expected shape (N >= 1, {space.dim}) for {space.flat_names()}, got {arr.shape}"
        )
    _check_size(len(arr), "test set")
    bad = np.argwhere(~np.isfinite(arr))
    if len(bad):
        i, j = bad[0]
        raise ValueError(
            f"test set: non-finite value in task {i}, dimension {space.flat_names()[j]!r}"
        )
    return arr


def _check_size(n_tasks: int, where: str) -> None:
    if n_tasks > MAX_TASKS:
        raise ValueError(f"{where}: {n_tasks} tasks; valid: at most {MAX_TASKS}")


def _points_per_dim(nb_tasks: int, n_free: int) -> int:
    k = int(math.floor(nb_tasks ** (1.0 / n_free) + 1e-9))
    if k < 2:
        raise ValueError(
            f"grid test set: {nb_tasks} test tasks give fewer than 2 points per dimension over "
            f"{n_free} varying dimensions; ask for at least {2**n_free} (--nb-test-episodes, "
            "nb_tasks in Python) or use 'uniform'"
        )
    return k


def grid(
    task_space, nb_tasks: int = 100, ranges: Mapping[str, tuple[float, float]] | None = None
) -> np.ndarray:
    """A regular grid, first dimension varying fastest, floor(nb_tasks^(1/d')) points per varying
    dimension (d' = dimensions with min < max; constant ones keep their value).

    `ranges` overrides the bounds of named parameters (a profile's `default_test_grid`)."""
    space = TaskSpace.coerce(task_space)
    low, high = space.low.copy(), space.high.copy()
    for name, (lo, hi) in (ranges or {}).items():
        low[space.slice(name)], high[space.slice(name)] = lo, hi
    free = high > low
    if not free.any():
        return low[None, :].copy()
    k = _points_per_dim(nb_tasks, int(free.sum()))
    axes = [np.linspace(lo, hi, k) if f else np.array([lo]) for lo, hi, f in zip(low, high, free)]
    return np.array([combo[::-1] for combo in itertools.product(*axes[::-1])], dtype=np.float64)


def uniform(task_space, nb_tasks: int = 100, seed: int = UNIFORM_SEED) -> np.ndarray:
    """`nb_tasks` uniform tasks within the bounds from numpy's default_rng(seed)."""
    space = TaskSpace.coerce(task_space)
    if nb_tasks < 1:
        raise ValueError(f"nb_tasks must be >= 1, got {nb_tasks}")
    return np.random.default_rng(seed).uniform(space.low, space.high, size=(nb_tasks, space.dim))


def default(task_space, nb_tasks: int = 100, profile: CurriculumProfile | None = None):
    """TeachMyAgent's rule: the profile's fixed grid when the space has exactly its parameters
    (the Stump Tracks set), else uniform."""
    space = TaskSpace.coerce(task_space)
    ranges = profile.default_test_grid if profile is not None else None
    if ranges and set(space.names) == set(ranges):
        return grid(space, nb_tasks, ranges)
    return uniform(space, nb_tasks)


def _reorder(names: list[str], rows, space: TaskSpace, where: str) -> np.ndarray:
    flat = space.flat_names()
    missing = [n for n in flat if n not in names]
    unknown = [n for n in names if n not in flat]
    if missing or unknown or len(names) != len(set(names)):
        raise ValueError(
            f"{where}: columns {names} must be exactly the task dimensions {flat} (missing {missing}, unknown {unknown})"
        )
    try:
        arr = np.asarray(rows, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: tasks must be rows of numbers") from None
    if arr.ndim != 2 or arr.shape[1] != len(names):
        raise ValueError(f"{where}: expected rows of {len(names)} values, got shape {arr.shape}")
    return arr[:, [names.index(n) for n in flat]]


def load(path, task_space) -> np.ndarray:
    """Read a .json or .csv test set (see the module docstring) and validate it."""
    space = TaskSpace.coerce(task_space)
    path = Path(path)
    where = f"test_set={str(path)!r}"
    if not path.is_file():
        raise ValueError(f"{where}: no such file")
    size = path.stat().st_size
    if size > MAX_FILE_BYTES:
        raise ValueError(f"{where}: a file of {size} bytes; valid: at most {MAX_FILE_BYTES}")
    if path.suffix == ".json":
        try:
            data = json.loads(path.read_text())
        except (ValueError, UnicodeDecodeError) as exc:  # JSONDecodeError says where it failed
            raise ValueError(f"{where}: not valid JSON ({exc})") from None
        tasks = data.get("tasks") if isinstance(data, Mapping) else data
        _check_size(len(tasks) if isinstance(tasks, list) else 0, where)
        if isinstance(data, Mapping):
            if "names" not in data or "tasks" not in data:
                raise ValueError(
                    f'{where}: expected {{"names": [...], "tasks": [[...]]}} or a list of dicts'
                )
            arr = _reorder(list(data["names"]), data["tasks"], space, where)
        elif isinstance(data, list) and all(isinstance(t, Mapping) for t in data):
            arr = np.array([space.to_vector(t) for t in data])
        else:
            raise ValueError(
                f'{where}: expected {{"names": [...], "tasks": [[...]]}} or a list of dicts'
            )
    elif path.suffix == ".csv":
        with path.open(newline="") as fh:
            rows = list(csv.reader(fh))
        if not rows:
            raise ValueError(f"{where}: empty file")
        body = [r for r in rows[1:] if r]
        _check_size(len(body), where)
        try:
            values = [[float(v) for v in r] for r in body]
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None
        arr = _reorder([h.strip() for h in rows[0]], values, space, where)
    else:
        raise ValueError(f"{where}: expected a .json or .csv file")
    return validate(arr, space)


def save(path, tasks, task_space) -> None:
    """Write a test set as .json ({"names", "tasks"}) or .csv (header of flat names)."""
    space = TaskSpace.coerce(task_space)
    arr = validate(tasks, space)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".json":
        path.write_text(json.dumps({"names": space.flat_names(), "tasks": arr.tolist()}))
    elif path.suffix == ".csv":
        with path.open("w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(space.flat_names())
            writer.writerows([repr(float(v)) for v in row] for row in arr)
    else:
        raise ValueError(f"test set file {str(path)!r}: expected a .json or .csv suffix")


def generated(test_set) -> bool:
    """Whether `test_set` (as `resolve` takes it) is drawn at a size: None (the default rule),
    "grid", "uniform" or a named set; a file or an array holds its own tasks."""
    return test_set is None or (isinstance(test_set, str) and not Path(test_set).suffix)


def resolve(
    test_set, task_space, nb_tasks: int = 100, profile: CurriculumProfile | None = None
) -> np.ndarray:
    """None (the default rule), "grid", "uniform", a set named by the environment's profile
    ("walking", ...), a .json/.csv path, or an array -> validated tasks."""
    space = TaskSpace.coerce(task_space)
    named = profile.test_sets if profile is not None else {}
    if test_set is None:
        return default(space, nb_tasks, profile)
    if isinstance(test_set, str) and test_set == "grid":
        return grid(space, nb_tasks)
    if isinstance(test_set, str) and test_set == "uniform":
        return uniform(space, nb_tasks)
    if isinstance(test_set, str) and test_set in named:
        return validate(named[test_set](space, nb_tasks), space)
    if isinstance(test_set, str) and not Path(test_set).suffix:
        raise ValueError(
            f"test set {test_set!r}: not a file (.json/.csv), 'grid', 'uniform' or a named set "
            f"of this environment ({', '.join(named) or 'none'})"
        )
    if isinstance(test_set, (str, Path)):
        return load(test_set, space)
    return validate(test_set, space)
