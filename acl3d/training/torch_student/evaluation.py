"""The test set played as many worlds at once: test task k is world k of a batched env.

All test tasks start together (up to `MAX_ENVS` worlds; a larger test set is played in chunks of
that many), each world seeded `eval_seed + k`, and the pass ends when every world has finished
its first episode. The policy gets (N, obs) tensors; evaluation draws from its own random
streams, so training continues exactly as without it.
"""

from __future__ import annotations

import itertools
from abc import ABC, abstractmethod

import numpy as np
import torch

from acl3d.envs.batched import MAX_ENVS
from acl3d.envs.batched_vector import BatchedVectorEnv
from acl3d.envs.curriculum_wrapper import INFO_KEY
from acl3d.envs.many_worlds import many_worlds
from acl3d.training.evaluation import EvalResult, own_random_streams

CHECK_EVERY = 32  # steps between the many-world evaluator's host checks


class ChunkedEvaluator(ABC):
    """Plays the test set in chunks of `num_worlds` tasks (one world each); subclasses set
    `tasks`, `seed`, `num_worlds`, `success_return` and play one chunk in `_play`."""

    tasks: np.ndarray
    seed: int
    num_worlds: int
    success_return: float

    def run(self, policy) -> EvalResult:
        """`policy((N, obs) float32 tensor) -> (N, act) tensor` (on the worlds' device)."""
        n_tasks = len(self.tasks)
        returns, lengths = np.zeros(n_tasks), np.zeros(n_tasks, dtype=np.int64)
        successes = np.zeros(n_tasks, dtype=bool)
        with own_random_streams(self.seed):
            for start in range(0, n_tasks, self.num_worlds):
                chunk = np.arange(start, min(start + self.num_worlds, n_tasks))
                self._play(policy, chunk, returns, lengths, successes)
        return EvalResult(
            self.tasks.astype(np.float64), returns, lengths, successes, self.success_return
        )

    @abstractmethod
    def _play(self, policy, chunk: np.ndarray, returns, lengths, successes) -> None:
        """Play test tasks `chunk` at once; write their results into the arrays."""


class WorldEvaluator(ChunkedEvaluator):
    """Evaluates a policy on `tasks` with the run's evaluation seed (the same every pass)."""

    def __init__(self, config, tasks):
        self.tasks = np.atleast_2d(np.asarray(tasks, dtype=np.float32))
        self.seed = config.eval_seed
        self.num_worlds = int(min(len(self.tasks), config.eval_envs or MAX_ENVS, MAX_ENVS))
        self.vector = BatchedVectorEnv(
            config.env, self.num_worlds, body=config.body, **config.env_kwargs
        )
        self.success_return = float(self.vector.envs[0].curriculum_profile.success_return)

    def _play(self, policy, chunk: np.ndarray, returns, lengths, successes) -> None:
        n = self.num_worlds
        index = [chunk[min(i, len(chunk) - 1)] for i in range(n)]  # spare worlds replay the last
        options = [{"task": self.tasks[k]} for k in index]
        obs, _ = self.vector.reset(seed=[self.seed + k for k in index], options=options)
        running = np.arange(n) < len(chunk)
        while running.any():
            actions = policy(torch.from_numpy(np.asarray(obs, dtype=np.float32)))
            obs, _, terminated, truncated, infos = self.vector.step(actions.cpu().numpy())
            for i in np.flatnonzero((terminated | truncated) & running):
                report, k = infos[INFO_KEY][i], index[i]
                returns[k], lengths[k], successes[k] = (
                    report["return"],
                    report["length"],
                    report["success"],
                )
                running[i] = False

    def close(self) -> None:
        self.vector.close()


class ManyWorldEvaluator(ChunkedEvaluator):
    """`WorldEvaluator` on the many-world simulation (MuJoCo Warp): test task k is world k of
    one `ManyWorldTracks` on the run's device, all played at once; the terrain draws come from
    the evaluation seed, so every pass plays the same tracks."""

    def __init__(self, config, tasks, device):
        self.tasks = np.atleast_2d(np.asarray(tasks, dtype=np.float64))
        self.seed = config.eval_seed
        self.num_worlds = int(min(len(self.tasks), config.eval_envs or MAX_ENVS, MAX_ENVS))
        self.worlds = many_worlds(
            config.env, self.num_worlds, device, autoreset=False, body=config.body,
            **config.env_kwargs,
        )  # fmt: skip
        self.success_return = float(self.worlds.curriculum_profile.success_return)

    def _play(self, policy, chunk: np.ndarray, returns, lengths, successes) -> None:
        """Each world's first episode, its results kept on the device as it ends; the host
        asks whether any world still runs once every `CHECK_EVERY` steps only."""
        worlds, n, k = self.worlds, self.num_worlds, len(chunk)
        index = np.minimum(chunk[0] + np.arange(n), chunk[-1])  # spare worlds replay the last
        worlds.tasks[:] = self.tasks[index]
        obs = worlds.reset(seed=self.seed + int(chunk[0]))
        running = torch.arange(n, device=worlds.device) < k
        ended_with = None
        for step in itertools.count(1):
            obs, _, terminated, truncated, infos = worlds.step(policy(obs))
            ended = (terminated | truncated) & running
            now = [infos[key] for key in ("episode_return", "episode_length", "success")]
            ended_with = now if ended_with is None else ended_with
            ended_with = [torch.where(ended, a, b) for a, b in zip(now, ended_with)]
            running &= ~ended
            if step % CHECK_EVERY == 0 and not bool(running.any()):
                break
        ret, length, success = (value[:k].cpu().numpy() for value in ended_with)
        returns[chunk], lengths[chunk], successes[chunk] = ret, length, success

    def close(self) -> None:
        self.worlds.close()
