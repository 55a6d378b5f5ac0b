"""The teacher interface shared by every curriculum algorithm (TeachMyAgent's AbstractTeacher).

A teacher proposes tasks (flat float32 vectors in task-space units) and learns from the outcome
of the episodes played on them. Every random draw comes from the teacher's own seeded generator,
and `state_dict()` captures everything needed to resume exactly. Input checks run before any
state changes, so a bad call never corrupts what the teacher learned.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections import defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from acl3d import validation
from acl3d.curriculum_profile import CurriculumProfile
from acl3d.task_space import TaskSpace
from acl3d.teachers.state_files import load_state, save_state
from acl3d.teachers.step_streams import MAX_STREAMS, check_streams

# Sanity limits on what teachers are told: a reported task may lie outside the bounds (float
# rounding, a shuffler's inverse map) but not by more than this many ranges of each dimension, and
# no return is larger than this (beyond, squares in the mixture fits overflow).
SANE_TASK_MARGIN = 10.0
MAX_ABS_RETURN = 1e12

ValueEstimator = Callable[[np.ndarray], np.ndarray | None]
# the states of several episodes -> each one's values, as a `ValueEstimator` gives them
EpisodeValues = Callable[[list[np.ndarray]], list[np.ndarray | None]]


def _no_value(states: np.ndarray) -> None:
    return None


@dataclass(frozen=True)
class RunFacts:
    """What the training loop knows that a teacher may take as constructor arguments."""

    profile: CurriculumProfile = field(default_factory=CurriculumProfile)
    initial_dist: dict | None = None  # the easy-task prior, given at expert knowledge "high"
    total_steps: int | None = None  # the run's budget in environment steps


class Teacher(ABC):
    """Base class of all teachers: what a teacher must and may do is declared here, and the
    training loop reads these declarations (it never inspects a teacher's methods or name).

    Must implement `_sample()`. May implement `_sample_batch` / `_update_batch` /
    `_step_updates` (the batched calls; by default a loop over `_sample` / `_episodic_update` /
    `_step_update`), `_episodic_update`, `_step_update` (called only with "step_rewards" in
    `needs`), `_record_initial_state` ("initial_states"), `_is_exploratory` (with
    `marks_exploratory`), `_non_exploratory_sample`, `_extra_state` / `_load_extra_state`
    (exact resume) and `plot_state`. The public methods
    check their inputs before calling these, so a bad call changes nothing.

    Class attributes:
      name: registry name (`acl3d.teachers.make(name, ...)`; `acl3d.teachers.register(cls)`).
      needs: what the teacher consumes beyond episodic returns, among
        {"success", "step_rewards", "initial_states", "value_estimator"}; the training loop uses it
        to wire the right data and to refuse incompatible students early.
      marks_exploratory: `is_exploratory(task)` may say True for a proposed task (a new or edited
        level whose episode must not train the student: Robust PLR, ACCEL).
      uses_initial_dist: the constructor takes `initial_dist` (expert knowledge "high").
      return_params: constructor parameters in return units, scaled with the returns when the
        controller scales them (ADR's and the Oracle's thresholds).
    """

    name: ClassVar[str] = "abstract"
    needs: ClassVar[frozenset[str]] = frozenset()
    marks_exploratory: ClassVar[bool] = False
    uses_initial_dist: ClassVar[bool] = False
    return_params: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def run_params(cls, facts: RunFacts) -> dict[str, Any]:
        """Constructor arguments this teacher takes from the run: `initial_dist` when it uses
        one and the run has one. Override to take more (call super())."""
        if cls.uses_initial_dist and facts.initial_dist is not None:
            return {"initial_dist": facts.initial_dist}
        return {}

    @classmethod
    def toy_params(cls, facts: RunFacts) -> dict[str, Any]:
        """Constructor arguments this teacher needs on a toy problem (`acl3d.toy`: one-step
        episodes, returns in [0, 1], 0 where nothing can be learned; its facts in
        `facts.profile`), beyond what `run_params` gives every run. Override where needed."""
        return {}

    @classmethod
    def plot_history(cls, bk: dict, low: np.ndarray, high: np.ndarray, steps: np.ndarray):
        """[(episodes seen, plot_state dict)] in time order, rebuilt from a dumped book-keeping
        `bk` (`dump()`) over the task box [low, high]; `steps`: the environment step at which
        each episode ended. [] for a teacher that keeps no such history (see
        `acl3d.teachers.histories`)."""
        return []

    def __init__(self, task_space, seed: int | None = None):
        self.task_space = TaskSpace.coerce(task_space)
        self.mins = self.task_space.low
        self.maxs = self.task_space.high
        self.dim = self.task_space.dim
        seed = validation.seed(seed)
        if seed is None:
            seed = int(np.random.SeedSequence().entropy % (2**31))
        self.seed = seed
        self.rng = np.random.default_rng(self.seed)
        self.value_estimator: ValueEstimator = _no_value
        self.episode_values: EpisodeValues = self._each_episode
        self.bk: dict[str, list] = defaultdict(list)
        self.nb_episodes = 0

    # ------------------------------------------------------------------ public API
    def sample_task(self) -> np.ndarray:
        """Propose the next task (float32 vector of length `dim`)."""
        task = np.asarray(self._sample(), dtype=np.float32).reshape(self.dim)
        return task

    def episodic_update(self, task, reward: float, is_success: bool = False) -> None:
        """Learn from one finished episode played on `task` with return `reward`."""
        task = self._check_task(task)
        reward = self._check_scalar("reward", reward)
        is_success = validation.flag("is_success", is_success)
        self._episodic_update(task, reward, is_success)
        self.nb_episodes += 1

    def sample_tasks(self, n: int) -> np.ndarray:
        """Propose `n` tasks at once ((n, dim) float32): what a vector of worlds resetting
        together asks for. Reproducible from the seed; with n = 1 the same draw as
        `sample_task()`, with n > 1 not necessarily the same as n single calls (a vectorised
        teacher draws each quantity for the whole batch)."""
        n = validation.count("n", n, minimum=0)
        if n == 0:
            return np.zeros((0, self.dim), dtype=np.float32)
        if n == 1:  # `_sample`'s draw, so a run matches the one-task API
            return self.sample_task()[None]
        return np.asarray(self._sample_batch(n), dtype=np.float32).reshape(n, self.dim)

    def update_batch(self, tasks, returns, successes=None) -> None:
        """Learn from M finished episodes at once: (M, dim) tasks, (M,) returns, (M,) success
        flags (None: none succeeded), in the order they finished. The whole batch is checked
        before the teacher changes; the result equals M `episodic_update` calls in that order."""
        tasks = validation.real_array("tasks", tasks)
        if tasks.ndim != 2 or tasks.shape[1] != self.dim:
            raise validation.fail("tasks", tasks.shape, f"an (M, {self.dim}) array")
        self._check_sane("tasks", tasks)
        m = len(tasks)
        returns = validation.real_array("returns", returns, shape=(m,))
        if np.any(np.abs(returns) > MAX_ABS_RETURN):
            raise validation.fail("returns", returns, f"values within +-{MAX_ABS_RETURN:g}")
        successes = np.zeros(m, bool) if successes is None else np.asarray(successes)
        if successes.shape != (m,) or successes.dtype.kind not in "bi" or np.any(successes > 1):
            raise validation.fail("successes", successes, f"({m},) bools")
        self._update_batch(tasks, returns, successes.astype(bool))

    def step_update(self, state, action, reward, next_state, done, stream: int = 0) -> None:
        """One environment step of the episode running on `stream` (an env index: episodes of
        several envs interleave). Only teachers with "step_rewards" in `needs` use it."""
        reward = self._check_scalar("reward", reward)
        stream = validation.integer("stream", stream, 0, MAX_STREAMS - 1)
        if "step_rewards" in self.needs:
            self._step_update(state, action, reward, next_state, bool(done), stream)

    def step_updates(self, states, actions, rewards, next_states, dones, streams=None) -> None:
        """N steps taken together, one per stream (`streams`: distinct env indices; None:
        0 .. N-1), as N `step_update` calls in that order would give: what a vector of envs
        steps at once. Checked whole before the teacher changes."""
        rewards = validation.real_array("rewards", rewards)
        n = rewards.size
        if rewards.shape != (n,) or np.any(np.abs(rewards) > MAX_ABS_RETURN):
            raise validation.fail("rewards", rewards, f"(N,) values within +-{MAX_ABS_RETURN:g}")
        dones = np.asarray(dones)
        if (
            dones.shape != (n,)
            or dones.dtype.kind not in "bi"
            or np.any((dones != 0) & (dones != 1))
        ):
            raise validation.fail("dones", dones, f"({n},) bools")
        streams = check_streams(streams, n)
        if "step_rewards" in self.needs:
            self._step_updates(states, actions, rewards, next_states, dones.astype(bool), streams)

    def is_exploratory(self, task) -> bool:
        """Whether the episode of `task` (proposed, not yet reported) must not train the
        student; always False unless the teacher `marks_exploratory`."""
        task = self._check_task(task)
        return self.marks_exploratory and bool(self._is_exploratory(task))

    def record_initial_state(self, task, state) -> None:
        """First observation of the episode that runs `task` (only SPDL uses it)."""
        if "initial_states" in self.needs:
            task = self._check_task(task)
            self._record_initial_state(task, np.asarray(state, dtype=np.float32))

    def set_value_estimator(self, fn: ValueEstimator, episodes: EpisodeValues | None = None):
        """The student's value function (a batch of states -> values) and `episodes`, the
        values of a list of episodes' states in one call (one trip to a GPU; default: `fn` on
        each episode)."""
        self.value_estimator = fn
        self.episode_values = self._each_episode if episodes is None else episodes

    def _each_episode(self, states: list[np.ndarray]) -> list[np.ndarray | None]:
        return [self.value_estimator(s) for s in states]

    def non_exploratory_task_sampling(self) -> dict[str, Any]:
        """A task from the teacher's current distribution without exploration noise (for plots)."""
        task = np.asarray(self._non_exploratory_sample(), dtype=np.float32).reshape(self.dim)
        return {
            "task": task,
            "infos": {"bk_index": len(self.bk.get("episodes", [])), "task_infos": None},
        }

    def is_non_exploratory_task_sampling_available(self) -> bool:
        return True

    def non_exploratory_samples(self, n: int, seed: int) -> np.ndarray:
        """`n` tasks ((n, dim) float32) as `non_exploratory_task_sampling` draws them, but from
        random streams seeded with `seed` instead of the teacher's own: showing the curriculum
        (a run's periodical samples) never changes what the teacher proposes next."""
        n = validation.count("n", n)
        with self._own_streams(validation.integer("seed", seed, 0)):
            return np.stack([self.non_exploratory_task_sampling()["task"] for _ in range(n)])

    @contextmanager
    def _own_streams(self, seed: int) -> Iterator[None]:
        """The teacher's random streams swapped for ones seeded with `seed`, then given back. A
        teacher that draws from another stream besides `self.rng` extends this."""
        saved, self.rng = self.rng, np.random.default_rng(seed)
        try:
            yield
        finally:
            self.rng = saved

    def plot_state(self) -> dict[str, Any] | None:
        """The current distribution for plots (`acl3d.teachers.plots`); None: tasks only."""
        return None

    def dump(self) -> dict[str, list]:
        """The teacher's book-keeping (merged into the run's teacher dump)."""
        return dict(self.bk)

    # ------------------------------------------------------------------ checkpointing
    def state_dict(self) -> dict[str, Any]:
        """Everything needed to resume exactly; values are JSON scalars/lists/dicts or numpy arrays."""
        return {
            "name": self.name,
            "seed": self.seed,
            "rng": self.rng.bit_generator.state,
            "nb_episodes": self.nb_episodes,
            "bk": {k: list(v) for k, v in self.bk.items()},
            "extra": self._extra_state(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state.get("name") != self.name:
            raise ValueError(f"state_dict is for teacher {state.get('name')!r}, not {self.name!r}")
        self.seed = int(state["seed"])
        self.rng.bit_generator.state = state["rng"]
        self.nb_episodes = int(state["nb_episodes"])
        self.bk = defaultdict(list, {k: list(v) for k, v in state["bk"].items()})
        self._load_extra_state(state["extra"])

    def save(self, path) -> None:
        """Write `state_dict()` as PATH.json + PATH.npz (open formats, no pickle)."""
        save_state(path, self.state_dict())

    def load(self, path) -> None:
        self.load_state_dict(load_state(path))

    # ------------------------------------------------------------------ for subclasses
    @abstractmethod
    def _sample(self) -> np.ndarray: ...

    def _episodic_update(self, task: np.ndarray, reward: float, is_success: bool) -> None:
        pass

    def _sample_batch(self, n: int) -> np.ndarray:
        """(n >= 2, dim) tasks; override where the draws vectorise."""
        return np.stack([np.asarray(self._sample()).reshape(self.dim) for _ in range(n)])

    def _update_batch(self, tasks: np.ndarray, returns: np.ndarray, successes: np.ndarray):
        """Checked episodes in order; a loop, as most teachers' updates depend on the order
        (a nearest neighbour, a region split, a buffer). Override where they do not."""
        for task, ret, success in zip(tasks, returns, successes):
            self._episodic_update(task, float(ret), bool(success))
            self.nb_episodes += 1

    def _step_update(
        self, state, action, reward: float, next_state, done: bool, stream: int
    ) -> None:
        pass

    def _step_updates(self, states, actions, rewards, next_states, dones, streams) -> None:
        """Checked steps (rewards, dones and streams as arrays); a loop over `_step_update`.
        Override where the steps vectorise."""

        def row(values, k: int):
            return None if values is None else values[k]

        for k, stream in enumerate(streams.tolist()):
            state, action, next_state = row(states, k), row(actions, k), row(next_states, k)
            self._step_update(state, action, float(rewards[k]), next_state, bool(dones[k]), stream)

    def _is_exploratory(self, task: np.ndarray) -> bool:
        return False

    def _record_initial_state(self, task: np.ndarray, state: np.ndarray) -> None:
        pass

    def _non_exploratory_sample(self) -> np.ndarray:
        return self._sample()

    def _extra_state(self) -> dict[str, Any]:
        return {}

    def _load_extra_state(self, extra: dict[str, Any]) -> None:
        pass

    # ------------------------------------------------------------------ helpers
    def uniform_task(self) -> np.ndarray:
        """A uniform draw in the bounds (degenerate dimensions give their single value)."""
        return self.rng.uniform(self.mins, self.maxs)

    def clip(self, task) -> np.ndarray:
        return np.clip(task, self.mins, self.maxs)

    def rescale(self, unit_task) -> np.ndarray:
        """[0, 1]^d -> task space."""
        return self.mins + np.asarray(unit_task) * (self.maxs - self.mins)

    def normalise(self, task) -> np.ndarray:
        """Task space -> [0, 1]^d (degenerate dimensions map to 0)."""
        span = self.maxs - self.mins
        return np.divide(np.asarray(task) - self.mins, span, out=np.zeros(self.dim), where=span > 0)

    def _check_task(self, task) -> np.ndarray:
        """A finite task of the right length, within SANE_TASK_MARGIN ranges of the bounds."""
        arr = validation.real_array("task", task, shape=(self.dim,))
        self._check_sane("task", arr)
        return arr

    def _check_sane(self, name: str, arr: np.ndarray) -> None:
        """Task(s) `arr` (last axis: dim) within SANE_TASK_MARGIN ranges of the bounds."""
        margin = SANE_TASK_MARGIN * np.maximum(self.maxs - self.mins, 1.0)
        if np.any(arr < self.mins - margin) or np.any(arr > self.maxs + margin):
            raise validation.fail(
                name,
                arr.tolist(),
                f"{self.dim} values for {list(self.task_space.names)} within"
                f" {SANE_TASK_MARGIN:g} ranges of the bounds {self.mins.tolist()} .. {self.maxs.tolist()}",
            )

    @staticmethod
    def _check_scalar(what: str, value) -> float:
        """A finite real number of sane size (returns beyond ±MAX_ABS_RETURN are corrupt data)."""
        return validation.real(what, value, -MAX_ABS_RETURN, MAX_ABS_RETURN)
