"""Leaving some transitions out of PPO's update: Robust PLR's "no policy update on new levels".

Robust PLR (PLR⊥) and ACCEL train the student only on replayed levels; the episodes of new and
edited levels serve to score them. In acl3d every env draws its own level per episode and
episodes run across rollouts, so a rollout mixes both kinds: the rollout buffer carries an
`excluded` flag per (step, env), set during collection from the curriculum's flags, and its
minibatches hold kept transitions only. Excluded transitions still bound the GAE of their own
episode (advantages never cross an episode boundary) and still update VecNormalize's running
statistics (the environment's, not the student's). A rollout that keeps nothing skips the update.
"""

from __future__ import annotations

from collections.abc import Generator

import numpy as np
from stable_baselines3 import PPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.type_aliases import RolloutBufferSamples

_FLATTENED = ("observations", "actions", "values", "log_probs", "advantages", "returns")


class ExcludingRolloutBuffer(RolloutBuffer):
    """A PPO rollout buffer whose `get()` yields only the transitions not marked `excluded`.

    `excluded[pos, env]` is written before the transition at `pos` is added (SB3 calls
    `callback.on_step()` right before `rollout_buffer.add()`). Minibatches come from the same
    `np.random.permutation` draw as SB3's, filtered to kept transitions: the global RNG advances
    exactly as without exclusions, and with none excluded the minibatches are SB3's own.
    """

    def reset(self) -> None:
        super().reset()
        self.excluded = np.zeros((self.buffer_size, self.n_envs), dtype=bool)

    @property
    def kept(self) -> int:
        """Transitions of the current rollout that the update will use."""
        return int(self.excluded.size - np.count_nonzero(self.excluded))

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
        if getattr(self.rollout_buffer, "kept", None) == 0:
            self.logger.record("train/skipped_update", 1)
            return
        super().train()
