"""Hand-written lesson curricula in Unity ML-Agents' format.

A curriculum fixes some task parameters to one value per lesson and moves to the next lesson
when a measure of the student's progress passes that lesson's threshold:

    {"measure": "reward",            # or "progress"
     "thresholds": [50, 150],        # one per lesson transition
     "min_lesson_length": 20,        # episodes
     "signal_smoothing": true,
     "parameters": {"stump_height": [0.0, 1.0, 2.0]}}   # len(thresholds) + 1 values each

As in ML-Agents' original files, parameters may also sit at the top level instead of under
"parameters". The same content can be given as a dict or a .json/.yaml file.

Precise rules (ML-Agents left some of these to the reader):
* The measure is taken once per episode reported to the teacher (`episodic_update`):
  - "reward": that episode's return as the teacher receives it (raw, or in [0, 1] when the
    TeacherController scales rewards, so thresholds must use the same scale);
  - "progress": training progress, environment steps received so far / `max_steps` (ML-Agents'
    steps / max_steps). Steps are counted through `step_update`, so with this measure the
    teacher asks for step rewards (`needs` contains "step_rewards") and requires `max_steps`.
* With signal_smoothing the measure is m = 0.25 * previous_m + 0.75 * new (ML-Agents' weights),
  previous_m starting at 0 and carried across lessons; without it m is the new value.
* The lesson advances after an episode when m > threshold[lesson] (strictly; m equal to the
  threshold does not advance) and the lesson has lasted >= min_lesson_length episodes, that
  episode included. The episode count restarts at 0 in the new lesson. The last lesson is final.
* Parameters the curriculum does not name are drawn uniformly within their bounds every episode
  (domain randomisation over the rest of the space), from the teacher's seeded generator.
* Lesson values must lie within the task-space bounds; a multi-dimensional parameter takes one
  value per dimension or a single value for all of them.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from acl3d.teachers.base import RunFacts, Teacher

_KEYS = ("measure", "thresholds", "min_lesson_length", "signal_smoothing", "parameters")
_MEASURES = ("reward", "progress")


def load_curriculum(curriculum) -> dict[str, Any]:
    """A curriculum dict from a dict or a .json / .yaml / .yml path."""
    if isinstance(curriculum, Mapping):
        return dict(curriculum)
    if isinstance(curriculum, (str, Path)):
        path = Path(curriculum)
        if not path.is_file():
            raise ValueError(f"curriculum file {str(path)!r} does not exist")
        text = path.read_text()
        if path.suffix == ".json":
            data = json.loads(text)
        elif path.suffix in (".yaml", ".yml"):
            import yaml

            data = yaml.safe_load(text)
        else:
            raise ValueError(f"curriculum file {str(path)!r}: expected a .json, .yaml or .yml file")
        if not isinstance(data, Mapping):
            raise ValueError(f"curriculum file {str(path)!r}: expected a mapping at the top level")
        return dict(data)
    raise ValueError(
        f"curriculum must be a dict or a path to a .json/.yaml file, got {type(curriculum).__name__}"
    )


class Lessons(Teacher):
    """ML-Agents lesson curriculum (see the module docstring for the exact rules)."""

    name = "lessons"
    needs = frozenset()

    @classmethod
    def run_params(cls, facts: RunFacts) -> dict[str, Any]:
        """The run's budget: ML-Agents' "progress" measure is relative to it."""
        return {} if facts.total_steps is None else {"max_steps": int(facts.total_steps)}

    def __init__(
        self, task_space, seed: int | None = None, curriculum=None, max_steps: int | None = None
    ):
        super().__init__(task_space, seed)
        if curriculum is None:
            raise ValueError(
                "lessons: curriculum is required (a dict or a path to a .json/.yaml file)"
            )
        data = load_curriculum(curriculum)
        self.measure = data.get("measure", "reward")
        if self.measure not in _MEASURES:
            raise ValueError(f"curriculum measure must be one of {_MEASURES}, got {self.measure!r}")
        thresholds = data.get("thresholds")
        if not isinstance(thresholds, (list, tuple)) or not all(
            isinstance(t, (int, float)) and not isinstance(t, bool) and math.isfinite(t)
            for t in thresholds
        ):
            raise ValueError(
                f"curriculum thresholds must be a list of finite numbers, got {thresholds!r}"
            )
        self.thresholds = [float(t) for t in thresholds]
        mll = data.get("min_lesson_length", 1)
        if not isinstance(mll, int) or isinstance(mll, bool) or mll < 0:
            raise ValueError(
                f"curriculum min_lesson_length must be an integer >= 0 (episodes), got {mll!r}"
            )
        self.min_lesson_length = mll
        smoothing = data.get("signal_smoothing", True)
        if not isinstance(smoothing, bool):
            raise ValueError(
                f"curriculum signal_smoothing must be true or false, got {smoothing!r}"
            )
        self.signal_smoothing = smoothing
        if self.measure == "progress":
            if (
                not isinstance(max_steps, (int, np.integer))
                or isinstance(max_steps, bool)
                or max_steps <= 0
            ):
                raise ValueError(
                    f'measure "progress" needs max_steps, the training budget in environment steps (integer > 0), got {max_steps!r}'
                )
            self.needs = frozenset({"step_rewards"})
        self.max_steps = None if max_steps is None else int(max_steps)
        self.lesson_values = self._parse_parameters(data)
        self.fixed = ~np.isnan(self.lesson_values[0])

        self.lesson = 0
        self.lesson_length = 0
        self.smoothed = 0.0
        self.steps = 0

    def _parse_parameters(self, data: dict) -> np.ndarray:
        """(n_lessons, dim) array of lesson values; NaN where a dimension is not in the curriculum."""
        params = data.get("parameters", {})
        if not isinstance(params, Mapping):
            raise ValueError(
                f"curriculum parameters must be a mapping name -> list of values, got {params!r}"
            )
        params = dict(params)
        for key, value in data.items():
            if key not in _KEYS:
                if key in params:
                    raise ValueError(
                        f"curriculum parameter {key!r} is given twice (top level and under 'parameters')"
                    )
                params[key] = value
        if not params:
            raise ValueError("curriculum names no parameters")
        n = len(self.thresholds) + 1
        values = np.full((n, self.dim), np.nan)
        for name, lessons in params.items():
            if name not in self.task_space.names:
                raise ValueError(
                    f"curriculum parameter {name!r} is not a task parameter; valid: {list(self.task_space.names)}"
                )
            if not isinstance(lessons, (list, tuple)) or len(lessons) != n:
                got = len(lessons) if isinstance(lessons, (list, tuple)) else lessons
                raise ValueError(
                    f"curriculum parameter {name!r}: expected {n} values (one more than the {n - 1} thresholds), got {got!r}"
                )
            sl = self.task_space.slice(name)
            for i, v in enumerate(lessons):
                try:
                    arr = np.broadcast_to(np.asarray(v, dtype=np.float64), (sl.stop - sl.start,))
                except (TypeError, ValueError):
                    raise ValueError(
                        f"curriculum parameter {name!r}, lesson {i}: expected a number or {sl.stop - sl.start} numbers, got {v!r}"
                    ) from None
                lo, hi = self.mins[sl], self.maxs[sl]
                if not np.all(np.isfinite(arr)) or np.any(arr < lo) or np.any(arr > hi):
                    raise ValueError(
                        f"curriculum parameter {name!r}, lesson {i}: value {v!r} is outside the bounds [{lo.min():g}, {hi.max():g}]"
                    )
                values[i, sl] = arr
        return values

    @property
    def n_lessons(self) -> int:
        return len(self.thresholds) + 1

    def current_values(self) -> dict[str, Any]:
        """The values the current lesson fixes, by parameter name."""
        row = self.lesson_values[self.lesson]
        out = {}
        for p in self.task_space.parameters:
            v = row[self.task_space.slice(p.name)]
            if not np.isnan(v).any():
                out[p.name] = float(v[0]) if p.dims == 1 else v.copy()
        return out

    def plot_state(self) -> dict[str, Any]:
        """Every lesson as one task (randomised dimensions at the centre of their bounds)."""
        tasks = np.where(
            np.isnan(self.lesson_values), (self.mins + self.maxs) / 2, self.lesson_values
        )
        return {
            "kind": "lesson",
            "index": self.lesson,
            "tasks": tasks,
            "current": self.current_values(),
        }

    # ------------------------------------------------------------------ teacher API
    def _sample(self) -> np.ndarray:
        task = self.uniform_task()
        task[self.fixed] = self.lesson_values[self.lesson, self.fixed]
        return task

    def _step_update(self, state, action, reward: float, next_state, done: bool, stream) -> None:
        self.steps += 1

    def _step_updates(self, states, actions, rewards, next_states, dones, streams) -> None:
        self.steps += len(streams)

    def _episodic_update(self, task: np.ndarray, reward: float, is_success: bool) -> None:
        new = reward if self.measure == "reward" else self.steps / self.max_steps
        m = 0.25 * self.smoothed + 0.75 * new if self.signal_smoothing else new
        self.smoothed = m
        self.lesson_length += 1
        self.bk["lesson"].append(self.lesson)
        self.bk["measure"].append(m)
        if (
            self.lesson < self.n_lessons - 1
            and m > self.thresholds[self.lesson]
            and self.lesson_length >= self.min_lesson_length
        ):
            self.lesson += 1
            self.lesson_length = 0

    def _extra_state(self) -> dict[str, Any]:
        return {
            "lesson": self.lesson,
            "lesson_length": self.lesson_length,
            "smoothed": self.smoothed,
            "steps": self.steps,
        }

    def _load_extra_state(self, extra: dict[str, Any]) -> None:
        self.lesson = int(extra["lesson"])
        self.lesson_length = int(extra["lesson_length"])
        self.smoothed = float(extra["smoothed"])
        self.steps = int(extra["steps"])
