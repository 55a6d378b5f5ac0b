"""Gymnasium's vector API over the many-world simulation: `device=` on `make_vec` picks MuJoCo Warp.

    envs = gymnasium.make_vec("acl3d/StumpTracks-v0", num_envs=4096,
                              vectorization_mode="vector_entry_point", device="cuda")

gives a `WarpVectorEnv`: the same spaces, `reset` and `step` as the CPU batched vector env, but
observations, rewards and flags are torch tensors on that device (actions may be tensors or
arrays), every world of one `ManyWorlds`, finished worlds reset in the same step
(`AutoresetMode.SAME_STEP`; `infos["final_obs"]` holds their last observations). A `teacher`
(or a `curriculum_sync`) picks each world's next task; without one, `reset(options={"task": t})`
sets every world's task. Every family: Stump Tracks, Hexagon Tracks, Parkour (its movable
creepers refused by name: they stay on the CPU batched env) and 3D Terrain.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from acl3d import validation
from acl3d.envs.episode_statistics import TeacherSync
from acl3d.envs.many_worlds import many_worlds


class WarpVectorEnv(VectorEnv):
    """N worlds of `env_id` on MuJoCo Warp behind Gymnasium's vector API (module docstring).

    Args:
        env_id: an acl3d id or short name of a family the many-world simulation runs.
        num_envs: worlds, in [1, 2**20].
        device: "cuda" (a GPU, or "cuda:N") or "cpu" (Warp's CPU device); one this machine
            lacks is refused naming it.
        teacher / curriculum_sync: where each world's next task comes from (exclusive).
        autoreset_mode: SAME_STEP only (the worlds reset within the step that ends them).
        **env_kwargs: the single env's arguments (body, planar, max_episode_steps, ...).
    """

    def __init__(
        self,
        env_id: str,
        num_envs: int,
        device,
        teacher=None,
        curriculum_sync=None,
        autoreset_mode=AutoresetMode.SAME_STEP,
        **env_kwargs,
    ):
        if teacher is not None and curriculum_sync is not None:
            raise ValueError("teacher and curriculum_sync are exclusive: give one of them")
        if autoreset_mode not in (AutoresetMode.SAME_STEP, "SAME_STEP", "SameStep"):
            raise validation.fail(
                "autoreset_mode", autoreset_mode, "AutoresetMode.SAME_STEP with device="
            )
        sync = TeacherSync(teacher) if teacher is not None else curriculum_sync
        self.worlds = many_worlds(env_id, num_envs, device, curriculum=sync, **env_kwargs)
        template = self.worlds.template
        self.num_envs, self.device = self.worlds.num_envs, self.worlds.device
        self.metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}
        self.single_observation_space = template.observation_space
        self.single_action_space = template.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.task_space = self.worlds.task_space

    def reset(self, *, seed: int | None = None, options: Mapping | None = None):
        """(obs (N, obs) tensor, {}); `options={"task": t}` (a dict or a vector) sets every
        world's task when no teacher picks them."""
        if options is not None:
            unknown = set(options) - {"task"}
            if not isinstance(options, Mapping) or unknown:
                raise validation.fail("options", options, "None or {'task': ...}")
            task = options["task"]
            if isinstance(task, Mapping):
                vector = self.task_space.to_vector(task)
            else:
                vector = self.task_space.validate_vector(task)
            self.worlds.template.composition.check_buildable(self.task_space.to_dict(vector))
            self.worlds.tasks[:] = vector
        return self.worlds.reset(seed), {}

    def step(self, actions):
        """(obs, rewards, terminated, truncated, infos) as tensors on the device; each info
        (final_obs, success, unstable, episode_return, episode_length) holds the rows of the
        worlds that finished, which `infos["_" + key]` flags, as Gymnasium's vector envs lay
        infos out."""
        if not isinstance(actions, torch.Tensor):
            array = np.asarray(actions)
            if array.dtype.kind not in "iuf":  # bools, complex numbers, strings and objects
                raise ValueError(f"actions: expected real numbers, got dtype {array.dtype}")
            actions = torch.as_tensor(array)
        elif actions.dtype == torch.bool or actions.is_complex():
            raise ValueError(f"actions: expected real numbers, got dtype {actions.dtype}")
        if not bool(torch.isfinite(actions).all()):
            raise ValueError("actions: non-finite values")
        obs, reward, terminated, truncated, infos = self.worlds.step(actions.to(self.device))
        finished = terminated | truncated
        infos.update({f"_{key}": finished for key in list(infos)})
        return obs, reward, terminated, truncated, infos

    def close_extras(self, **kwargs) -> None:
        self.worlds.close()
