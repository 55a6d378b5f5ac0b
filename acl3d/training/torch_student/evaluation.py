"""The test set played as many worlds at once: test task k is world k of a batched env.

All test tasks start together (up to `MAX_ENVS` worlds; a larger test set is played in chunks of
that many), each world seeded `eval_seed + k`, and the pass ends when every world has finished
its first episode. An evaluation plays `PolicySnapshot`s: on the many-world simulation several
snapshots (the policies of several evaluation steps) play side by side, each on its own copy of
the test set, in one pass whose steps cost what one snapshot's would. Sampled actions come from
a generator of each snapshot's own, seeded with the evaluation seed plus the chunk's first task
index, so a snapshot's results depend only on its weights and the seed, not on what it was
played beside, and training's random streams stay as they were.
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
from acl3d.training.torch_student.policy_stack import PolicyStack

CHECK_EVERY = 32  # steps between the many-world evaluator's host checks


class _Outcomes:
    """One snapshot's results over the test set, filled chunk by chunk."""

    def __init__(self, n_tasks: int):
        self.returns, self.lengths = np.zeros(n_tasks), np.zeros(n_tasks, dtype=np.int64)
        self.successes = np.zeros(n_tasks, dtype=bool)


class ChunkedEvaluator(ABC):
    """Plays the test set in chunks of `num_worlds` tasks (one world each), `copies` snapshots
    at a time; subclasses set `tasks`, `seed`, `num_worlds`, `copies`, `success_return` and
    `device`, and play one chunk in `_play`."""

    tasks: np.ndarray
    seed: int
    num_worlds: int
    copies: int
    success_return: float
    device: torch.device

    def run(self, policies: list, stochastic: bool) -> list[EvalResult]:
        """The results of each of `policies` (`PolicySnapshot`s on the worlds' device): sampled
        actions (`stochastic`) or the mean ones."""
        n_tasks, results = len(self.tasks), []
        for lo in range(0, len(policies), self.copies):
            group = policies[lo : lo + self.copies]
            outcomes = [_Outcomes(n_tasks) for _ in group]
            with own_random_streams(self.seed):
                for start in range(0, n_tasks, self.num_worlds):
                    chunk = np.arange(start, min(start + self.num_worlds, n_tasks))
                    # each chunk's own stream: a chunk lasts as long as its slowest block, so
                    # a stream carried over would depend on the policies played beside
                    generators = [
                        torch.Generator(self.device).manual_seed(self.seed + start)
                        if stochastic
                        else None
                        for _ in group
                    ]
                    self._play(group, generators, chunk, outcomes)
            tasks = self.tasks.astype(np.float64)
            results += [
                EvalResult(tasks, o.returns, o.lengths, o.successes, self.success_return)
                for o in outcomes
            ]
        return results

    @abstractmethod
    def _play(self, policies, generators, chunk: np.ndarray, outcomes) -> None:
        """Play test tasks `chunk` at once with each policy; write into its `_Outcomes`."""


class WorldEvaluator(ChunkedEvaluator):
    """Evaluates snapshots one after another on the CPU batched env of `env` (`body`,
    `env_kwargs`) with `seed` (a run's evaluation seed: the same every pass), `eval_envs` worlds
    at a time (None: one per test task, up to `MAX_ENVS`)."""

    def __init__(self, env: str, body: str, env_kwargs: dict, tasks, seed: int, eval_envs=None):
        self.tasks = np.atleast_2d(np.asarray(tasks, dtype=np.float32))
        self.seed, self.copies, self.device = int(seed), 1, torch.device("cpu")
        self.num_worlds = int(min(len(self.tasks), eval_envs or MAX_ENVS, MAX_ENVS))
        self.vector = BatchedVectorEnv(env, self.num_worlds, body=body, **env_kwargs)
        self.observation_shape = self.vector.single_observation_space.shape
        self.success_return = float(self.vector.envs[0].curriculum_profile.success_return)

    def _play(self, policies, generators, chunk: np.ndarray, outcomes) -> None:
        (policy,), (generator,), (out,) = policies, generators, outcomes
        n = self.num_worlds
        index = [chunk[min(i, len(chunk) - 1)] for i in range(n)]  # spare worlds replay the last
        options = [{"task": self.tasks[k]} for k in index]
        obs, _ = self.vector.reset(seed=[self.seed + k for k in index], options=options)
        running = np.arange(n) < len(chunk)
        while running.any():
            actions = policy(torch.from_numpy(np.asarray(obs, dtype=np.float32)), generator)
            obs, _, terminated, truncated, infos = self.vector.step(actions.cpu().numpy())
            for i in np.flatnonzero((terminated | truncated) & running):
                report, k = infos[INFO_KEY][i], index[i]
                out.returns[k], out.lengths[k], out.successes[k] = (
                    report["return"],
                    report["length"],
                    report["success"],
                )
                running[i] = False

    def close(self) -> None:
        self.vector.close()


class ManyWorldEvaluator(ChunkedEvaluator):
    """`WorldEvaluator` on the many-world simulation (MuJoCo Warp, on `device`): `copies` blocks of
    `num_worlds` worlds on the run's device, test task k world k of each block, snapshot b
    playing block b; every block draws the same terrain from the evaluation seed, so every pass
    plays the same tracks."""

    def __init__(self, env: str, body: str, env_kwargs: dict, tasks, seed: int, eval_envs,
                 device, copies: int = 1):  # fmt: skip
        self.tasks = np.atleast_2d(np.asarray(tasks, dtype=np.float64))
        self.seed, self.copies, self.device = int(seed), int(copies), torch.device(device)
        self.num_worlds = int(min(len(self.tasks), eval_envs or MAX_ENVS, MAX_ENVS))
        self.worlds = many_worlds(
            env, self.num_worlds * self.copies, device, autoreset=False, body=body, **env_kwargs
        )
        self.observation_shape = (self.worlds.observation_size,)
        self.success_return = float(self.worlds.curriculum_profile.success_return)

    def _play(self, policies, generators, chunk: np.ndarray, outcomes) -> None:
        """Each world's first episode, its results kept on the device as it ends; the host
        asks whether any world still runs once every `CHECK_EVERY` steps only. The snapshots
        act as one `PolicyStack`; blocks beyond those given replay the last one on its mean
        actions (their results are not read)."""
        worlds, n, k = self.worlds, self.num_worlds, len(chunk)
        index = np.minimum(chunk[0] + np.arange(n), chunk[-1])  # spare worlds replay the last
        worlds.tasks[:] = np.tile(self.tasks[index], (self.copies, 1))
        obs = worlds.reset(seed=self.seed + int(chunk[0]), period=n)
        spare = len(policies) - 1
        stack = PolicyStack([policies[min(b, spare)] for b in range(self.copies)])
        generators = [generators[b] if b <= spare else None for b in range(self.copies)]
        world = torch.arange(n * self.copies, device=worlds.device)
        running = (world % n < k) & (world // n < len(policies))  # spare blocks: not waited for
        ended_with = None
        for step in itertools.count(1):
            obs, _, terminated, truncated, infos = worlds.step(stack(obs, generators))
            ended = (terminated | truncated) & running
            now = [infos[key] for key in ("episode_return", "episode_length", "success")]
            ended_with = now if ended_with is None else ended_with
            ended_with = [torch.where(ended, a, b) for a, b in zip(now, ended_with)]
            running &= ~ended
            if step % CHECK_EVERY == 0 and not bool(running.any()):
                break
        values = [value.cpu().numpy().reshape(self.copies, n)[:, :k] for value in ended_with]
        for b, out in enumerate(outcomes):
            out.returns[chunk], out.lengths[chunk], out.successes[chunk] = (v[b] for v in values)

    def close(self) -> None:
        self.worlds.close()
