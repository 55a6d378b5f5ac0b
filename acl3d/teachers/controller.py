"""The training loop's single entry point to a curriculum (TeachMyAgent's TeacherController).

It builds the teacher with the expert knowledge of the chosen level, optionally shuffles the task
dimensions, scales returns, owns the test set, and records every task and outcome for the run's
dump and for exact resumption. Everything it knows about the environment (reward bounds, ADR
thresholds, initial distribution, named and default test sets) comes from the environment's
`CurriculumProfile`; no environment is named here. Tasks exchanged with the caller are always in *environment* space;
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

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from acl3d import validation
from acl3d.curriculum_profile import CurriculumProfile
from acl3d.task_space import TaskSpace
from acl3d.teachers import make, teacher_class
from acl3d.teachers import test_sets as test_sets_mod
from acl3d.teachers.dimensions_shuffler import DimensionsShuffler
from acl3d.teachers.expert_knowledge import teacher_params as expert_params
from acl3d.teachers.state_files import load_state, save_state

NB_PERIODICAL_SAMPLES = 100


def _length(value) -> int:
    return validation.integer("length", value, 0, allow_float=True)


def _finite_obs(obs: np.ndarray) -> np.ndarray:
    if not np.all(np.isfinite(obs)):
        raise ValueError("initial_obs: contains non-finite values")
    return obs


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
        profile: CurriculumProfile | None = None,
        scale_reward: bool = False,
        reward_bounds: tuple[float, float] | None = None,
        shuffle_dimensions: bool = False,
        test_set=None,
        nb_test_episodes: int = 100,
        keep_periodical_task_samples: int = 0,
        total_steps: int | None = None,
    ):
        self.task_space = TaskSpace.coerce(task_space)
        self.seed = validation.integer("seed", seed, 0)
        if profile is not None and not isinstance(profile, CurriculumProfile):
            raise validation.fail("profile", profile, "a CurriculumProfile or None")
        profile = profile if profile is not None else CurriculumProfile()
        if reward_bounds is not None:
            profile = dataclasses.replace(profile, reward_bounds=reward_bounds)
        self.profile = profile
        self.teacher_name = teacher
        self.expert_knowledge = expert_knowledge
        self.scale_reward = validation.flag("scale_reward", scale_reward)
        self.keep_periodical_task_samples = validation.count(
            "keep_periodical_task_samples", keep_periodical_task_samples, minimum=0
        )
        validation.count("nb_test_episodes", nb_test_episodes)

        low, high = self.task_space.low, self.task_space.high
        self.shuffler = (
            DimensionsShuffler(low, high, cuttings=4, seed=self.seed)
            if validation.flag("shuffle_dimensions", shuffle_dimensions)
            else None
        )
        if total_steps is not None:
            total_steps = validation.count("total_steps", total_steps)
        params = expert_params(teacher, profile, self.task_space, expert_knowledge, total_steps)
        params.update(teacher_params or {})
        params = self._to_teacher_space(teacher, params)
        self.teacher = make(teacher, self.task_space, seed=self.seed, **params)

        self._test_tasks = test_sets_mod.resolve(
            test_set, self.task_space, int(nb_test_episodes), profile
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
        if self.scale_reward:
            for key in teacher_class(teacher).return_params:
                if key in params:
                    params[key] = self.scale(params[key])
        return params

    # ------------------------------------------------------------------ properties
    @property
    def needs(self) -> frozenset[str]:
        return self.teacher.needs

    def set_value_estimator(self, fn, episodes=None) -> None:
        self.teacher.set_value_estimator(fn, episodes)

    @property
    def reward_bounds(self) -> tuple[float, float]:
        return self.profile.reward_bounds

    def scale(self, episode_return: float) -> float:
        return self.profile.scale(episode_return)

    @property
    def marks_exploratory(self) -> bool:
        """Whether the teacher marks some levels exploratory (Robust PLR, ACCEL)."""
        return self.teacher.marks_exploratory

    # ------------------------------------------------------------------ training
    def sample_task(self) -> np.ndarray:
        """The next training task (float32, environment space)."""
        return self.sample_training_task()[0]

    def sample_training_task(self) -> tuple[np.ndarray, bool]:
        """The next training task (float32, environment space) and whether its episode is
        exploratory (see `sample_training_tasks`)."""
        tasks, exploratory = self.sample_training_tasks(1)
        return tasks[0], bool(exploratory[0])

    def sample_training_tasks(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """`n` training tasks ((n, d) float32, environment space; one teacher call) and whether
        each episode is exploratory: a new or edited level on which Robust PLR / ACCEL do not
        update the student. Decided now, in the teacher's space (a shuffled float32 task does
        not map back exactly), because the teacher forgets the proposal once it is reported."""
        teacher_tasks = self.teacher.sample_tasks(n)
        exploratory = np.zeros(len(teacher_tasks), dtype=bool)
        if self.marks_exploratory:
            exploratory[:] = [self.teacher.is_exploratory(t) for t in teacher_tasks]
        tasks = teacher_tasks if self.shuffler is None else self.shuffler.forward(teacher_tasks)
        tasks = np.asarray(tasks, dtype=np.float32).reshape(len(teacher_tasks), self.task_space.dim)
        self._records["sampled_tasks"].extend(tasks)
        return tasks, exploratory

    def record_step(self, state, action, reward, next_state, done, worker: int = 0) -> None:
        """One environment step, for teachers whose `needs` include "step_rewards".

        `worker` identifies the environment when several run interleaved (SPDL keeps one
        discounted return per worker)."""
        if "step_rewards" not in self.needs:
            return
        self.teacher.step_update(state, action, reward, next_state, bool(done), stream=worker)

    def record_steps(self, states, actions, rewards, next_states, dones, workers=None) -> None:
        """One step of each of N envs taken together ((N, ...) arrays; `workers`: their env
        indices, None: 0 .. N-1), for teachers whose `needs` include "step_rewards": what N
        `record_step` calls in that order give, in one call."""
        if "step_rewards" not in self.needs:
            return
        self.teacher.step_updates(states, actions, rewards, next_states, dones, streams=workers)

    def record_episode(self, env_task, episode_return, length, success, initial_obs=None) -> None:
        """A finished training episode on `env_task` (as returned by `sample_task`)."""
        env_task = self._check_env_task(env_task)
        ret = validation.real("episode_return", episode_return)
        length, success = _length(length), _success(success)
        if initial_obs is not None:
            initial_obs = _finite_obs(np.asarray(initial_obs, dtype=np.float32)[None])
        self._learn(env_task[None], np.array([ret]), [length], np.array([success]), initial_obs)

    def record_episodes(self, finished) -> None:
        """Finished training episodes, oldest first (an `EpisodeBatch` of numpy arrays): the
        teacher learns them in one `update_batch` call. All are checked, at once, before any is
        recorded."""
        m, dim = len(finished), self.task_space.dim
        tasks = validation.real_array("tasks", finished.tasks)
        if tasks.shape != (m, dim):
            raise validation.fail("tasks", tasks.shape, f"({m}, {dim}) for {m} episodes")
        returns = validation.real_array("returns", finished.returns, shape=(m,))
        lengths = np.asarray(finished.lengths)
        if lengths.shape != (m,) or lengths.dtype.kind not in "iu" or np.any(lengths < 0):
            raise validation.fail("lengths", finished.lengths, f"({m},) integers >= 0")
        successes = np.asarray(finished.successes)
        if successes.shape != (m,) or successes.dtype != bool:
            raise validation.fail("successes", finished.successes, f"({m},) bools")
        obs = finished.initial_obs
        obs = None if obs is None else _finite_obs(np.asarray(obs, dtype=np.float32))
        self._learn(tasks, returns, lengths.tolist(), successes, obs)

    def _learn(self, env_tasks, returns, lengths, successes, initial_obs) -> None:
        """Checked episodes to the teacher (in teacher space, scaled) and to the records."""
        if not len(env_tasks):
            return
        tasks = self.shuffler.inverse(env_tasks) if self.shuffler is not None else env_tasks
        rewards = [self.scale(r) for r in returns] if self.scale_reward else returns
        # one episode (`record_episode`) goes through the teacher's one-episode API; SPDL gets
        # each episode's first state right before it
        if len(tasks) == 1 or "initial_states" in self.needs:
            for k, task in enumerate(tasks):
                if initial_obs is not None:
                    self.teacher.record_initial_state(task, initial_obs[k])
                self.teacher.episodic_update(task, float(rewards[k]), bool(successes[k]))
        else:
            self.teacher.update_batch(tasks, rewards, successes)
        r = self._records
        r["train_tasks"].extend(np.asarray(env_tasks, dtype=np.float32))
        r["train_returns"].extend(np.asarray(returns, dtype=np.float64).tolist())
        r["train_lengths"].extend(int(n) for n in lengths)
        r["train_success"].extend(np.asarray(successes, dtype=bool).tolist())

    def maybe_sample_periodically(self, total_steps: int) -> np.ndarray | None:
        """Every `keep_periodical_task_samples` steps, keep 100 non-exploratory task samples
        (environment space) to show how the curriculum moves; returns them when taken."""
        if self.keep_periodical_task_samples <= 0 or total_steps < self._next_periodic:
            return None
        k = self.keep_periodical_task_samples
        self._next_periodic = (int(total_steps) // k + 1) * k
        if self.teacher.is_non_exploratory_task_sampling_available():
            # streams of their own, from the run's seed and the step, so a run's tasks do not
            # depend on how often it shows its curriculum, and a resumed run draws the same
            seed = np.random.SeedSequence([self.seed, int(total_steps)]).generate_state(1)[0]
            tasks = self.teacher.non_exploratory_samples(NB_PERIODICAL_SAMPLES, int(seed))
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
            validation.real("episode_return", episode_return),
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
            "env_name": self.profile.name,
            "expert_knowledge": self.expert_knowledge,
            "names": self.task_space.flat_names(),
            "bounds": self.task_space.bounds_dict(),
            "low": self.task_space.low,
            "high": self.task_space.high,
            "scale_reward": self.scale_reward,
            "reward_bounds": list(self.reward_bounds),
            "success_return": self.profile.success_return,  # what train_success means
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
