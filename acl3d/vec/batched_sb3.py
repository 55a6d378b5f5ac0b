"""The batched env as a Stable-Baselines3 `VecEnv`, with per-sub-env curriculum task queues.

SB3 conventions: `reset()` returns observations only (infos in `reset_infos`), finished
sub-envs reset within the same `step_wait`, with `infos[i]["terminal_observation"]` and
`infos[i]["TimeLimit.truncated"]`. `env_method`/`get_attr`/`set_attr` (with `indices`) go to
one `SubEnv` per sub-env, which offers the `CurriculumEnv` worker API (`push_task`,
`queued_tasks`, `clear_tasks`, `get_state`/`set_state`) and otherwise hands attributes and
methods to its single env.

Curriculum: episodes are summed by one `acl3d.envs.episode_statistics.EpisodeStatistics`. A
reset that names no task (`set_options`) plays the sub-env's next queued task; with
`curriculum_sync` set (a `CurriculumSync`, e.g. `acl3d.training.curriculum.CurriculumVecEnv`),
every step that ends episodes hands them to `curriculum_sync.sync(finished, env_ids)` once,
which returns the next task of each finished sub-env with an empty queue, before it resets.
With `curriculum=True` and neither, a reset fails loudly; finished episodes are reported in
`infos[i]["curriculum"]` and `infos[i]["episode"]` as `CurriculumEnv` does.
"""

from __future__ import annotations

import numpy as np

from acl3d.envs.batched import BatchedEnvs
from acl3d.envs.curriculum_wrapper import CurriculumWorker, TaskQueue, played_task
from acl3d.envs.episode_statistics import EpisodeBatch, EpisodeStatistics
from acl3d.extras import optional_dependency

with optional_dependency("the batched env's Stable-Baselines3 VecEnv"):
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv


class SubEnv(CurriculumWorker):
    """Sub-env i of a `BatchedVecEnv`: its curriculum worker (`TaskQueue`) and its single env."""

    def __init__(self, owner: BatchedVecEnv, index: int):
        self._owner, self._index = owner, index
        self.env = owner.batch.envs[index]
        self.queue = TaskQueue(self.env.curriculum_profile.success_return)

    # ------------------------------------------------------------------ CurriculumEnv API
    def get_state(self) -> dict:
        """As `CurriculumEnv.get_state`: queue, running episode and the single env's state (a
        batched env's sub-envs are acl3d envs: each a `SnapshotEnv`)."""
        self._owner.batch.sync(self._index)
        return self.queue.get_state(
            self.episode_return,
            int(self._owner.stats.lengths[self._index]),
            self.last_obs,
            self.env.get_state(),
            len(self.env.task_vector),
        )

    def set_state(self, state: dict) -> None:
        self.env.set_state(state["env"])
        batch = self._owner.batch
        batch.restored(self._index)
        self.queue.set_state(state)
        stats, i = self._owner.stats, self._index
        stats.tasks[i] = self.env.task_vector if state["task"] is None else state["task"]
        stats.returns[i], stats.lengths[i] = float(state["return"]), int(state["length"])
        batch.elapsed[i] = int(state["length"])
        if state["last_obs"] is not None:
            if self._owner.last_obs is None:
                owner = self._owner
                owner.last_obs = np.zeros(
                    (owner.num_envs, *owner.observation_space.shape), np.float32
                )
            self._owner.last_obs[self._index] = state["last_obs"]

    @property
    def episode_return(self) -> float:
        return float(self._owner.stats.returns[self._index])

    @property
    def last_obs(self):
        last = self._owner.last_obs
        return None if last is None else last[self._index].copy()

    # ------------------------------------------------------------------ the single env
    def __getattr__(self, name):
        if name.startswith("__") or name == "env":
            raise AttributeError(name)
        self._owner.batch.sync(self._index)
        return getattr(self.env, name)

    def reset(self, seed=None, options=None):
        """Start an episode: the task from `options`, else the queue (filled by the owner's
        `curriculum_sync` where it has one)."""
        owner = self._owner
        options = dict(options or {})
        if "task" in options or self.queue.tasks or owner.curriculum:
            options = self.queue.options(options)
        obs, info = owner.batch.reset_one(self._index, seed, options)
        task = played_task(self.env, options.get("task", self.env.task_vector))
        self.queue.begin(task, obs)
        owner.stats.begin(np.array([self._index]), np.asarray(task)[None], np.asarray(obs)[None])
        return obs, info


class BatchedVecEnv(VecEnv):
    """N acl3d envs of one id in this process, as an SB3 VecEnv (see the module docstring).

    Args:
        env_id, num_envs, threads, max_episode_steps, **env_kwargs: as `BatchedEnvs`.
        curriculum: every reset needs a task (queued, from `curriculum_sync`, or in the
            reset options), as behind `CurriculumEnv`; False plays the env's current task.
    """

    def __init__(
        self,
        env_id: str,
        num_envs: int,
        threads: int | None = None,
        curriculum: bool = False,
        max_episode_steps: int | None = None,
        **env_kwargs,
    ):
        self.batch = BatchedEnvs(env_id, num_envs, threads, max_episode_steps, **env_kwargs)
        self.stats = EpisodeStatistics(self.batch.num_envs, self.batch.task_space.dim)
        self.last_obs = None  # the latest observations, (N, obs)
        self.subenvs = [SubEnv(self, i) for i in range(self.batch.num_envs)]
        super().__init__(
            self.batch.num_envs, self.batch.single_observation_space, self.batch.single_action_space
        )
        self.curriculum = bool(curriculum)
        self.curriculum_sync = None  # a CurriculumSync, set by the one that drives the curriculum
        self._actions = None

    def reset(self):
        seeds, options = self.batch.seeds(self._seeds), self._options
        self._pull(np.arange(self.num_envs), EpisodeBatch.empty(self.batch.task_space.dim), options)
        results = [s.reset(seeds[i], options[i]) for i, s in enumerate(self.subenvs)]
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = [info for _, info in results]
        self.last_obs = np.stack([obs for obs, _ in results])
        return self.last_obs.copy()

    def _pull(self, ids, finished: EpisodeBatch, options=None) -> None:
        """Hand `finished` to the curriculum sync and queue the tasks it returns for the
        sub-envs of `ids` that will reset without a task (no queued one, none in options)."""
        if self.curriculum_sync is None:
            return
        subenvs = self.subenvs
        pull = [
            i for i in ids
            if not subenvs[i].queue.tasks and not (options and "task" in (options[i] or {}))
        ]  # fmt: skip
        if pull or len(finished):
            tasks = self.curriculum_sync.sync(finished, np.asarray(pull, dtype=np.int64))
            for i, task in zip(pull, tasks):
                subenvs[i].queue.push(task)

    def step_async(self, actions) -> None:
        self._actions = self.batch.check_actions(actions)

    def step_wait(self):
        if self._actions is None:
            raise RuntimeError("step_wait() without step_async()")
        actions, self._actions = self._actions, None
        step = self.batch.step(actions)
        obs, rewards, terminated, truncated = step[:4]
        infos = step.infos()
        dones = self.stats.step(rewards, terminated, truncated, step.success)
        finished = self.stats.pop()
        subenvs = self.subenvs
        for k, i in enumerate(finished.env_ids):
            info = infos[i]
            info["TimeLimit.truncated"] = bool(finished.truncated[k])
            info["terminal_observation"] = obs[i].copy()
            subenvs[i].queue.report(
                info, float(finished.returns[k]), int(finished.lengths[k]),
                bool(terminated[i]), bool(truncated[i]),
            )  # fmt: skip
        self._pull(finished.env_ids, finished)
        for i in finished.env_ids:
            obs[i] = subenvs[i].reset()[0]
        self.last_obs = obs.copy()
        return obs, rewards.astype(np.float32), dones, infos

    def close(self) -> None:
        self.batch.close()

    # ------------------------------------------------------------------ dispatch
    def get_attr(self, attr_name, indices=None):
        return [getattr(self.subenvs[i], attr_name) for i in self._get_indices(indices)]

    def set_attr(self, attr_name, value, indices=None) -> None:
        for i in self._get_indices(indices):
            self.batch.sync(i)
            setattr(self.subenvs[i].env, attr_name, value)
            self.batch.restored(i)

    def env_method(self, method_name, *method_args, indices=None, **method_kwargs):
        return [
            getattr(self.subenvs[i], method_name)(*method_args, **method_kwargs)
            for i in self._get_indices(indices)
        ]

    def env_is_wrapped(self, wrapper_class, indices=None):
        return [False for _ in self._get_indices(indices)]

    def get_images(self):
        images = []
        for i, s in enumerate(self.subenvs):
            self.batch.sync(i)
            images.append(s.env.render())
        return images
