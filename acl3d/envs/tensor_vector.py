"""Many worlds as torch tensors: the interface a torch-native student trains on.

`TensorVectorEnv` is the whole contract between such a student and a simulation. It is kept
small so that a CPU batch (`CpuTensorVectorEnv`, below) and a many-world GPU simulation (MuJoCo
Warp) implement the same thing and the student's loop never changes:

* `num_envs`, `device`, `observation_size`, `action_size`: ints and a `torch.device`.
* `reset(seed)` -> obs, an (N, observation_size) float32 tensor on `device`. World i is seeded
  `seed + i` (None: unseeded). Every world starts an episode.
* `step(actions)` with an (N, action_size) float tensor on `device` (actions outside the action
  bounds are the caller's to clip) -> `(obs, rewards, terminated, truncated, infos)`:
  obs (N, observation_size) float32, rewards (N,) float32, terminated and truncated (N,) bool.
  A world whose episode ended (terminated or truncated) is reset within the same step
  (autoreset): its row of `obs` is already the first observation of its next episode.
* `infos` is a dict of tensors with N rows, at least
  `final_obs` (N, observation_size): the last observation of the episode that ended in each
  finished world (for bootstrapping a value at a time limit); rows of other worlds hold their
  `obs`. `success` (N,) bool: the env's success flag of this step.
* `close()` frees the simulation.

Nothing in the contract is per-world Python; tensors stay on `device`. How a world's next task
is chosen (the curriculum) is an argument of the implementation's constructor, not part of the
contract: `CpuTensorVectorEnv` takes a `CurriculumSync` (`acl3d.envs.episode_statistics`), handed
each step's finished episodes and asked for the next tasks of the worlds that reset, in one call.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import torch
from gymnasium.vector import AutoresetMode

from acl3d.envs.batched_vector import BatchedVectorEnv


class TensorVectorEnv(Protocol):
    """N worlds stepped together on torch tensors (see the module docstring)."""

    num_envs: int
    device: torch.device
    observation_size: int
    action_size: int

    def reset(self, seed: int | None = None) -> torch.Tensor: ...

    def step(
        self, actions: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, dict[str, torch.Tensor]]: ...

    def close(self) -> None: ...


class CpuTensorVectorEnv:
    """`TensorVectorEnv` over the CPU batched vector env (same-step autoreset).

    Observations and flags come from the batched env's numpy arrays without a copy per world
    (`torch.from_numpy`), so world i plays exactly what sub-env i of `BatchedVectorEnv` plays.

    Args:
        env_id, num_envs, threads, **env_kwargs: as `acl3d.envs.batched.BatchedEnvs`.
        curriculum_sync: the curriculum (`sync(finished, env_ids) -> tasks`), or None.
    """

    device = torch.device("cpu")

    def __init__(
        self,
        env_id: str,
        num_envs: int,
        threads: int | None = None,
        curriculum_sync=None,
        **env_kwargs,
    ):
        self.vector = BatchedVectorEnv(
            env_id,
            num_envs,
            threads=threads,
            autoreset_mode=AutoresetMode.SAME_STEP,
            curriculum_sync=curriculum_sync,
            **env_kwargs,
        )
        self.num_envs = self.vector.num_envs
        self.observation_size = int(np.prod(self.vector.single_observation_space.shape))
        self.action_size = int(self.vector.single_action_space.shape[0])
        self.action_low = torch.as_tensor(self.vector.single_action_space.low, dtype=torch.float32)
        self.action_high = torch.as_tensor(
            self.vector.single_action_space.high, dtype=torch.float32
        )
        self.task_space = self.vector.task_space

    def reset(self, seed: int | None = None) -> torch.Tensor:
        obs, _ = self.vector.reset(seed=seed)
        return _floats(obs)

    def step(self, actions: torch.Tensor):
        out = self.vector.step_arrays(actions.detach().numpy())
        obs = _floats(out.obs)
        final = obs if out.final_obs is None else _floats(out.final_obs)
        extras = {"final_obs": final, "success": torch.from_numpy(out.engine.success)}
        return (
            obs,
            _floats(out.rewards),
            torch.from_numpy(out.terminated),
            torch.from_numpy(out.truncated),
            extras,
        )

    # ------------------------------------------------------------------ exact snapshots
    def get_state(self) -> dict:
        """Every world's running episode (env state, step count) and the episode statistics,
        for a checkpoint that continues bit for bit."""
        batch = self.vector.batch
        worlds = []
        for i, env in enumerate(self.vector.envs):
            batch.sync(i)
            worlds.append({"env": env.get_state(), "length": int(batch.elapsed[i])})
        return {"worlds": worlds, "episodes": self.vector.stats.state_dict()}

    def set_state(self, state: dict) -> None:
        """Inverse of `get_state()` on an env built with the same arguments."""
        worlds = state["worlds"]
        if len(worlds) != self.num_envs:
            raise ValueError(f"state holds {len(worlds)} worlds; this env has {self.num_envs}")
        batch = self.vector.batch
        for i, world in enumerate(worlds):
            self.vector.envs[i].set_state(world["env"])
            batch.restored(i)
            batch.elapsed[i] = int(world["length"])
        self.vector.stats.load_state_dict(state["episodes"])

    def close(self) -> None:
        self.vector.close()


def _floats(array: np.ndarray) -> torch.Tensor:
    """A float32 tensor sharing `array`'s memory when it already is float32."""
    return torch.from_numpy(np.ascontiguousarray(array, dtype=np.float32))
