"""Leaving some transitions out of the student's updates: Robust PLR's "no policy update on new
levels".

Robust PLR (PLR⊥) and ACCEL train the student only on replayed levels; the episodes of new and
edited levels serve to score them. In acl3d every env draws its own level per episode and
episodes run across rollouts, so a collection mixes both kinds: the buffer carries an `excluded`
flag per (step, env), written during collection from the curriculum's flags (SB3 calls
`callback.on_step()` right before it adds the step's transitions), and updates use kept
transitions only.

* PPO: minibatches hold kept transitions only. Excluded transitions still bound the GAE of their
  own episode (advantages never cross an episode boundary) and still update VecNormalize's
  running statistics (the environment's, not the student's). A rollout that keeps nothing skips
  the update.
* SAC: excluded transitions stay in the replay buffer (its layout stores all envs of a step
  together) but are never sampled; while the buffer keeps none, gradient steps are skipped.
"""

from __future__ import annotations

from collections.abc import Generator

import numpy as np
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.buffers import ReplayBuffer, RolloutBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples, RolloutBufferSamples

_FLATTENED = ("observations", "actions", "values", "log_probs", "advantages", "returns")


class ExcludingRolloutBuffer(RolloutBuffer):
    """A PPO rollout buffer whose `get()` yields only the transitions not marked `excluded`.

    `excluded[pos, env]` is written before the transition at `pos` is added. Minibatches come
    from the same `np.random.permutation` draw as SB3's, filtered to kept transitions: the global
    RNG advances exactly as without exclusions, and with none excluded the minibatches are SB3's.
    """

    def reset(self) -> None:
        super().reset()
        self.excluded = np.zeros((self.buffer_size, self.n_envs), dtype=bool)

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
        if getattr(self.rollout_buffer, "kept", None) == 0:
            self.logger.record("train/skipped_update", 1)
            return
        super().train()


class ExcludingReplayBuffer(ReplayBuffer):
    """A SAC replay buffer that never samples the transitions marked `excluded`.

    Samples are SB3's draws (a uniform step, then a uniform env) with excluded pairs drawn again
    until kept: uniform over the kept transitions, and SB3's own samples when none is excluded.
    """

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if self.optimize_memory_usage:
            raise ValueError(
                "optimize_memory_usage=True: not supported when excluding transitions (the next "
                "observation is the next slot's, which may be excluded); valid: False"
            )
        self.excluded = np.zeros((self.buffer_size, self.n_envs), dtype=bool)

    def reset(self) -> None:
        super().reset()
        self.excluded[:] = False

    def _filled(self) -> np.ndarray:
        return self.excluded if self.full else self.excluded[: self.pos]

    @property
    def kept(self) -> int:
        """Transitions stored and available to sampling."""
        filled = self._filled()
        return int(filled.size - np.count_nonzero(filled))

    @property
    def excluded_fraction(self) -> float:
        filled = self._filled()
        return float(np.count_nonzero(filled) / filled.size) if filled.size else 0.0

    def _get_samples(self, batch_inds: np.ndarray, env=None) -> ReplayBufferSamples:
        upper = self.buffer_size if self.full else self.pos
        batch_inds = np.array(batch_inds)
        env_inds = np.random.randint(0, high=self.n_envs, size=(len(batch_inds),))
        redraw = self.excluded[batch_inds, env_inds]
        if redraw.all() and self.kept == 0:
            raise ValueError("the replay buffer holds no kept transition to sample")
        while redraw.any():
            n = int(np.count_nonzero(redraw))
            batch_inds[redraw] = np.random.randint(0, upper, size=n)
            env_inds[redraw] = np.random.randint(0, high=self.n_envs, size=n)
            redraw = self.excluded[batch_inds, env_inds]
        done = self.dones[batch_inds, env_inds] * (1 - self.timeouts[batch_inds, env_inds])
        data = (
            self._normalize_obs(self.observations[batch_inds, env_inds, :], env),
            self.actions[batch_inds, env_inds, :],
            self._normalize_obs(self.next_observations[batch_inds, env_inds, :], env),
            done.reshape(-1, 1),
            self._normalize_reward(self.rewards[batch_inds, env_inds].reshape(-1, 1), env),
        )
        return ReplayBufferSamples(*tuple(map(self.to_torch, data)))


class ExcludingSAC(SAC):
    """SB3's SAC, except that no gradient step is taken while the replay buffer keeps no
    transition; with any other buffer it is SAC itself. acl3d's `sac` student."""

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        if getattr(self.replay_buffer, "kept", None) == 0:
            self.logger.record("train/skipped_update", 1)
            return
        super().train(gradient_steps, batch_size)
