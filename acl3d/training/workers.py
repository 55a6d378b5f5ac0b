"""Environment factories and worker vector envs for training and evaluation.

acl3d envs default to the batched env (`acl3d.vec.batched_sb3.BatchedVecEnv`: all sub-envs in
this process, physics on one thread per core), or to several worker processes each stepping a
batched env (`envs_per_worker`). Other Gymnasium ids, and `vec_env="dummy"|"subproc"`, get one
env per `CurriculumEnv` worker. Environments in worker processes are built from a picklable
factory, so the `forkserver` or `spawn` start methods work (`fork` is refused: MuJoCo/OpenGL
and torch threads do not survive it reliably).
"""

from __future__ import annotations

import functools
import importlib
import inspect

import gymnasium as gym
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv

from acl3d.training.curriculum import CurriculumEnv

# "warp": the many-world simulation on MuJoCo Warp (torch-native students; on --device's device)
VEC_ENV_KINDS: tuple[str, ...] = ("auto", "batched", "dummy", "subproc", "warp")
START_METHODS: tuple[str, ...] = ("forkserver", "spawn")


def make_env(env_name: str, body: str | None = None, env_kwargs=None, render_mode=None) -> gym.Env:
    """An acl3d track by short name (`stump-tracks`, ...) or any Gymnasium id (`ns/Name-v0`).

    Tracks get `body`; other ids get only `env_kwargs`. Curricula need `env.unwrapped` to be a
    `TaskEnv` (`acl3d.envs.task_env`), as every acl3d env is.
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


def env_keywords(env_name: str) -> list[str]:
    """The keyword arguments an env's constructor takes (for messages), besides `body`."""
    import acl3d.envs

    env_id = acl3d.envs.env_id(env_name) if is_batchable(env_name) else env_name
    spec = gym.spec(env_id)
    entry = spec.entry_point
    if isinstance(entry, str):
        module, _, name = entry.partition(":")
        entry = getattr(importlib.import_module(module), name)
    params = inspect.signature(entry).parameters
    fixed = {"body", "render_mode", *spec.kwargs}
    names = [n for n, p in params.items() if p.kind is p.KEYWORD_ONLY or p.default is not p.empty]
    return ["max_episode_steps", *(n for n in names if n not in fixed)]


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
    envs_per_worker: int | None = None,
    threads: int | None = None,
) -> VecEnv:
    """`n_envs` envs: `batched` (acl3d ids; `auto` picks it for them), `dummy` or `subproc`.

    Batched: `envs_per_worker=None` (or >= n_envs) keeps all envs in this process with
    `threads` physics threads (default one per core); a smaller `envs_per_worker` runs
    ceil(n_envs / envs_per_worker) worker processes of that many envs each (threads split the
    cores). Other ids under `auto`: DummyVecEnv for one env, else SubprocVecEnv.
    With `curriculum=True` every reset plays a teacher/test task (`CurriculumEnv` semantics,
    training and evaluation); `False` gives plain envs (the no-teacher baseline).
    """
    check_vec_env(vec_env, start_method)
    if isinstance(n_envs, bool) or not isinstance(n_envs, int) or n_envs < 1:
        raise ValueError(f"n_envs={n_envs!r}; valid: an integer >= 1")
    if envs_per_worker is not None and (
        isinstance(envs_per_worker, bool)
        or not isinstance(envs_per_worker, int)
        or not 1 <= envs_per_worker <= n_envs
    ):
        raise ValueError(
            f"envs_per_worker={envs_per_worker!r}; valid: None or an integer in [1, {n_envs}]"
        )
    batchable = is_batchable(env_name)
    if vec_env == "batched" and not batchable:
        raise ValueError(
            f"vec_env='batched' needs an acl3d environment, got {env_name!r}; "
            "valid for other ids: auto, dummy, subproc"
        )
    if vec_env == "batched" or (vec_env == "auto" and batchable):
        return _batched_vec_env(
            env_name,
            body,
            n_envs,
            env_kwargs,
            start_method,
            render_mode,
            curriculum,
            envs_per_worker,
            threads,
        )
    factory = make_worker_env if curriculum else make_env
    fns = [
        functools.partial(factory, env_name, body, dict(env_kwargs or {}), render_mode)
        for _ in range(n_envs)
    ]
    if vec_env == "dummy" or (vec_env == "auto" and n_envs == 1):
        return DummyVecEnv(fns)
    return SubprocVecEnv(fns, start_method=start_method)


def is_batchable(env_name: str) -> bool:
    """acl3d tracks run in the batched env; other Gymnasium ids one env per worker."""
    import acl3d.envs

    return env_name in acl3d.envs.ENV_NAMES or env_name in acl3d.envs.ENV_IDS.values()


def make_batched_env(env_name, body, n_envs, env_kwargs, render_mode, curriculum, threads):
    """Factory of one batched env (also run inside worker processes)."""
    from acl3d.vec.batched_sb3 import BatchedVecEnv

    kwargs = dict(env_kwargs or {})
    if body is not None:
        kwargs["body"] = body
    if render_mode is not None:
        kwargs["render_mode"] = render_mode
    return BatchedVecEnv(env_name, n_envs, threads=threads, curriculum=curriculum, **kwargs)


def _batched_vec_env(
    env_name, body, n_envs, env_kwargs, start_method, render_mode, curriculum, per_worker, threads
) -> VecEnv:
    if per_worker is None or per_worker >= n_envs:
        return make_batched_env(
            env_name, body, n_envs, env_kwargs, render_mode, curriculum, threads
        )
    from acl3d.envs.batched import default_threads
    from acl3d.vec.batched_workers import BatchedSubprocVecEnv

    sizes = [min(per_worker, n_envs - lo) for lo in range(0, n_envs, per_worker)]
    threads = threads or max(1, default_threads() // len(sizes))
    factories = [
        functools.partial(
            make_batched_env, env_name, body, size, env_kwargs, render_mode, curriculum, threads
        )
        for size in sizes
    ]
    return BatchedSubprocVecEnv(factories, start_method=start_method)
