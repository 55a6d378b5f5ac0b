"""What a curriculum needs to know about an environment, declared by the environment itself.

Teachers never name environments. Each environment declares a `CurriculumProfile` next to its
task space (`env.unwrapped.curriculum_profile`), and the training loop hands it to the
`TeacherController`, which reads the reward bounds, the success return, the ADR thresholds,
the expert-knowledge initial distribution and the test sets from it. An environment without a profile gets
`CurriculumProfile()`: generic bounds, no prior, uniform test sets.

This module sits next to `acl3d.task_space` (below terrain, teachers and envs) so that both the
environments that declare profiles and the teachers that read them can import it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from acl3d import validation
from acl3d.task_space import TaskSpace

# space -> {"mean": (d,), "variance": (d, d)} or None (no prior for this space)
InitialDist = Callable[[TaskSpace], "dict[str, np.ndarray] | None"]
# (space, nb_tasks) -> (nb_tasks, d) tasks
TestSetBuilder = Callable[[TaskSpace, int], np.ndarray]


def _pair(name: str, value, strictly_increasing: bool) -> tuple[float, float]:
    if not isinstance(value, (tuple, list, np.ndarray)) or len(value) != 2:
        raise validation.fail(name, value, "a pair (lower, upper) of finite numbers")
    lo, hi = validation.real(f"{name}[0]", value[0]), validation.real(f"{name}[1]", value[1])
    if hi < lo or (strictly_increasing and hi == lo):
        relation = "<" if strictly_increasing else "<="
        raise validation.fail(name, value, f"a pair (lower, upper) with lower {relation} upper")
    return lo, hi


@dataclass(frozen=True, eq=False)
class CurriculumProfile:
    """The curriculum facts of one environment (all optional; defaults suit an unknown env).

    Attributes:
        name: the environment's short name, recorded in teacher dumps (None: unnamed).
        reward_bounds: returns are mapped linearly from these bounds to [0, 1] (and clamped)
            when the controller scales rewards.
        success_return: an episode succeeds when its return is above this (TeachMyAgent's 230);
            also the mean return that moves the Oracle's window on.
        adr_reward_thresholds: the returns below / above which ADR shrinks / expands its box.
        initial_dist: the easy-task Gaussian given to teachers at expert knowledge "high".
        test_sets: named test sets ("walking", ...), selectable with `test_set="walking"`.
        default_test_grid: {parameter: (min, max)}; when the task space has exactly these
            parameters, the default test set is the regular grid over these ranges (TeachMyAgent's
            fixed Stump Tracks set); otherwise the default is uniform in the bounds.
        easy_at_high: the parameters whose easy end is their upper bound (Stump Tracks'
            obstacle_spacing: wide gaps are easy); every other parameter is easiest at its lower
            bound. Where a curriculum starts and which way it walks (the Oracle's window, ADR's
            first box, GoalGAN's first goals) follows from it.
    """

    name: str | None = None
    reward_bounds: tuple[float, float] = (-100.0, 100.0)
    success_return: float = 230.0
    adr_reward_thresholds: tuple[float, float] = (0.0, 180.0)
    initial_dist: InitialDist | None = None
    test_sets: Mapping[str, TestSetBuilder] = field(default_factory=dict)
    default_test_grid: Mapping[str, tuple[float, float]] | None = None
    easy_at_high: frozenset[str] = frozenset()

    def __post_init__(self):
        if self.name is not None and not isinstance(self.name, str):
            raise validation.fail("name", self.name, "a string or None")
        set_ = object.__setattr__
        set_(self, "reward_bounds", _pair("reward_bounds", self.reward_bounds, True))
        set_(self, "success_return", validation.real("success_return", self.success_return))
        thresholds = _pair("adr_reward_thresholds", self.adr_reward_thresholds, False)
        set_(self, "adr_reward_thresholds", thresholds)
        if self.initial_dist is not None and not callable(self.initial_dist):
            raise validation.fail("initial_dist", self.initial_dist, "a callable or None")
        sets = self.test_sets
        if not isinstance(sets, Mapping) or not all(
            isinstance(k, str) and callable(v) for k, v in sets.items()
        ):
            raise validation.fail("test_sets", sets, "a mapping of names (str) to builders")
        set_(self, "test_sets", dict(sets))  # a copy: the caller's dict may change
        if self.default_test_grid is not None:
            if not isinstance(self.default_test_grid, Mapping):
                raise validation.fail(
                    "default_test_grid", self.default_test_grid, "None or {parameter: (min, max)}"
                )
            grid = {
                str(k): _pair(f"default_test_grid[{k!r}]", v, True)
                for k, v in dict(self.default_test_grid).items()
            }
            set_(self, "default_test_grid", grid)
        names = self.easy_at_high
        if isinstance(names, str) or not all(isinstance(n, str) for n in names):
            raise validation.fail("easy_at_high", names, "a collection of parameter names")
        set_(self, "easy_at_high", frozenset(names))

    def easy_directions(self, task_space) -> np.ndarray:
        """(d,) +1 where a dimension gets harder upwards, -1 where it gets harder downwards."""
        return easy_directions(task_space, self.easy_at_high)

    def easy_task(self, task_space) -> np.ndarray:
        """The easiest task of `task_space`: every dimension at its easy bound."""
        return easy_task(task_space, self.easy_at_high)

    def initial_distribution(self, task_space) -> dict[str, np.ndarray] | None:
        """The easy-task Gaussian for `task_space`, or None when the environment gives none."""
        if self.initial_dist is None:
            return None
        return self.initial_dist(TaskSpace.coerce(task_space))

    def scale(self, episode_return: float) -> float:
        """`episode_return` mapped linearly from `reward_bounds` to [0, 1], clamped."""
        lb, ub = self.reward_bounds
        return float(np.clip((episode_return - lb) / (ub - lb), 0.0, 1.0))


def easy_directions(task_space, easy_at_high=frozenset()) -> np.ndarray:
    """(d,) +1 for the dimensions easiest at their lower bound, -1 for those of the parameters
    named in `easy_at_high` (names the space lacks are ignored: a profile serves many spaces)."""
    space = TaskSpace.coerce(task_space)
    if isinstance(easy_at_high, str) or not all(isinstance(n, str) for n in easy_at_high):
        raise validation.fail("easy_at_high", easy_at_high, "a collection of parameter names")
    directions = np.ones(space.dim)
    for name in set(easy_at_high) & set(space.names):
        directions[space.slice(name)] = -1.0
    return directions


def easy_task(task_space, easy_at_high=frozenset()) -> np.ndarray:
    """The easiest task of `task_space`: every dimension at its easy bound."""
    space = TaskSpace.coerce(task_space)
    return np.where(easy_directions(space, easy_at_high) > 0, space.low, space.high)
