"""Episode statistics: the one place where an episode's return and length are summed.

Every training path (a single env behind `CurriculumWrapper`, the Gymnasium and SB3 batched vec
envs, a torch-native student stepping many worlds on a GPU) feeds its per-step (N,) arrays to an
`EpisodeStatistics` and gets back the finished episodes as one `EpisodeBatch` (env ids, tasks,
returns, lengths, successes, truncation, the step count at which each finished). That batch is
what the teacher learns from, what the episode log and TensorBoard write, and what evaluations
read, so an episode is summed once and every consumer sees the same numbers.

The curriculum is kept in step with the worlds by one verb, `CurriculumSync.sync(finished,
env_ids)`: learn from the finished episodes, then hand back the next task of each env that
resets. Data flow one way: teacher -> tasks -> worlds -> episode results -> teacher.

Arrays: numpy by default; with `device=` (a torch device or its name) every buffer is a torch
tensor there and `step` runs without a Python loop over envs and without a host sync (finished
episodes are kept on the device, masked, until `pop()` gathers them with one sync). Use::

    stats = EpisodeStatistics(num_envs, task_dim)               # or device="cuda"
    stats.begin(np.arange(num_envs), tasks)                     # episodes start (reset)
    ... each step:
    stats.step(rewards, terminated, truncated, successes)       # (N,) arrays
    finished = stats.pop()                                      # EpisodeBatch, maybe empty
    tasks = sync.sync(finished, finished.env_ids)               # teacher learns, new tasks
    stats.begin(finished.env_ids, tasks)                        # the worlds reset on them
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, Protocol

import numpy as np

from acl3d import validation


@dataclass(frozen=True)
class EpisodeBatch:
    """M finished episodes, oldest first (then by env id); arrays of the stats' kind (numpy or
    torch on its device).

    env_ids (M,) int64, tasks (M, d) float32 (the task each episode played), returns (M,)
    float64, lengths (M,) int64, successes (M,) bool, truncated (M,) bool (ended by the time
    limit, not by termination), total_steps (M,) int64 (env steps of the whole vector env when
    the episode ended), initial_obs (M, obs) float32 or None (only when `begin` was given them).
    """

    env_ids: Any
    tasks: Any
    returns: Any
    lengths: Any
    successes: Any
    truncated: Any
    total_steps: Any
    initial_obs: Any = None

    def __len__(self) -> int:
        return int(self.env_ids.shape[0])

    def numpy(self) -> EpisodeBatch:
        """The same batch as numpy arrays (a copy from the device for torch tensors)."""
        return EpisodeBatch(**{f.name: _to_numpy(getattr(self, f.name)) for f in fields(self)})

    @staticmethod
    def concat(batches: list[EpisodeBatch]) -> EpisodeBatch:
        """The numpy batches one after the other, as one."""
        if len(batches) == 1:
            return batches[0]
        return EpisodeBatch(**{
            f.name: None if getattr(batches[0], f.name) is None
            else np.concatenate([getattr(b, f.name) for b in batches])
            for f in fields(EpisodeBatch)
        })  # fmt: skip

    @staticmethod
    def empty(task_dim: int) -> EpisodeBatch:
        """No episodes (numpy), e.g. for the first `sync` before any episode ran."""
        z = np.zeros(0, dtype=np.int64)
        return EpisodeBatch(
            z, np.zeros((0, task_dim), np.float32), np.zeros(0), z, z.astype(bool),
            z.astype(bool), z,
        )  # fmt: skip


class CurriculumSync(Protocol):
    """The curriculum side of a vector of worlds: one verb, called whenever envs reset."""

    def sync(self, finished: EpisodeBatch, env_ids) -> Any:
        """Learn from `finished` (possibly empty), then return the next task of every env in
        `env_ids` (possibly empty) as an (len(env_ids), d) float32 array, in that order."""
        ...


class BatchTeacher(Protocol):
    """What `TeacherSync` needs of a teacher (every `acl3d.teachers.base.Teacher` has it)."""

    def sample_tasks(self, n: int) -> np.ndarray: ...

    def update_batch(self, tasks, returns, successes) -> None: ...


def check_methods(name: str, obj, methods: tuple[str, ...]) -> None:
    """ValueError naming `name` unless `obj` has every one of `methods` (callable)."""
    missing = [m for m in methods if not callable(getattr(obj, m, None))]
    if missing:
        raise validation.fail(name, obj, f"an object with {', '.join(methods)}; {missing} missing")


class TeacherSync:
    """`CurriculumSync` of one teacher shared by all envs (numpy on the teacher's side)."""

    def __init__(self, teacher: BatchTeacher):
        check_methods("teacher", teacher, ("sample_tasks", "update_batch"))
        self.teacher = teacher

    def sync(self, finished: EpisodeBatch, env_ids) -> np.ndarray:
        if len(finished):
            f = finished.numpy()
            self.teacher.update_batch(f.tasks, f.returns, f.successes)
        tasks = np.asarray(self.teacher.sample_tasks(len(env_ids)), dtype=np.float32)
        return tasks.reshape(len(env_ids), tasks.shape[-1] if tasks.ndim else 0)


class EpisodeStatistics:
    """Running returns and lengths of N envs' episodes; emits the finished ones as batches.

    Args:
        num_envs: N.
        task_dim: length of a task vector.
        device: None for numpy arrays; a torch device (or its name) for torch tensors there.
        success_return: where a step gives no success flag (`successes=None`), an episode
            succeeds when its return exceeds this; None: it does not succeed.
    """

    def __init__(self, num_envs: int, task_dim: int, *, device=None, success_return=None):
        self.num_envs = validation.count("num_envs", num_envs)
        self.task_dim = validation.count("task_dim", task_dim, minimum=0)
        self.success_return = (
            None if success_return is None else validation.real("success_return", success_return)
        )
        self._xp = _Numpy() if device is None else _Torch(device)
        xp, n = self._xp, self.num_envs
        self.returns = xp.zeros(n, "float64")
        self.lengths = xp.zeros(n, "int64")
        self.tasks = xp.zeros((n, self.task_dim), "float32")
        self.initial_obs = None  # (N, obs) once `begin` is given observations
        self.total_steps = 0
        self._pending: list[EpisodeBatch] = []
        self._empty = xp.empty_batch(self.task_dim)  # what `pop` gives when nothing ended

    # ------------------------------------------------------------------ episodes
    def begin(self, env_ids, tasks, initial_obs=None) -> None:
        """Episodes start on `env_ids` with these tasks and, optionally, first observations:
        indices with (len, d) tasks, or an (N,) bool mask with (N, d) tasks (rows off the mask
        ignored; on torch this form needs no host sync)."""
        xp, n = self._xp, self.num_envs
        if xp.is_mask(env_ids):
            mask = xp.asarray(env_ids, "bool").reshape(n)
            self.tasks = xp.where(
                mask, xp.asarray(tasks, "float32").reshape(n, self.task_dim), self.tasks
            )
            if initial_obs is not None:
                obs = xp.asarray(initial_obs, "float32").reshape(n, -1)
                base = (
                    self.initial_obs
                    if self.initial_obs is not None
                    else xp.zeros(obs.shape, "float32")
                )
                self.initial_obs = xp.where(mask, obs, base)
            self._restart(mask)
            return
        ids = xp.indices(env_ids, n)
        if ids.shape[0] == 0:
            return
        tasks = xp.asarray(tasks, "float32").reshape(-1, self.task_dim)
        if tasks.shape[0] != ids.shape[0]:
            raise validation.fail("tasks", tuple(tasks.shape), f"({ids.shape[0]}, {self.task_dim})")
        self.tasks[ids] = tasks
        self.returns[ids] = 0.0
        self.lengths[ids] = 0
        if initial_obs is not None:
            obs = xp.asarray(initial_obs, "float32").reshape(ids.shape[0], -1)
            if self.initial_obs is None:
                self.initial_obs = xp.zeros((n, obs.shape[1]), "float32")
            self.initial_obs[ids] = obs

    def _restart(self, mask) -> None:
        """Zero the running sums of the envs in `mask`."""
        self.returns = self._xp.where(mask, 0.0, self.returns)
        self.lengths = self._xp.where(mask, 0, self.lengths)

    def add(self, rewards) -> None:
        """Add one step's rewards to every env's running sums, booking no episode: for passes
        of one episode a world (evaluations), whose results are read from the step's infos,
        so a step keeps no rows of every env for a `pop()` nobody makes."""
        self.returns += self._xp.asarray(rewards, "float64").reshape(self.num_envs)
        self.lengths += 1
        self.total_steps += self.num_envs

    def step(self, rewards, terminated, truncated, successes=None):
        """Add one step of every env; returns the (N,) mask of episodes that ended. The ended
        episodes wait in `pop()`; their running sums restart at 0 (an auto-reset env's next
        step belongs to its next episode; `begin` sets its task)."""
        xp, n = self._xp, self.num_envs
        terminated = xp.asarray(terminated, "bool").reshape(n)
        truncated = xp.asarray(truncated, "bool").reshape(n)
        self.add(rewards)
        done = terminated | truncated
        if successes is not None:
            success = xp.asarray(successes, "bool").reshape(n)
        elif self.success_return is not None:
            success = self.returns > self.success_return
        else:
            success = xp.zeros(n, "bool")
        rows = xp.rows(done)
        if rows is not None:
            self._pending.append(
                (None if xp.is_numpy else done, self._rows(rows, success, truncated & ~terminated))
            )
        if not xp.is_numpy:
            self._restart(done)  # masked, with no host sync
        elif rows is not None:  # numpy: the ended rows in place (most steps end none)
            self.returns[rows] = 0.0
            self.lengths[rows] = 0
        return done

    def _rows(self, rows, success, truncated) -> EpisodeBatch:
        """The episode fields of `rows` (numpy: the ended envs; torch: every env, masked later)."""
        return EpisodeBatch(
            env_ids=self._xp.env_ids(rows),
            tasks=self.tasks[rows],
            returns=self.returns[rows],
            lengths=self.lengths[rows],
            successes=success[rows],
            truncated=truncated[rows],
            total_steps=self._xp.full(rows.shape[0], self.total_steps, "int64"),
            initial_obs=None if self.initial_obs is None else self.initial_obs[rows],
        )

    def pop(self) -> EpisodeBatch:
        """The episodes that ended since the last call, oldest first (then by env id). Torch:
        pop once per rollout or so; until then every step's rows wait on the device."""
        pending, self._pending = self._pending, []
        if not pending:
            return self._empty
        return self._xp.gather(pending)

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        """The running episodes as numpy arrays (episodes not yet popped are not part of it)."""
        return {
            "returns": _to_numpy(self.returns),
            "lengths": _to_numpy(self.lengths),
            "tasks": _to_numpy(self.tasks),
            "total_steps": int(self.total_steps),
            "initial_obs": None if self.initial_obs is None else _to_numpy(self.initial_obs),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Inverse of `state_dict()` (on stats of the same size)."""
        xp, n = self._xp, self.num_envs
        self.returns = xp.copy(state["returns"], "float64").reshape(n)
        self.lengths = xp.copy(state["lengths"], "int64").reshape(n)
        self.tasks = xp.copy(state["tasks"], "float32").reshape(n, self.task_dim)
        self.total_steps = int(state["total_steps"])
        obs = state.get("initial_obs")
        self.initial_obs = None if obs is None else xp.copy(obs, "float32").reshape(n, -1)
        self._pending = []


def _to_numpy(x):
    if x is None or isinstance(x, np.ndarray):
        return x
    return x.detach().cpu().numpy()


class _Numpy:
    """Array operations on numpy: finished rows are taken at once (a cheap host check)."""

    is_numpy = True

    def zeros(self, shape, dtype: str):
        return np.zeros(shape, dtype=dtype)

    def full(self, n: int, value, dtype: str):
        return np.full(n, value, dtype=dtype)

    def asarray(self, x, dtype: str):
        return np.asarray(x, dtype=dtype)

    def copy(self, x, dtype: str):
        return np.array(x, dtype=dtype, copy=True)

    def is_mask(self, ids) -> bool:
        return np.asarray(ids).dtype == bool

    def where(self, mask, a, b):
        """Rows of `a` where the (N,) `mask` holds, else of `b` (same dtype as `b`)."""
        return np.where(mask.reshape(-1, *([1] * (np.ndim(b) - 1))), a, b).astype(b.dtype)

    def indices(self, ids, n: int):
        ids = np.asarray(ids)
        if ids.dtype == bool:
            return np.flatnonzero(ids.reshape(n))
        ids = ids.astype(np.int64).reshape(-1)
        if len(ids) and (ids.min() < 0 or ids.max() >= n):
            raise validation.fail("env_ids", ids.tolist(), f"indices in [0, {n})")
        return ids

    def rows(self, done):
        rows = np.flatnonzero(done)
        return rows if len(rows) else None

    def env_ids(self, rows):
        return rows.astype(np.int64)

    def empty_batch(self, task_dim: int) -> EpisodeBatch:
        return EpisodeBatch.empty(task_dim)

    def gather(self, pending) -> EpisodeBatch:
        return EpisodeBatch.concat([b for _, b in pending])


class _Torch:
    """Array operations on torch tensors of one device: every step keeps all rows and the done
    mask, so no step reads a value back to the host; `gather` compacts them with one sync."""

    is_numpy = False

    def __init__(self, device):
        import torch

        self.torch = torch
        self.device = torch.device(device)

    def _dtype(self, name: str):
        return getattr(self.torch, name)

    def zeros(self, shape, dtype: str):
        return self.torch.zeros(shape, dtype=self._dtype(dtype), device=self.device)

    def full(self, n: int, value, dtype: str):
        return self.torch.full((n,), value, dtype=self._dtype(dtype), device=self.device)

    def asarray(self, x, dtype: str):
        return self.torch.as_tensor(x, dtype=self._dtype(dtype), device=self.device)

    def copy(self, x, dtype: str):
        return self.asarray(x, dtype).clone()

    def is_mask(self, ids) -> bool:
        return self.torch.as_tensor(ids).dtype == self.torch.bool

    def where(self, mask, a, b):
        """Rows of `a` where the (N,) `mask` holds, else of `b` (same dtype as `b`)."""
        if not isinstance(a, (int, float)):  # a Python number stays one: no host-to-device copy
            a = self.torch.as_tensor(a, dtype=b.dtype, device=self.device)
        return self.torch.where(mask.reshape(-1, *([1] * (b.dim() - 1))), a, b)

    def indices(self, ids, n: int):
        ids = self.torch.as_tensor(ids, device=self.device)
        if ids.dtype == self.torch.bool:
            return ids.reshape(n).nonzero().reshape(-1)
        return ids.to(self.torch.int64).reshape(-1)

    def rows(self, done):
        return self.torch.arange(done.shape[0], device=self.device)

    def env_ids(self, rows):
        return rows

    def empty_batch(self, task_dim: int) -> EpisodeBatch:
        b = EpisodeBatch.empty(task_dim)
        return EpisodeBatch(**{
            f.name: None if getattr(b, f.name) is None
            else self.torch.as_tensor(getattr(b, f.name), device=self.device)
            for f in fields(EpisodeBatch)
        })  # fmt: skip

    def gather(self, pending) -> EpisodeBatch:
        cat = self.torch.cat
        keep = cat([mask for mask, _ in pending]).nonzero().reshape(-1)  # the one host sync
        batches = [b for _, b in pending]
        return EpisodeBatch(**{
            f.name: None if getattr(batches[0], f.name) is None
            else cat([getattr(b, f.name) for b in batches])[keep]
            for f in fields(EpisodeBatch)
        })  # fmt: skip
