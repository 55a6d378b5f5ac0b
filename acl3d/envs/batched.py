"""N acl3d environments of one id in one process, stepped together.

`BatchedEnvs` is the engine under the Gymnasium vector env (`acl3d.envs.batched_vector`) and
the Stable-Baselines3 vec env (`acl3d.vec.batched_sb3`). Each sub-env is a full single env
(`TrackEnv` / `ParkourEnv`, built by the id's own entry point) with its own model, terrain, rules
and RNG stream, so sub-env i seeded s + i plays exactly what a single env seeded s + i plays.
Resets go through the sub-env's own `reset`.

The physics of all sub-envs is one `BatchPhysics` (`mujoco.batch` on the sub-envs' own models,
one call per step on its own C threads; a batch of one steps its sub-env's own MjData). Tracks,
3D Terrain and Parkour: the rules' step (`TrackRules.step`: observation, reward, termination, sensors, servo caps; Parkour's survival and
lidar) runs once on (N, ...) arrays, and each sub-env's running episode is its row of the
batch's `EpisodeRows` (the sub-env holds a view of it); Parkour's water forces and grasps run for
the envs that need them on their row of the batch. Ray-cast lidars (MuJoCo's rays): each
sub-env's own rules run before and after the batch step on its row (`RowPhysics`), one after the
other. Between steps the batch rows hold the physics; `sync(i)`
writes row i into sub-env i's own MjData before anything reads it (snapshots, rendering),
`restored(i)` takes a sub-env's MjData back after it was reset or set.
The time limit is the registered one (TimeLimit semantics: truncated once 2000 steps are played).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import gymnasium as gym
import numpy as np

from acl3d import validation
from acl3d.envs import env_id as resolve_env_id
from acl3d.envs.physics import BatchPhysics

MAX_ENVS = 4096


class EngineStep(NamedTuple):
    """One step of N sub-envs: (N, ...) arrays. `success` and `unstable` are the flags a
    single env's step info holds (`{"success": ..., "unstable": True}` when MuJoCo reset a
    diverged simulation); the wrappers lay them out as their APIs want."""

    obs: np.ndarray
    rewards: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    success: np.ndarray
    unstable: np.ndarray

    def info(self, i: int) -> dict:
        """Sub-env i's step info, as the single env's."""
        info = {"success": bool(self.success[i])}
        if self.unstable[i]:
            info["unstable"] = True
        return info

    def infos(self) -> list[dict]:
        """The single envs' step infos, one dict per sub-env."""
        infos = [{"success": s} for s in self.success.tolist()]
        for i in self.unstable.nonzero()[0]:
            infos[i]["unstable"] = True
        return infos


def default_threads() -> int:
    """One physics thread per core this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()


class BatchedEnvs:
    """N sub-envs of one registered acl3d id, stepped together (no autoreset: see the wrappers).

    Args:
        env_id: an acl3d id or short name ("acl3d/StumpTracks-v0", "parkour", ...).
        num_envs: number of sub-envs, in [1, 4096].
        threads: the batch's physics threads (default: one per core, at most `num_envs`).
        max_episode_steps: the time limit (default: the registered one, 2000).
        **env_kwargs: constructor arguments of every sub-env (body, planar, ...).
    """

    def __init__(
        self,
        env_id: str,
        num_envs: int,
        threads: int | None = None,
        max_episode_steps: int | None = None,
        **env_kwargs,
    ):
        num_envs = validation.integer("num_envs", num_envs, 1, MAX_ENVS)
        threads = (
            default_threads() if threads is None else validation.integer("threads", threads, 1, 256)
        )
        self.env_id = resolve_env_id(env_id)
        if max_episode_steps is None:
            max_episode_steps = gym.spec(self.env_id).max_episode_steps
        self.max_episode_steps = validation.integer(
            "max_episode_steps", max_episode_steps, 1, 10**9
        )
        self.envs = [
            gym.make(self.env_id, disable_env_checker=True, **env_kwargs).unwrapped
            for _ in range(num_envs)
        ]
        self.num_envs = num_envs
        e = self.envs[0]
        self.single_observation_space = e.observation_space
        self.single_action_space = e.action_space
        self.action_size = e.action_space.shape[0]
        self.task_space = e.task_space
        self.elapsed = np.zeros(num_envs, dtype=np.int64)
        self.threads = min(threads, num_envs)
        # every sub-env's physics is one batch (on its own threads), each on the sub-env's model;
        # a batch of one steps its env's own MjData, as the single env does (nothing to copy)
        if num_envs == 1:
            self.physics = e.physics
        else:
            models = [env.model for env in self.envs]
            self.physics = BatchPhysics(models, e.frame_skip, self.threads, e.rules.physics_fields)
        self._unsynced = np.zeros(num_envs, dtype=bool)  # rows ahead of the sub-env's MjData
        self.rules = e.rules  # every sub-env's rules compute the same: one steps them all
        # tracks, 3D Terrain and Parkour: one array step; ray-cast lidars: each sub-env's own
        # rules on its row of the batch
        self.vectorised = e.rules.steps_in_batch
        if self.vectorised:
            self.rows = self.rules.new_rows(num_envs)
            for i, env in enumerate(self.envs):
                env.rows = self.rows.row(i)
        self._rows_physics = [self.physics.row(i) for i in range(num_envs)]
        self._running = False  # every sub-env reset or restored: each stays in an episode

    # ------------------------------------------------------------------ resets
    def reset_one(self, i: int, seed: int | None = None, options: dict | None = None):
        """Reset sub-env i through its own `reset` (same RNG stream as a single env)."""
        obs, info = self.envs[i].reset(seed=seed, options=options)
        self.elapsed[i] = 0
        self.restored(i)
        return obs, info

    def reset(self, seed=None, options=None):
        """Reset all: `seed` None, an int s (sub-env i gets s + i) or one seed per sub-env;
        `options` None, one dict for all, or one dict per sub-env. Returns (obs, infos)."""
        seeds = self.seeds(seed)
        per_env = self.per_env_options(options)
        results = [self.reset_one(i, seeds[i], per_env[i]) for i in range(self.num_envs)]
        return np.stack([r[0] for r in results]), [r[1] for r in results]

    def seeds(self, seed) -> list:
        n = self.num_envs
        if seed is None:
            return [None] * n
        if isinstance(seed, np.ndarray) and seed.ndim == 1:
            seed = seed.tolist()
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            return [int(seed) + i for i in range(n)]
        if isinstance(seed, Sequence) and len(seed) == n:
            for s in seed:
                if s is not None and (isinstance(s, bool) or not isinstance(s, (int, np.integer))):
                    raise ValueError(f"seed={seed!r}; valid: None, an int or {n} ints/None")
            return [None if s is None else int(s) for s in seed]
        raise ValueError(f"seed={seed!r}; valid: None, an int or a sequence of {n} ints/None")

    def per_env_options(self, options) -> list:
        n = self.num_envs
        if options is None or isinstance(options, Mapping):
            return [options] * n
        if isinstance(options, Sequence) and len(options) == n:
            return list(options)
        raise ValueError(f"options={options!r}; valid: None, a dict or a sequence of {n} dicts")

    # ------------------------------------------------------------------ steps
    def check_actions(self, actions) -> np.ndarray:
        """(N, action_size) float64 copy, or ValueError (nothing changed)."""
        a = np.asarray(actions)
        expected = (self.num_envs, self.action_size)
        if a.shape != expected:
            raise ValueError(f"actions: expected shape {expected}, got {a.shape}")
        if a.dtype.kind not in "iuf":  # bools, complex numbers, strings and objects refused
            raise ValueError(f"actions: expected real numbers, got dtype {a.dtype}")
        a = a.astype(np.float64)
        if not np.isfinite(a).all():
            bad = sorted({int(i) for i in np.argwhere(~np.isfinite(a))[:, 0]})
            raise ValueError(f"actions: non-finite values for sub-env(s) {bad}")
        return a

    def step(self, actions) -> EngineStep:
        """One step of every sub-env as arrays (no reset of finished sub-envs); before every
        sub-env has been reset, gymnasium's ResetNeeded (nothing changed)."""
        if not self._running:
            self._running = all(env.physics.stepped for env in self.envs)
            if not self._running:
                raise gym.error.ResetNeeded("step() before reset(): call reset() first")
        a = self.check_actions(actions)
        if self.vectorised:
            played = self.rules.before_physics(self.physics, a, self.rows)
            self.rules.servo(played, self.physics)
            self._step_physics()
            obs, rewards, terminated, unstable = self.rules.step(self.physics, a, self.rows)
            success = self.rows.success.copy()
        else:
            rows = self._rows_physics
            for env, action, row in zip(self.envs, a, rows):
                env.act(action, row)
            self._step_physics()
            out = [env.after_physics(ac, row) for env, ac, row in zip(self.envs, a, rows)]
            obs = np.stack([o[0] for o in out])
            rewards = np.array([o[1] for o in out], dtype=np.float64)
            terminated = np.array([o[2] for o in out], dtype=bool)
            success = np.array([o[4]["success"] for o in out], dtype=bool)
            unstable = np.array([o[4].get("unstable", False) for o in out], dtype=bool)
        self.elapsed += 1
        truncated = self.elapsed >= self.max_episode_steps
        return EngineStep(obs, rewards, terminated, truncated, success, unstable)

    def _step_physics(self) -> None:
        self.physics.step()
        self._unsynced[:] = True

    # ------------------------------------------------------------------ sub-env state
    def sync(self, i: int) -> None:
        """Bring sub-env i's own MjData up to date (before reading, saving or rendering it)."""
        if self._unsynced[i]:
            self.physics.unload(i, self.envs[i].physics)
            self._unsynced[i] = False

    def restored(self, i: int) -> None:
        """Sub-env i's physics was reset or set on the env itself: take it into the batch."""
        self.physics.load(i, self.envs[i].physics)
        self._unsynced[i] = False

    def close(self) -> None:
        for env in self.envs:
            env.close()
