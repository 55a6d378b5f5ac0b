"""Environment factories and worker vector envs for training and evaluation.

Environments are built inside the worker processes from a picklable factory, so SubprocVecEnv
can use the `forkserver` or `spawn` start methods (`fork` is refused: MuJoCo/OpenGL and torch
threads do not survive it reliably).
"""

from __future__ import annotations

import functools

import gymnasium as gym
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv

from acl3d.training.curriculum import CurriculumEnv

VEC_ENV_KINDS: tuple[str, ...] = ("auto", "dummy", "subproc")
START_METHODS: tuple[str, ...] = ("forkserver", "spawn")


def make_env(env_name: str, body: str | None = None, env_kwargs=None, render_mode=None) -> gym.Env:
    """An acl3d track by short name (`stump-tracks`, ...) or any Gymnasium id (`ns/Name-v0`).

    Tracks get `body`; other ids get only `env_kwargs`. Curricula need `env.unwrapped.task_space`.
    """
    kwargs = dict(env_kwargs or {})
    if render_mode is not None:
        kwargs["render_mode"] = render_mode
    import acl3d.envs  # registers the acl3d/* ids

    if body is not None and (env_name in acl3d.envs.ENV_NAMES or env_name.startswith("acl3d/")):
        kwargs["body"] = body
    if env_name in acl3d.envs.ENV_NAMES or env_name.startswith("acl3d/"):
        return acl3d.envs.make(env_name, **kwargs)
    if "/" in env_name or "-v" in env_name:
        return gym.make(env_name, **kwargs)
    raise ValueError(f"unknown environment {env_name!r}; valid: {', '.join(acl3d.envs.ENV_NAMES)}")


def make_worker_env(env_name: str, body: str | None, env_kwargs=None, render_mode=None):
    """Factory run inside each worker: the env behind a `CurriculumEnv`."""
    return CurriculumEnv(make_env(env_name, body, env_kwargs, render_mode))


def check_vec_env(vec_env: str, start_method: str) -> None:
    if vec_env not in VEC_ENV_KINDS:
        raise ValueError(f"vec_env {vec_env!r} unknown; valid: {', '.join(VEC_ENV_KINDS)}")
    if start_method not in START_METHODS:
        raise ValueError(
            f"start_method {start_method!r} not allowed; valid: {', '.join(START_METHODS)} "
            "(fork is unsafe with MuJoCo rendering and torch threads)"
        )


def make_vec_env(
    env_name: str,
    body: str | None,
    n_envs: int,
    env_kwargs=None,
    vec_env: str = "auto",
    start_method: str = "forkserver",
    render_mode=None,
    curriculum: bool = True,
) -> VecEnv:
    """`n_envs` workers (DummyVecEnv in-process, or SubprocVecEnv); `auto` = subproc if n > 1.

    With `curriculum=True` each env sits behind a `CurriculumEnv` (training and evaluation);
    `False` gives plain envs (the no-teacher baseline of the benchmark).
    """
    check_vec_env(vec_env, start_method)
    if n_envs < 1:
        raise ValueError(f"n_envs must be >= 1, got {n_envs}")
    factory = make_worker_env if curriculum else make_env
    fns = [
        functools.partial(factory, env_name, body, dict(env_kwargs or {}), render_mode)
        for _ in range(n_envs)
    ]
    if vec_env == "dummy" or (vec_env == "auto" and n_envs == 1):
        return DummyVecEnv(fns)
    return SubprocVecEnv(fns, start_method=start_method)
