"""The batched env as a Gymnasium 1.x vector env: `gymnasium.make_vec(id, num_envs,
vectorization_mode="vector_entry_point", body=...)` for every acl3d id.

Autoreset (declared in `metadata["autoreset_mode"]`, as `SyncVectorEnv` does it):

* `NEXT_STEP` (default, Gymnasium's and CleanRL's): the step that ends a sub-env's episode
  returns its last observation; the next `step` resets it (its action is ignored) and returns the
  first observation with reward 0. Gymnasium's vector wrappers (`NormalizeObservation`,
  `RecordEpisodeStatistics`, `ClipAction`, `TransformObservation`, ...) need this mode.
* `SAME_STEP`: a sub-env that ends is reset within the same `step`; its last observation and
  info are in `infos["final_obs"]` / `infos["final_info"]` (masks `_final_obs`, `_final_info`).

Curricula (`task_source`, see `acl3d.envs.curriculum_wrapper`): every reset that names no task
plays `task_source.next_task(i)`; every finished episode is reported once, with the task it
played, to `task_source.episode_finished(i, report)` during the step that ends it, hence
before that sub-env's next task is chosen. The same report is in `infos["curriculum"]`
(mask `_curriculum`). `teacher=` is the shortcut for `task_source=TeacherTaskSource(teacher)`.
Episodes cut short by `reset()` are not reported.

A sub-env that resets under NEXT_STEP is stepped by the engine with the others and then reset;
steps draw no randomness, so sub-env i still plays exactly what a single env plays.
"""

from __future__ import annotations

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from acl3d import validation
from acl3d.envs.batched import BatchedEnvs
from acl3d.envs.curriculum_wrapper import INFO_KEY, TeacherTaskSource, episode_report

AUTORESET_MODES = (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)


class BatchedVectorEnv(VectorEnv):
    """N acl3d envs of `env_id` stepped together (see `acl3d.envs.batched.BatchedEnvs`).

    Args:
        env_id, num_envs, threads, **env_kwargs: as `BatchedEnvs`.
        autoreset_mode: `AutoresetMode.NEXT_STEP` (default) or `SAME_STEP` (or their names).
        task_source: a `TaskSource` choosing each sub-env's tasks (see the module docstring).
        teacher: an acl3d teacher (or any object with `sample_task` / `episodic_update`) shared
            by all sub-envs; exclusive with `task_source`.
    """

    def __init__(
        self,
        env_id: str,
        num_envs: int,
        threads: int | None = None,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        task_source=None,
        teacher=None,
        **env_kwargs,
    ):
        mode = _autoreset_mode(autoreset_mode)
        if teacher is not None and task_source is not None:
            raise ValueError("teacher and task_source are exclusive: give one of them")
        if teacher is not None:
            task_source = TeacherTaskSource(teacher)
        elif task_source is not None and not all(
            callable(getattr(task_source, m, None)) for m in ("next_task", "episode_finished")
        ):
            raise validation.fail(
                "task_source",
                task_source,
                "an object with next_task(i) and episode_finished(i, report)",
            )
        self.batch = BatchedEnvs(env_id, num_envs, threads=threads, **env_kwargs)
        self.metadata = {"autoreset_mode": mode, "render_modes": []}
        self.task_source = task_source
        self.num_envs = n = self.batch.num_envs
        self.single_observation_space = self.batch.single_observation_space
        self.single_action_space = self.batch.single_action_space
        self.observation_space = batch_space(self.single_observation_space, n)
        self.action_space = batch_space(self.single_action_space, n)
        self.envs = self.batch.envs
        self.task_space = self.batch.task_space
        self._returns = np.zeros(n)
        self._tasks = np.zeros((n, self.task_space.dim), dtype=np.float32)
        self._initial_obs = [None] * n
        self._autoreset = np.zeros(n, dtype=bool)
        self._next_step = mode == AutoresetMode.NEXT_STEP
        self._every_env = np.ones(n, dtype=bool)
        self._every_env.flags.writeable = False

    def reset(self, *, seed=None, options=None):
        """`seed`: None, an int s (sub-env i seeded s + i) or one per sub-env; `options`: a dict
        for all sub-envs (e.g. {"task": ...}) or one dict per sub-env."""
        seeds = self.batch.seeds(seed)
        per_env = self.batch.per_env_options(options)
        results = [self._reset_one(i, seeds[i], per_env[i]) for i in range(self.num_envs)]
        self._autoreset[:] = False
        infos = [info for _, info in results]
        return np.stack([obs for obs, _ in results]), _stack_infos(infos, self._every_env)

    def _reset_one(self, i: int, seed=None, options=None):
        """Reset sub-env i on the task of `options`, else on its task source's next one."""
        options = dict(options or {})
        if "task" not in options and self.task_source is not None:
            options["task"] = self.task_source.next_task(i)
        obs, info = self.batch.reset_one(i, seed, options)
        self._tasks[i] = self.envs[i].task_vector
        self._returns[i] = 0.0
        self._initial_obs[i] = obs.copy()
        return obs, info

    def step(self, actions):
        obs, rewards, terminated, truncated, infos = self.batch.step(actions)
        self._returns += rewards
        for i in self._autoreset.nonzero()[0]:  # NEXT_STEP: ended at the previous step
            obs[i], infos[i] = self._reset_one(int(i))
            rewards[i], terminated[i], truncated[i] = 0.0, False, False
        done = terminated | truncated
        ended = done.nonzero()[0]
        for i in ended:
            infos[i][INFO_KEY] = self._report(int(i), infos[i], terminated[i], truncated[i])
        out = _stack_infos(infos, self._every_env)
        if self._next_step:
            self._autoreset = done
        elif len(ended):
            final_obs = np.empty(self.num_envs, dtype=object)
            final_infos: list[dict] = [{} for _ in range(self.num_envs)]
            for i in ended:
                final_obs[i], final_infos[i] = obs[i].copy(), infos[i]
                obs[i] = self._reset_one(int(i))[0]
            out["final_obs"], out["_final_obs"] = final_obs, done.copy()
            out["final_info"], out["_final_info"] = _stack_infos(final_infos, done), done.copy()
        return obs, rewards, terminated, truncated, out

    def _report(self, i: int, info: dict, terminated: bool, truncated: bool) -> dict:
        """Sub-env i's finished episode, handed to the task source once."""
        report = episode_report(
            self._tasks[i],
            self._returns[i],
            self.batch.elapsed[i],
            info.get("success", False),
            truncated and not terminated,
            self._initial_obs[i],
        )
        if self.task_source is not None:
            self.task_source.episode_finished(i, report)
        return report

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


def _stack_infos(infos: list[dict], mask: np.ndarray) -> dict:
    """Gymnasium's vector info layout: per key an array over sub-envs and a `_key` mask."""
    out: dict = {}
    n = len(infos)
    for key in sorted(set().union(*infos)):
        values = [info.get(key) for info in infos]
        has = np.fromiter([key in info for info in infos], bool, n) & mask
        if all(type(v) is bool or v is None for v in values):  # every step's "success"
            arr = np.fromiter(values, bool, n) & has
        else:
            arr = np.zeros(n, dtype=object)
            arr[has] = [values[i] for i in has.nonzero()[0]]
        out[key], out["_" + key] = arr, has
    return out


def stump_tracks(num_envs: int = 1, **kwargs) -> BatchedVectorEnv:
    """Vector entry point of acl3d/StumpTracks-v0."""
    return BatchedVectorEnv("acl3d/StumpTracks-v0", num_envs, **kwargs)


def hexagon_tracks(num_envs: int = 1, **kwargs) -> BatchedVectorEnv:
    """Vector entry point of acl3d/HexagonTracks-v0."""
    return BatchedVectorEnv("acl3d/HexagonTracks-v0", num_envs, **kwargs)


def parkour(num_envs: int = 1, **kwargs) -> BatchedVectorEnv:
    """Vector entry point of acl3d/Parkour-v0."""
    return BatchedVectorEnv("acl3d/Parkour-v0", num_envs, **kwargs)


def terrain3d(num_envs: int = 1, **kwargs) -> BatchedVectorEnv:
    """Vector entry point of acl3d/Terrain3D-v0."""
    return BatchedVectorEnv("acl3d/Terrain3D-v0", num_envs, **kwargs)
