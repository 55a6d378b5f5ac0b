"""Leaving some transitions out of the student's updates: Robust PLR's "no policy update on new
levels".

Robust PLR (PLR⊥) and ACCEL train the student only on replayed levels; the episodes of new and
edited levels serve to score them. In acl3d every env draws its own level per episode and
episodes run across rollouts, so a collection mixes both kinds: the buffer carries an `excluded`
flag per (step, env), given during collection from the curriculum's flags by `exclude_next()`
(SB3 calls `callback.on_step()` right before it adds the step's transitions), and updates use
kept transitions only.

* PPO: minibatches hold kept transitions only. Excluded transitions still bound the GAE of their
  own episode (advantages never cross an episode boundary) and still update VecNormalize's
  running statistics (the environment's, not the student's). A rollout that keeps nothing skips
  the update.
* SAC: excluded transitions stay in the replay buffer (its layout stores all envs of a step
  together) but are never sampled; while the buffer keeps none, gradient steps are skipped.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Generator

import numpy as np
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.buffers import ReplayBuffer, RolloutBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples, RolloutBufferSamples

_FLATTENED = ("observations", "actions", "values", "log_probs", "advantages", "returns")


class ExcludingBuffer(ABC):
    """A student's buffer that leaves marked transitions out of the updates: what the exclusion
    callback marks through and the students skip an update on."""

    @abstractmethod
    def exclude_next(self, flags) -> None:
        """Which of the transitions the next `add()` stores (one per env) are excluded."""

    @property
    @abstractmethod
    def kept(self) -> int:
        """Transitions the next update may use."""

    @property
    @abstractmethod
    def excluded_fraction(self) -> float:
        """The share of the buffer's transitions that are excluded."""


def keeps_nothing(buffer) -> bool:
    """The student's buffer excludes transitions and keeps none: its update is skipped (a plain
    SB3 buffer always updates)."""
    return isinstance(buffer, ExcludingBuffer) and buffer.kept == 0


class ExcludingRolloutBuffer(ExcludingBuffer, RolloutBuffer):
    """A PPO rollout buffer whose `get()` yields only the transitions not marked `excluded`.

    Minibatches come from the same `np.random.permutation` draw as SB3's, filtered to kept
    transitions: the global RNG advances exactly as without exclusions, and with none excluded
    the minibatches are SB3's.
    """

    def reset(self) -> None:
        super().reset()
        self.excluded = np.zeros((self.buffer_size, self.n_envs), dtype=bool)

    def exclude_next(self, flags) -> None:
        self.excluded[self.pos] = flags

    @property
    def kept(self) -> int:
        """Transitions of the current rollout that the update will use."""
        return int(self.excluded.size - np.count_nonzero(self.excluded))

    @property
    def excluded_fraction(self) -> float:
        return float(np.count_nonzero(self.excluded) / self.excluded.size)

    def get(self, batch_size: int | None = None) -> Generator[RolloutBufferSamples, None, None]:
        assert self.full, "the rollout buffer is not full"
        order = np.random.permutation(self.buffer_size * self.n_envs)
        keep = ~self.excluded.swapaxes(0, 1).reshape(-1)  # env-major, as swap_and_flatten
        order = order[keep[order]]
        if not self.generator_ready:
            for name in _FLATTENED:
                self.__dict__[name] = self.swap_and_flatten(self.__dict__[name])
            self.generator_ready = True
        if batch_size is None:
            batch_size = len(order)
        for start in range(0, len(order), batch_size):
            yield self._get_samples(order[start : start + batch_size])


class ExcludingPPO(PPO):
    """SB3's PPO, except that a rollout whose buffer keeps no transition skips the update (PPO
    would fail on it); with any other buffer it is PPO itself. acl3d's `ppo` student."""

    def train(self) -> None:
        if keeps_nothing(self.rollout_buffer):
            self.logger.record("train/skipped_update", 1)
            return
        super().train()


class ExcludingReplayBuffer(ExcludingBuffer, ReplayBuffer):
    """A SAC replay buffer that never samples the transitions marked `excluded`.

    With none excluded, samples are SB3's own draws; otherwise one uniform draw over the kept
    transitions (counted per stored step, kept up to date as transitions are added).
    """

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if self.optimize_memory_usage:
            raise ValueError(
                "optimize_memory_usage=True: not supported when excluding transitions (the next "
                "observation is the next slot's, which may be excluded); valid: False"
            )
        self.excluded = np.zeros((self.buffer_size, self.n_envs), dtype=bool)
        self._row_kept = np.zeros(self.buffer_size, dtype=np.int64)  # kept transitions per step
        self._next = np.zeros(self.n_envs, dtype=bool)

    def reset(self) -> None:
        super().reset()
        self.excluded[:] = False
        self._row_kept[:] = 0

    def exclude_next(self, flags) -> None:
        self._next[:] = flags

    def add(self, *args, **kwargs) -> None:
        self.excluded[self.pos] = self._next
        self._row_kept[self.pos] = self.n_envs - np.count_nonzero(self._next)
        self._next[:] = False
        super().add(*args, **kwargs)

    def set_excluded(self, excluded) -> None:
        """The flags of the first stored steps (a restored checkpoint's)."""
        excluded = np.asarray(excluded, dtype=bool)
        self.excluded[: len(excluded)] = excluded
        self._row_kept = self.n_envs - np.count_nonzero(self.excluded, axis=1)

    def _stored(self) -> int:
        return self.buffer_size if self.full else self.pos

    @property
    def kept(self) -> int:
        """Stored transitions available to sampling."""
        return int(self._row_kept[: self._stored()].sum())

    @property
    def excluded_fraction(self) -> float:
        stored = self._stored() * self.n_envs
        return 1.0 - self.kept / stored if stored else 0.0

    def sample(self, batch_size: int, env=None) -> ReplayBufferSamples:
        row_kept = self._row_kept[: self._stored()]
        total = int(row_kept.sum())
        if total == len(row_kept) * self.n_envs:
            return super().sample(batch_size, env=env)
        if total == 0:
            raise ValueError("the replay buffer holds no kept transition to sample")
        ends = np.cumsum(row_kept)
        draw = np.random.randint(0, total, size=batch_size)
        rows = np.searchsorted(ends, draw, side="right")
        rank = draw - (ends[rows] - row_kept[rows])  # the rank-th kept env of that step
        cols = np.argmax(np.cumsum(~self.excluded[rows], axis=1) > rank[:, None], axis=1)
        done = self.dones[rows, cols] * (1 - self.timeouts[rows, cols])
        data = (
            self._normalize_obs(self.observations[rows, cols, :], env),
            self.actions[rows, cols, :],
            self._normalize_obs(self.next_observations[rows, cols, :], env),
            done.reshape(-1, 1),
            self._normalize_reward(self.rewards[rows, cols].reshape(-1, 1), env),
        )
        return ReplayBufferSamples(*tuple(map(self.to_torch, data)))


class ExcludingSAC(SAC):
    """SB3's SAC, except that no gradient step is taken while the replay buffer keeps no
    transition; with any other buffer it is SAC itself. acl3d's `sac` student."""

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        if keeps_nothing(self.replay_buffer):
            self.logger.record("train/skipped_update", 1)
            return
        super().train(gradient_steps, batch_size)
