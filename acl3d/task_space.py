"""Task spaces: the named, bounded parameter vectors that teachers sample and environments build.

One object serves both sides so a curriculum, a test set and an environment always agree on the
order, units and bounds of the task dimensions (TeachMyAgent's `param_env_bounds`, made explicit).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from gymnasium import spaces

from acl3d import validation

# Tasks travel as float32 vectors (what teachers propose and environments report).
TASK_DTYPE = np.float32


@dataclass(frozen=True)
class TaskParameter:
    """One named parameter of a task: `dims` values sharing (or not) the same bounds."""

    name: str
    low: tuple[float, ...]
    high: tuple[float, ...]
    unit: str = ""
    doc: str = ""
    default: tuple[float, ...] | None = None

    @property
    def dims(self) -> int:
        return len(self.low)


def _as_tuple(value, dims: int, what: str) -> tuple[float, ...]:
    """`dims` finite bounds from one number (repeated) or `dims` numbers."""
    arr = validation.real_array(what, value).reshape(-1)
    if arr.size == 1 and dims > 1:
        arr = np.repeat(arr, dims)
    if arr.size != dims:
        raise validation.fail(what, value, f"1 or {dims} finite numbers")
    return tuple(float(v) for v in arr)


@dataclass(frozen=True)
class TaskSpace:
    """An ordered list of task parameters with dict <-> flat-vector conversion.

    `low`/`high` are the benchmark bounds a teacher samples in; environments accept buildable
    values outside them (curricula explore beyond bounds).
    """

    parameters: tuple[TaskParameter, ...]
    _offsets: dict = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        if not self.parameters:
            raise ValueError("a task space needs at least one parameter")
        offsets, start = {}, 0
        for p in self.parameters:
            if p.name in offsets:
                raise ValueError(f"duplicate task parameter name {p.name!r}")
            lo = validation.real_array(f"{p.name} lower bound", p.low)
            hi = validation.real_array(f"{p.name} upper bound", p.high)
            if lo.shape != hi.shape or lo.ndim != 1 or lo.size == 0:
                raise validation.fail(
                    f"bounds of {p.name!r}", (p.low, p.high), "as many lower as upper bounds"
                )
            if np.any(lo > hi):  # shown as written: [min, max] (per dimension if several)
                given = [lo.tolist(), hi.tolist()] if lo.size > 1 else [lo.item(), hi.item()]
                raise validation.fail(f"bounds of {p.name!r}", given, "min <= max")
            offsets[p.name] = (start, start + p.dims)
            start += p.dims
        object.__setattr__(self, "_offsets", offsets)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_bounds(cls, bounds: Mapping[str, Sequence]) -> TaskSpace:
        """Build from TeachMyAgent bounds: `{name: [min, max]}`, `[min, max, n]` or `[[min, max], ...]`."""
        forms = "[min, max], [min, max, n] or [[min, max], ...] of finite numbers"
        if not isinstance(bounds, Mapping) or not bounds:
            raise validation.fail("bounds", bounds, "a non-empty {name: [min, max]} mapping")
        params = []
        for name, b in bounds.items():
            what = f"bounds[{name!r}]"
            if not isinstance(name, str) or not name:
                raise validation.fail("bounds", bounds, "parameter names that are strings")
            if not isinstance(b, (list, tuple, np.ndarray)):
                raise validation.fail(what, b, forms)
            b = b.tolist() if isinstance(b, np.ndarray) else list(b)
            if b and isinstance(b[0], (list, tuple)):
                pairs = validation.real_array(what, b)
                if pairs.ndim != 2 or pairs.shape[1] != 2:
                    raise validation.fail(what, b, forms)
                low, high = tuple(pairs[:, 0]), tuple(pairs[:, 1])
            elif len(b) == 2:
                low = (validation.real(f"{what} min", b[0]),)
                high = (validation.real(f"{what} max", b[1]),)
            elif len(b) == 3:
                n = validation.integer(f"{what} dimension count", b[2], 1, allow_float=True)
                low = (validation.real(f"{what} min", b[0]),) * n
                high = (validation.real(f"{what} max", b[1]),) * n
            else:
                raise validation.fail(what, b, forms)
            params.append(TaskParameter(name, tuple(map(float, low)), tuple(map(float, high))))
        return cls(tuple(params))

    @classmethod
    def from_gym(cls, space: spaces.Box, names: Sequence[str] | None = None) -> TaskSpace:
        """Build from a 1-d `gymnasium.spaces.Box` with finite bounds; `names` label its
        dimensions (default "x0", "x1", ...)."""
        if not isinstance(space, spaces.Box) or len(space.shape) != 1:
            raise validation.fail("task_space", space, "a 1-d gymnasium.spaces.Box")
        if not (np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))):
            raise validation.fail("task_space", space, "a Box with finite bounds")
        dim = space.shape[0]
        names = [f"x{i}" for i in range(dim)] if names is None else list(names)
        if len(names) != dim or not all(isinstance(n, str) and n for n in names):
            raise validation.fail("names", names, f"{dim} non-empty strings")
        return cls(
            tuple(
                TaskParameter(n, (float(lo),), (float(hi),))
                for n, lo, hi in zip(names, space.low, space.high)
            )
        )

    @classmethod
    def coerce(cls, space) -> TaskSpace:
        """Accept a TaskSpace, a TeachMyAgent bounds dict or a 1-d `gymnasium.spaces.Box`."""
        if isinstance(space, TaskSpace):
            return space
        if isinstance(space, Mapping):
            return cls.from_bounds(space)
        if isinstance(space, spaces.Box):
            return cls.from_gym(space)
        raise validation.fail(
            "task_space",
            space,
            "a TaskSpace, a bounds dict {name: [min, max]} or a 1-d gymnasium.spaces.Box",
        )

    def with_bounds(self, **bounds) -> TaskSpace:
        """A copy whose named parameters get new bounds, e.g. `with_bounds(stump_height=(0, 9))`."""
        params = []
        unknown = set(bounds) - set(self.names)
        if unknown:
            raise ValueError(
                f"unknown task parameter(s) {sorted(unknown)}; valid: {list(self.names)}"
            )
        for p in self.parameters:
            if p.name in bounds:
                pair = bounds[p.name]
                if not isinstance(pair, (list, tuple)) or len(pair) != 2:
                    raise validation.fail(f"bounds[{p.name!r}]", pair, "a (min, max) pair")
                lo, hi = pair
                p = TaskParameter(
                    p.name,
                    _as_tuple(lo, p.dims, p.name),
                    _as_tuple(hi, p.dims, p.name),
                    p.unit,
                    p.doc,
                    p.default,
                )
            params.append(p)
        return TaskSpace(tuple(params))

    # ------------------------------------------------------------------ description
    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    @property
    def dim(self) -> int:
        return sum(p.dims for p in self.parameters)

    @property
    def low(self) -> np.ndarray:
        return np.concatenate([p.low for p in self.parameters]).astype(np.float64)

    @property
    def high(self) -> np.ndarray:
        return np.concatenate([p.high for p in self.parameters]).astype(np.float64)

    @property
    def gym_space(self) -> spaces.Box:
        """The bounds as a float32 `gymnasium.spaces.Box` of shape (dim,): what teachers sample
        in and what `sample_task()` returns (e.g. Syllabus' `BoxTaskSpace(space.gym_space)`)."""
        return spaces.Box(
            self.low.astype(TASK_DTYPE), self.high.astype(TASK_DTYPE), dtype=TASK_DTYPE
        )

    def bounds_dict(self) -> dict[str, list]:
        """TeachMyAgent-style bounds (a list of [min, max] pairs per parameter)."""
        return {
            p.name: [[lo, hi] for lo, hi in zip(p.low, p.high)]
            if p.dims > 1
            else [p.low[0], p.high[0]]
            for p in self.parameters
        }

    def describe(self) -> str:
        lines = []
        for p in self.parameters:
            rng = (
                f"[{p.low[0]:g}, {p.high[0]:g}]"
                if len(set(p.low)) == 1 and len(set(p.high)) == 1
                else f"{list(p.low)}..{list(p.high)}"
            )
            lines.append(
                f"{p.name} ({p.dims}d{', ' + p.unit if p.unit else ''}): {rng}  {p.doc}".rstrip()
            )
        return "\n".join(lines)

    def slice(self, name: str) -> slice:
        start, stop = self._offsets[name]
        return slice(start, stop)

    # ------------------------------------------------------------------ conversion
    def to_dict(self, vector) -> dict[str, float | np.ndarray]:
        """Flat vector -> {name: float (1-d parameter) or array}."""
        vec = self.validate_vector(vector)
        out = {}
        for p in self.parameters:
            v = vec[self.slice(p.name)]
            out[p.name] = float(v[0]) if p.dims == 1 else v.copy()
        return out

    def columns(self, tasks: np.ndarray) -> dict[str, np.ndarray]:
        """(k, dim) task vectors -> {name: (k, dims) array}: each parameter's values over the
        tasks (what a generator's buildable check takes, for a batch in one call)."""
        return {p.name: tasks[:, self.slice(p.name)] for p in self.parameters}

    def to_vector(self, task: Mapping, fill_defaults: bool = True) -> np.ndarray:
        """{name: value} -> flat float64 vector; missing names take their default (or fail).

        Values are real numbers (or sequences/arrays of them): strings, bools and complex
        numbers are rejected, not converted.
        """
        if not isinstance(task, Mapping):
            raise validation.fail("task", task, f"a mapping of {list(self.names)} to numbers")
        unknown = set(task) - set(self.names)
        if unknown:
            raise ValueError(
                f"unknown task parameter(s) {sorted(map(str, unknown))}; valid: {list(self.names)}"
            )
        parts = []
        for p in self.parameters:
            if p.name in task:
                value = task[p.name]
            elif fill_defaults and p.default is not None:
                value = p.default
            else:
                raise ValueError(f"task parameter {p.name!r} missing and it has no default")
            parts.append(validation.real_array(p.name, value, size=p.dims))
        return np.concatenate(parts)

    def parse(self, text: str) -> dict[str, float | np.ndarray]:
        """Parse a CLI task: `"a=1.5,b=3"` (vector values as `v=0:1:2`) or a JSON object."""
        import json

        text = text.strip()
        if text.startswith("{"):
            try:
                task = json.loads(text)
            except json.JSONDecodeError as exc:
                raise validation.fail("task", text, f"a JSON object of numbers ({exc})") from None
        else:
            task = {}
            for item in filter(None, (t.strip() for t in text.split(","))):
                if "=" not in item:
                    raise ValueError(
                        f"task item {item!r}: expected name=value; parameters: {list(self.names)}"
                    )
                name, value = (t.strip() for t in item.split("=", 1))
                try:
                    numbers = [float(v) for v in value.split(":")]
                except ValueError:
                    raise ValueError(
                        f"task parameter {name!r}: {value!r} is not a number"
                    ) from None
                task[name] = numbers[0] if len(numbers) == 1 else np.array(numbers)
        self.to_vector(task)  # validates names, sizes and finiteness
        return task

    def validate_vector(self, vector) -> np.ndarray:
        """Check a flat task vector (real, finite, shape (dim,)); return it as float64."""
        valid = f"{self.dim} finite real numbers, shape ({self.dim},), for {list(self.names)}"
        if not validation.only_reals(vector):
            raise validation.fail("task vector", vector, valid)
        try:
            vec = np.asarray(vector, dtype=np.float64)
        except (OverflowError, ValueError):
            raise validation.fail("task vector", vector, valid) from None
        if vec.shape != (self.dim,):
            raise validation.fail("task vector", vector, f"{valid}; got shape {vec.shape}")
        if not np.all(np.isfinite(vec)):
            bad = [self._name_of(i) for i in np.flatnonzero(~np.isfinite(vec))]
            raise validation.fail("task vector", vector, f"{valid}; non-finite {bad}")
        return vec

    def contains(self, vector) -> bool:
        vec = self.validate_vector(vector)
        return bool(np.all(vec >= self.low) and np.all(vec <= self.high))

    def _name_of(self, index: int) -> str:
        for name, (a, b) in self._offsets.items():
            if a <= index < b:
                return name if b - a == 1 else f"{name}[{index - a}]"
        raise IndexError(index)

    def flat_names(self) -> list[str]:
        """One label per flat dimension (`name` or `name[i]`), for plots and CSV headers."""
        return [self._name_of(i) for i in range(self.dim)]
