"""The training loop's single entry point to a curriculum (TeachMyAgent's TeacherController).

It builds the teacher with the expert knowledge of the chosen level, optionally shuffles the task
dimensions, scales returns, owns the test set, and records every task and outcome for the run's
dump and for exact resumption. Tasks exchanged with the caller are always in *environment* space;
the teacher works in its own space, which differs only when dimensions are shuffled.

Differences from TeachMyAgent's controller (why):
* The dimension shuffler is inverted on the played task to find the teacher's task, instead of
  remembering the "last raw task": with several environments in flight the last sampled task is
  usually not the one that just finished.
* Dumps and checkpoints are JSON + NPZ (no pickle) and include the scaled-reward bounds and the
  teacher state, so a run resumes exactly.
* Inputs are validated before anything is recorded: a bad call changes nothing.
"""

from __future__ import annotations

import inspect
import math
from pathlib import Path
from typing import Any

import numpy as np

from acl3d.task_space import TaskSpace
from acl3d.teachers import make
from acl3d.teachers import test_sets as test_sets_mod
from acl3d.teachers.base import load_state, save_state
from acl3d.teachers.expert_knowledge import canonical_env_name
from acl3d.teachers.expert_knowledge import expert_knowledge as expert_kwargs

# Returns are mapped linearly from these bounds to [0, 1] (and clamped) when scale_reward is on.
REWARD_BOUNDS = {
    "stump-tracks": (-150.0, 350.0),
    "hexagon-tracks": (-150.0, 350.0),
    "parkour": (-150.0, 360.0),
}
DEFAULT_REWARD_BOUNDS = (-100.0, 100.0)
NB_PERIODICAL_SAMPLES = 100
_SNAP = 1e-6  # in interval widths: values this close to an interval's end belong to the next one


class DimensionsShuffler:
    """A per-dimension piecewise-translation bijection of the task box.

    Each dimension is cut into `cuttings` equal intervals, which are permuted (one seeded
    permutation per dimension); a value keeps its offset inside its interval. Intervals are
    half-open [a, b) and the upper bound maps to itself, which makes the map a bijection of the
    closed box. Values within 1e-6 interval widths of an interval's end are snapped to the next
    interval's start, so float32 round trips never jump a whole interval. Inputs outside the
    bounds are clipped; constant dimensions are left unchanged.
    """

    def __init__(self, low, high, cuttings: int = 4, seed: int | None = None):
        self.low = np.asarray(low, dtype=np.float64).reshape(-1)
        self.high = np.asarray(high, dtype=np.float64).reshape(-1)
        if self.low.shape != self.high.shape or np.any(self.low > self.high):
            raise ValueError(
                f"DimensionsShuffler: low {self.low} and high {self.high} must have the same shape and low <= high"
            )
        if not isinstance(cuttings, (int, np.integer)) or cuttings < 1:
            raise ValueError(f"cuttings must be an integer >= 1, got {cuttings!r}")
        self.cuttings = int(cuttings)
        rng = np.random.default_rng(seed)
        self.perms = (
            np.stack([rng.permutation(self.cuttings) for _ in range(len(self.low))])
            if len(self.low)
            else np.zeros((0, self.cuttings), dtype=np.int64)
        )
        self.inverse_perms = np.argsort(self.perms, axis=1)
        self.width = (self.high - self.low) / self.cuttings

    def _apply(self, x, table: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if x.shape[-1:] != self.low.shape:
            raise ValueError(
                f"DimensionsShuffler: expected vectors of {len(self.low)} values, got shape {x.shape}"
            )
        active = self.width > 0
        u = np.clip(
            np.divide(x - self.low, self.width, out=np.zeros_like(x), where=active),
            0,
            self.cuttings,
        )
        i = np.floor(u)
        frac = u - i
        snap = frac > 1 - _SNAP
        i, frac = np.where(snap, i + 1, i), np.where(snap, 0.0, frac)
        top = i >= self.cuttings
        idx = np.minimum(i, self.cuttings - 1).astype(np.int64)
        mapped = np.take_along_axis(
            np.broadcast_to(table, idx.shape[:-1] + table.shape), idx[..., None], -1
        )[..., 0]
        out_u = np.where(top, self.cuttings, mapped + frac)
        return np.where(active, self.low + out_u * self.width, x)

    def forward(self, x) -> np.ndarray:
        """Teacher space -> environment space."""
        return self._apply(x, self.perms)

    def inverse(self, y) -> np.ndarray:
        """Environment space -> teacher space."""
        return self._apply(y, self.inverse_perms)


def _finite(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a finite number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name}: expected a finite number, got {value!r}")
    return v


def _length(value) -> int:
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, np.integer, float, np.floating))
        or not float(value).is_integer()
        or value < 0
    ):
        raise ValueError(f"length: expected a non-negative integer number of steps, got {value!r}")
    return int(value)


def _success(value) -> bool:
    if isinstance(value, (bool, np.bool_)) or (
        isinstance(value, (int, np.integer)) and value in (0, 1)
    ):
        return bool(value)
    raise ValueError(f"success: expected a bool, got {value!r}")


class TeacherController:
    """Wires a teacher to the training loop (see the module docstring)."""

    def __init__(
        self,
        teacher: str,
        task_space,
        seed: int,
        *,
        teacher_params: dict | None = None,
        expert_knowledge: str = "low",
        env_name: str | None = None,
        scale_reward: bool = False,
        reward_bounds: tuple[float, float] | None = None,
        shuffle_dimensions: bool = False,
        test_set=None,
        nb_test_episodes: int = 100,
        keep_periodical_task_samples: int = 0,
    ):
        self.task_space = TaskSpace.coerce(task_space)
        if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
            raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
        self.seed = int(seed)
        self.env_name = canonical_env_name(env_name)
        self.teacher_name = teacher
        self.expert_knowledge = expert_knowledge
        self.scale_reward = bool(scale_reward)
        lb, ub = (
            reward_bounds
            if reward_bounds is not None
            else REWARD_BOUNDS.get(self.env_name, DEFAULT_REWARD_BOUNDS)
        )
        lb, ub = _finite("reward_bounds[0]", lb), _finite("reward_bounds[1]", ub)
        if not lb < ub:
            raise ValueError(f"reward_bounds must satisfy lower < upper, got ({lb}, {ub})")
        self.reward_bounds = (lb, ub)
        if (
            not isinstance(keep_periodical_task_samples, (int, np.integer))
            or keep_periodical_task_samples < 0
        ):
            raise ValueError(
                f"keep_periodical_task_samples must be an integer >= 0 (steps; 0 = off), got {keep_periodical_task_samples!r}"
            )
        self.keep_periodical_task_samples = int(keep_periodical_task_samples)
        if not isinstance(nb_test_episodes, (int, np.integer)) or nb_test_episodes < 1:
            raise ValueError(f"nb_test_episodes must be an integer >= 1, got {nb_test_episodes!r}")

        low, high = self.task_space.low, self.task_space.high
        self.shuffler = (
            DimensionsShuffler(low, high, cuttings=4, seed=self.seed)
            if shuffle_dimensions
            else None
        )
        params = dict(expert_kwargs(env_name, self.task_space, expert_knowledge).get(teacher, {}))
        params.update(teacher_params or {})
        params = self._to_teacher_space(teacher, params)
        self.teacher = make(teacher, self.task_space, seed=self.seed, **params)
        self._step_stream = "stream" in inspect.signature(self.teacher.step_update).parameters

        self._test_tasks = test_sets_mod.resolve(
            test_set, self.task_space, int(nb_test_episodes)
        ).astype(np.float32)
        self.nb_test_episodes = len(self._test_tasks)
        self._records: dict[str, list] = {k: [] for k in _RECORD_KEYS}
        self._next_periodic = self.keep_periodical_task_samples

    def _to_teacher_space(self, teacher: str, params: dict) -> dict:
        """Move distribution means into the teacher's (unshuffled) space, thresholds into [0, 1]."""
        for key in ("initial_dist", "target_dist"):
            dist = params.get(key)
            if dist is not None and self.shuffler is not None:
                mean = np.asarray(dist["mean"], dtype=np.float64)
                params[key] = {**dist, "mean": self.shuffler.inverse(mean)}
        if self.scale_reward and teacher == "adr":
            for key in ("min_reward_thr", "max_reward_thr"):
                if key in params:
                    params[key] = self.scale(params[key])
        return params

    # ------------------------------------------------------------------ properties
    @property
    def needs(self) -> frozenset[str]:
        return self.teacher.needs

    def set_value_estimator(self, fn) -> None:
        self.teacher.set_value_estimator(fn)

    def scale(self, episode_return: float) -> float:
        lb, ub = self.reward_bounds
        return float(np.clip((episode_return - lb) / (ub - lb), 0.0, 1.0))

    # ------------------------------------------------------------------ training
    def sample_task(self) -> np.ndarray:
        """The next training task (float32, environment space)."""
        task = self.teacher.sample_task()
        if self.shuffler is not None:
            task = self.shuffler.forward(task)
        task = np.asarray(task, dtype=np.float32)
        self._records["sampled_tasks"].append(task)
        return task

    def record_step(self, state, action, reward, next_state, done, worker: int = 0) -> None:
        """One environment step, for teachers whose `needs` include "step_rewards".

        `worker` identifies the environment when several run interleaved (SPDL keeps one
        discounted return per worker)."""
        if "step_rewards" not in self.needs:
            return
        reward = _finite("reward", reward)
        if self._step_stream:
            self.teacher.step_update(state, action, reward, next_state, bool(done), stream=worker)
        else:
            self.teacher.step_update(state, action, reward, next_state, bool(done))

    def record_episode(self, env_task, episode_return, length, success, initial_obs=None) -> None:
        """A finished training episode on `env_task` (as returned by `sample_task`)."""
        env_task = self._check_env_task(env_task)
        ret = _finite("episode_return", episode_return)
        length = _length(length)
        success = _success(success)
        if initial_obs is not None:
            initial_obs = np.asarray(initial_obs, dtype=np.float32)
            if not np.all(np.isfinite(initial_obs)):
                raise ValueError("initial_obs: contains non-finite values")
        task = self.shuffler.inverse(env_task) if self.shuffler is not None else env_task
        reward = self.scale(ret) if self.scale_reward else ret
        if initial_obs is not None:
            self.teacher.record_initial_state(task, initial_obs)
        self.teacher.episodic_update(task, reward, success)
        r = self._records
        r["train_tasks"].append(env_task.astype(np.float32))
        r["train_returns"].append(ret)
        r["train_lengths"].append(length)
        r["train_success"].append(success)

    def maybe_sample_periodically(self, total_steps: int) -> np.ndarray | None:
        """Every `keep_periodical_task_samples` steps, keep 100 non-exploratory task samples
        (environment space) to show how the curriculum moves; returns them when taken."""
        if self.keep_periodical_task_samples <= 0 or total_steps < self._next_periodic:
            return None
        k = self.keep_periodical_task_samples
        self._next_periodic = (int(total_steps) // k + 1) * k
        if self.teacher.is_non_exploratory_task_sampling_available():
            tasks = np.stack(
                [
                    self.teacher.non_exploratory_task_sampling()["task"]
                    for _ in range(NB_PERIODICAL_SAMPLES)
                ]
            )
            if self.shuffler is not None:
                tasks = self.shuffler.forward(tasks)
        else:
            tasks = np.zeros((0, self.task_space.dim))
        tasks = tasks.astype(np.float32)
        self._records["periodical_samples"].append(tasks)
        self._records["periodical_steps"].append(int(total_steps))
        return tasks

    # ------------------------------------------------------------------ evaluation
    def test_tasks(self) -> np.ndarray:
        """The test set, (N, d) float32 in environment space."""
        return self._test_tasks.copy()

    def record_test_episode(self, env_task, episode_return, length, success=False) -> None:
        env_task = self._check_env_task(env_task)
        ret, length, success = (
            _finite("episode_return", episode_return),
            _length(length),
            _success(success),
        )
        r = self._records
        r["test_played_tasks"].append(env_task.astype(np.float32))
        r["test_returns"].append(ret)
        r["test_lengths"].append(length)
        r["test_success"].append(success)

    def _check_env_task(self, env_task) -> np.ndarray:
        try:
            return self.task_space.validate_vector(np.asarray(env_task, dtype=np.float64))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"env_task: {exc}") from None

    # ------------------------------------------------------------------ outputs
    def _record_arrays(self) -> dict[str, Any]:
        d = self.task_space.dim
        r = self._records
        out = {}
        for key in _RECORD_KEYS:
            if key.endswith("tasks"):
                out[key] = np.array(r[key], dtype=np.float32).reshape(-1, d)
            elif key.endswith("returns"):
                out[key] = np.array(r[key], dtype=np.float64)
            elif key.endswith("lengths") or key == "periodical_steps":
                out[key] = np.array(r[key], dtype=np.int64)
            elif key.endswith("success"):
                out[key] = np.array(r[key], dtype=bool)
        out["periodical_samples"] = [
            np.asarray(s, dtype=np.float32) for s in r["periodical_samples"]
        ]
        return out

    def dump(self, path_prefix) -> None:
        """Write PREFIX.json (metadata, teacher book-keeping) + PREFIX.npz (arrays); no pickle."""
        tree = {
            "format": "acl3d-teacher-dump-1",
            "teacher": self.teacher_name,
            "env_name": self.env_name,
            "expert_knowledge": self.expert_knowledge,
            "names": self.task_space.flat_names(),
            "bounds": self.task_space.bounds_dict(),
            "low": self.task_space.low,
            "high": self.task_space.high,
            "scale_reward": self.scale_reward,
            "reward_bounds": list(self.reward_bounds),
            "shuffled": self.shuffler is not None,
            "test_tasks": self._test_tasks,
            **self._record_arrays(),
            "teacher_bk": self.teacher.dump(),
        }
        save_state(Path(path_prefix), tree)

    def state_dict(self) -> dict[str, Any]:
        return {
            "teacher_name": self.teacher_name,
            "dim": self.task_space.dim,
            "teacher": self.teacher.state_dict(),
            "records": self._record_arrays(),
            "next_periodic": self._next_periodic,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if (
            state.get("teacher_name") != self.teacher_name
            or int(state.get("dim", -1)) != self.task_space.dim
        ):
            raise ValueError(
                f"controller state is for teacher {state.get('teacher_name')!r} in {state.get('dim')} dimensions, not {self.teacher_name!r} in {self.task_space.dim}"
            )
        self.teacher.load_state_dict(state["teacher"])
        rec = state["records"]
        self._records = {k: [] for k in _RECORD_KEYS}
        for key in _RECORD_KEYS:
            values = rec[key]
            if key == "periodical_samples":
                self._records[key] = [np.asarray(v, dtype=np.float32) for v in values]
            elif key.endswith("tasks"):
                self._records[key] = list(
                    np.asarray(values, dtype=np.float32).reshape(-1, self.task_space.dim)
                )
            else:
                self._records[key] = np.asarray(values).tolist()
        self._next_periodic = int(state["next_periodic"])

    def save(self, path) -> None:
        save_state(Path(path), self.state_dict())

    def load(self, path) -> None:
        self.load_state_dict(load_state(Path(path)))


_RECORD_KEYS = (
    "sampled_tasks",
    "train_tasks",
    "train_returns",
    "train_lengths",
    "train_success",
    "test_played_tasks",
    "test_returns",
    "test_lengths",
    "test_success",
    "periodical_samples",
    "periodical_steps",
)
