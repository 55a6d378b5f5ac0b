"""The batched env as a Gymnasium 1.x vector env: `gymnasium.make_vec(id, num_envs,
vectorization_mode="vector_entry_point", body=...)` for every acl3d id.

Autoreset (declared in `metadata["autoreset_mode"]`, as `SyncVectorEnv` does it):

* `NEXT_STEP` (default, Gymnasium's and CleanRL's): the step that ends a sub-env's episode
  returns its last observation; the next `step` resets it (its action is ignored) and returns the
  first observation with reward 0. Gymnasium's vector wrappers (`NormalizeObservation`,
  `RecordEpisodeStatistics`, `ClipAction`, `TransformObservation`, ...) need this mode.
* `SAME_STEP`: a sub-env that ends is reset within the same `step`; its last observation and
  info are in `infos["final_obs"]` / `infos["final_info"]` (masks `_final_obs`, `_final_info`).

Curricula (`curriculum_sync`, a `acl3d.envs.episode_statistics.CurriculumSync`): episodes are
summed by one `EpisodeStatistics`; the step that ends episodes hands them to
`curriculum_sync.sync(finished, env_ids)` once, with the tasks they played, before any of those
sub-envs' next tasks is chosen (SAME_STEP: in that same call, which returns their next tasks;
NEXT_STEP: the resets of the next step ask for theirs). Resets that name no task play the
tasks `sync` returns. The same reports are in `infos["curriculum"]` (mask `_curriculum`).
`teacher=` is the shortcut for `curriculum_sync=TeacherSync(teacher)`. Episodes cut short by
`reset()` are not reported.

A sub-env that resets under NEXT_STEP is stepped by the engine with the others and then reset;
steps draw no randomness, so sub-env i still plays exactly what a single env plays.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from acl3d import validation
from acl3d.envs.batched import BatchedEnvs, EngineStep
from acl3d.envs.curriculum_wrapper import INFO_KEY, episode_report
from acl3d.envs.episode_statistics import (
    EpisodeBatch,
    EpisodeStatistics,
    TeacherSync,
    check_methods,
)

AUTORESET_MODES = (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)


class BatchedVectorEnv(VectorEnv):
    """N acl3d envs of `env_id` stepped together (see `acl3d.envs.batched.BatchedEnvs`).

    Args:
        env_id, num_envs, threads, **env_kwargs: as `BatchedEnvs`.
        autoreset_mode: `AutoresetMode.NEXT_STEP` (default) or `SAME_STEP` (or their names).
        curriculum_sync: a `CurriculumSync` choosing the sub-envs' tasks (module docstring).
        teacher: an acl3d teacher (anything with `sample_tasks(n)` / `update_batch(...)`)
            shared by all sub-envs; exclusive with `curriculum_sync`.
    """

    def __init__(
        self,
        env_id: str,
        num_envs: int,
        threads: int | None = None,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        curriculum_sync=None,
        teacher=None,
        **env_kwargs,
    ):
        mode = _autoreset_mode(autoreset_mode)
        if teacher is not None and curriculum_sync is not None:
            raise ValueError("teacher and curriculum_sync are exclusive: give one of them")
        if teacher is not None:
            curriculum_sync = TeacherSync(teacher)
        elif curriculum_sync is not None:
            check_methods("curriculum_sync", curriculum_sync, ("sync",))
        self.batch = BatchedEnvs(env_id, num_envs, threads=threads, **env_kwargs)
        self.metadata = {"autoreset_mode": mode, "render_modes": []}
        self.curriculum_sync = curriculum_sync
        self.num_envs = n = self.batch.num_envs
        self.single_observation_space = self.batch.single_observation_space
        self.single_action_space = self.batch.single_action_space
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)
        self.envs = self.batch.envs
        self.task_space = self.batch.task_space
        self.stats = EpisodeStatistics(n, self.task_space.dim)
        self._autoreset = np.zeros(n, dtype=bool)
        self._next_step = mode == AutoresetMode.NEXT_STEP
        self._every_env = np.ones(n, dtype=bool)
        self._every_env.flags.writeable = False

    def reset(self, *, seed=None, options=None):
        """`seed`: None, an int s (sub-env i seeded s + i) or one per sub-env; `options`: a dict
        for all sub-envs (e.g. {"task": ...}) or one dict per sub-env."""
        seeds = self.batch.seeds(seed)
        per_env = [dict(o or {}) for o in self.batch.per_env_options(options)]
        ids = np.arange(self.num_envs)
        obs, infos = self._reset_many(ids, EpisodeBatch.empty(self.task_space.dim), seeds, per_env)
        self._autoreset[:] = False
        return obs, _stack_infos(self.num_envs, self._every_env, dict(enumerate(infos)))

    def _reset_many(self, ids, finished: EpisodeBatch, seeds=None, options=None):
        """Reset sub-envs `ids` (after handing `finished` to the curriculum) on their options'
        tasks, else on the tasks `curriculum_sync` returns; their (observations, infos)."""
        options = options or [{} for _ in range(self.num_envs)]
        seeds = seeds or [None] * self.num_envs
        pull = [i for i in ids if "task" not in options[i]]
        if self.curriculum_sync is not None and (len(pull) or len(finished)):
            for i, task in zip(
                pull, self.curriculum_sync.sync(finished, np.asarray(pull, np.int64))
            ):
                options[i]["task"] = task
        obs, infos = [], []
        for i in ids:
            o, info = self.batch.reset_one(int(i), seeds[i], options[i])
            obs.append(o)
            infos.append(info)
        if len(ids):
            tasks = np.stack([self.envs[i].task_vector for i in ids])
            self.stats.begin(np.asarray(ids, np.int64), tasks, np.stack(obs))
        return (np.stack(obs) if obs else None), infos

    def step(self, actions):
        out = self.step_arrays(actions)
        return out.obs, out.rewards, out.terminated, out.truncated, out.infos(self._every_env)

    def step_arrays(self, actions) -> VectorStep:
        """`step` with its infos as arrays and the few per-env dicts (resets, finished
        episodes), for callers that need no Gymnasium info dict (`CpuTensorVectorEnv`)."""
        engine = self.batch.step(actions)
        obs, rewards, terminated, truncated = engine[:4]
        restart = self._autoreset.nonzero()[0]  # NEXT_STEP: ended at the previous step
        if len(restart):
            rewards[restart], terminated[restart], truncated[restart] = 0.0, False, False
        done = self.stats.step(rewards, terminated, truncated, engine.success)
        reset_infos: dict[int, dict] = {}
        if len(restart):
            empty = EpisodeBatch.empty(self.task_space.dim)
            new_obs, new_infos = self._reset_many(restart, empty)
            obs[restart] = new_obs
            reset_infos.update(zip(restart.tolist(), new_infos))
        finished = self.stats.pop()
        final_obs = None
        if self._next_step:
            self._autoreset = done
            if len(finished) and self.curriculum_sync is not None:
                self.curriculum_sync.sync(finished, np.zeros(0, np.int64))
        elif len(finished):
            final_obs = obs.copy()
            obs[finished.env_ids] = self._reset_many(finished.env_ids, finished)[0]
        return VectorStep(
            obs, rewards, terminated, truncated, engine, reset_infos, finished, done, final_obs
        )

    def close_extras(self, **kwargs):
        self.batch.close()


def _autoreset_mode(value) -> AutoresetMode:
    names = {m.value: m for m in AUTORESET_MODES} | {m.name: m for m in AUTORESET_MODES}
    if isinstance(value, AutoresetMode) and value in AUTORESET_MODES:
        return value
    if isinstance(value, str) and value in names:
        return names[value]
    raise validation.fail(
        "autoreset_mode", value, "AutoresetMode.NEXT_STEP or AutoresetMode.SAME_STEP"
    )


class VectorStep(NamedTuple):
    """One step of `BatchedVectorEnv` as arrays (`step_arrays`); `infos` lays it out as
    Gymnasium's info dict.

    The info of sub-env i is the engine's flags (`EngineStep.info(i)`), but a NEXT_STEP reset's
    is its reset's info (`reset_infos`) and a finished episode's adds `INFO_KEY`'s report.
    SAME_STEP: `final_obs` (N, obs) holds the last observations of the episodes that ended
    (`done`; None if none did), `obs` the next episodes' first ones.
    """

    obs: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    engine: EngineStep
    reset_infos: dict[int, dict]
    finished: EpisodeBatch
    done: np.ndarray
    final_obs: np.ndarray | None

    def infos(self, mask: np.ndarray) -> dict:
        n, finished = len(mask), self.finished
        special = dict(self.reset_infos)  # the sub-envs whose info is not the flags'
        for k, i in enumerate(finished.env_ids.tolist()):
            info = special.setdefault(i, self.engine.info(i))
            info[INFO_KEY] = episode_report(
                finished.tasks[k], finished.returns[k], finished.lengths[k],
                finished.successes[k], finished.truncated[k], finished.initial_obs[k],
            )  # fmt: skip
        flags = {"success": (self.engine.success, np.ones(n, bool))}
        if self.engine.unstable.any():
            flags["unstable"] = (self.engine.unstable, self.engine.unstable)
        out = _stack_infos(n, mask, special, flags)
        if self.final_obs is not None:
            ended = self.done.nonzero()[0].tolist()
            final_obs = np.empty(n, dtype=object)
            for i in ended:
                final_obs[i] = self.final_obs[i].copy()
            out["final_obs"], out["_final_obs"] = final_obs, self.done.copy()
            out["final_info"] = _stack_infos(n, self.done, {i: special[i] for i in ended})
            out["_final_info"] = self.done.copy()
        return out


def _stack_infos(n: int, mask: np.ndarray, infos: dict[int, dict], flags=None) -> dict:
    """Gymnasium's vector info layout (per key an array over sub-envs and a `_key` mask) of N
    infos: sub-env i's is `infos[i]` where given, else what `flags` says (key -> ((N,) bool
    values, (N,) mask of the infos holding the key)). A key is laid out when some info holds
    it; keys whose values are all bools (or absent) give bool arrays, others object arrays."""
    flags = flags or {}
    out: dict = {}
    if not infos:  # every info is the flags' (most steps)
        for key, (values, held) in sorted(flags.items()):
            if held.any():
                has = held & mask
                out[key], out["_" + key] = values & has, has
        return out
    ids = np.fromiter(infos, np.int64, len(infos))
    given_rows = np.zeros(n, bool)
    given_rows[ids] = True
    keys = set().union(*infos.values())
    keys |= {key for key, (_, held) in flags.items() if (held & ~given_rows).any()}
    for key in sorted(keys):
        values, held = flags.get(key, (np.zeros(n, bool), np.zeros(n, bool)))
        given = [info.get(key) for info in infos.values()]
        has = held.copy()
        has[ids] = [key in info for info in infos.values()]
        has &= mask
        if all(type(v) is bool or v is None for v in given):
            arr = values.copy()
            arr[ids] = [bool(v) for v in given]
            arr &= has
        else:
            arr = np.zeros(n, dtype=object)
            arr[has] = values[has].tolist()
            for i, value in zip(ids.tolist(), given):
                if has[i]:
                    arr[i] = value
        out[key], out["_" + key] = arr, has
    return out


def vector_env(env_id: str, num_envs: int, device, kwargs: dict) -> VectorEnv:
    """The CPU batched env, or with `device=` the many-world simulation on MuJoCo Warp
    (`acl3d.envs.warp_vector.WarpVectorEnv`: torch tensors on that device)."""
    if device is None:
        return BatchedVectorEnv(env_id, num_envs, **kwargs)
    if "threads" in kwargs:
        raise validation.fail("threads", kwargs["threads"], "not given with device=")
    from acl3d.envs.warp_vector import WarpVectorEnv

    return WarpVectorEnv(env_id, num_envs, device, **kwargs)


def stump_tracks(num_envs: int = 1, device=None, **kwargs) -> VectorEnv:
    """Vector entry point of acl3d/StumpTracks-v0."""
    return vector_env("acl3d/StumpTracks-v0", num_envs, device, kwargs)


def hexagon_tracks(num_envs: int = 1, device=None, **kwargs) -> VectorEnv:
    """Vector entry point of acl3d/HexagonTracks-v0."""
    return vector_env("acl3d/HexagonTracks-v0", num_envs, device, kwargs)


def parkour(num_envs: int = 1, device=None, **kwargs) -> VectorEnv:
    """Vector entry point of acl3d/Parkour-v0 (with `device=`, movable creepers are refused:
    they stay on the CPU batched env)."""
    return vector_env("acl3d/Parkour-v0", num_envs, device, kwargs)


def terrain3d(num_envs: int = 1, device=None, **kwargs) -> VectorEnv:
    """Vector entry point of acl3d/Terrain3D-v0."""
    return vector_env("acl3d/Terrain3D-v0", num_envs, device, kwargs)
