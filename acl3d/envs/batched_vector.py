"""The batched env as a Gymnasium 1.x vector env: `gymnasium.make_vec(id, num_envs,
vectorization_mode="vector_entry_point", body=...)` for every acl3d id.

Same-step autoreset (declared in `metadata["autoreset_mode"]`): a sub-env that ends is reset
within the same `step`; its last observation and info are in `infos["final_obs"]` and
`infos["final_info"]` (masks `_final_obs`, `_final_info`), as `SyncVectorEnv` in that mode.
"""

from __future__ import annotations

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from acl3d.envs.batched import BatchedEnvs


class BatchedVectorEnv(VectorEnv):
    """N acl3d envs of `env_id` stepped together (see `acl3d.envs.batched.BatchedEnvs`)."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(self, env_id: str, num_envs: int, threads: int | None = None, **env_kwargs):
        self.batch = BatchedEnvs(env_id, num_envs, threads=threads, **env_kwargs)
        self.num_envs = self.batch.num_envs
        self.single_observation_space = self.batch.single_observation_space
        self.single_action_space = self.batch.single_action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.envs = self.batch.envs

    def reset(self, *, seed=None, options=None):
        """`seed`: None, an int s (sub-env i seeded s + i) or one per sub-env; `options`: a dict
        for all sub-envs (e.g. {"task": ...}) or one dict per sub-env."""
        obs, infos = self.batch.reset(seed, options)
        return obs, _stack_infos(infos, np.ones(self.num_envs, dtype=bool))

    def step(self, actions):
        obs, rewards, terminated, truncated, infos = self.batch.step(actions)
        out = _stack_infos(infos, np.ones(self.num_envs, dtype=bool))
        done = terminated | truncated
        if done.any():
            final_obs = np.empty(self.num_envs, dtype=object)
            final_infos: list[dict] = [{} for _ in range(self.num_envs)]
            for i in np.flatnonzero(done):
                final_obs[i], final_infos[i] = obs[i].copy(), infos[i]
                obs[i], reset_info = self.batch.reset_one(int(i))
            out["final_obs"], out["_final_obs"] = final_obs, done.copy()
            out["final_info"], out["_final_info"] = _stack_infos(final_infos, done), done.copy()
        return obs, rewards, terminated, truncated, out

    def close_extras(self, **kwargs):
        self.batch.close()


def _stack_infos(infos: list[dict], mask: np.ndarray) -> dict:
    """Gymnasium's vector info layout: per key an array over sub-envs and a `_key` mask."""
    out: dict = {}
    for key in sorted({k for info in infos for k in info}):
        values = [info.get(key) for info in infos]
        dtype = bool if all(isinstance(v, bool) or v is None for v in values) else object
        arr = np.zeros(len(infos), dtype=dtype)
        has = np.array([key in info for info in infos]) & mask
        arr[has] = [values[i] for i in np.flatnonzero(has)]
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
