"""Evaluation on a fixed test set: % mastered (return above the env's success return) and mean
return (TeachMyAgent §4.2).

The test tasks are spread over the worker envs of an evaluation VecEnv (each worker plays the
next unplayed test task at its auto-reset), so evaluation runs in parallel and never touches
the training envs or the teacher. It draws from its own random streams too (`own_random_streams`),
so sampled actions leave training's streams as they were: the evaluation schedule never changes
what is trained, and an evaluation depends only on the policy and the seed.
"""

from __future__ import annotations

import random
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
import torch
from stable_baselines3.common.vec_env import VecEnv

from acl3d.training.curriculum import INFO_KEY, raise_worker_errors


@dataclass
class EvalResult:
    tasks: np.ndarray  # (N, d)
    returns: np.ndarray  # (N,)
    lengths: np.ndarray  # (N,)
    successes: np.ndarray  # (N,) env's own success flag
    success_return: float  # the env's curriculum profile's (TeachMyAgent's 230 on the tracks)

    @property
    def mastered_pct(self) -> float:
        """100 x share of test tasks with return strictly above the success return."""
        return float(100.0 * np.mean(self.returns > self.success_return))

    @property
    def mean_return(self) -> float:
        return float(np.mean(self.returns))

    def summary(self) -> dict[str, float]:
        return {
            "mastered_pct": self.mastered_pct,
            "mean_return": self.mean_return,
            "std_return": float(np.std(self.returns)),
            "mean_length": float(np.mean(self.lengths)),
            "n_tasks": int(len(self.returns)),
        }


@contextmanager
def own_random_streams(seed: int) -> Iterator[None]:
    """Runs the block on the global random streams (python, numpy, torch's CPU generator and
    every initialised CUDA device's) seeded with `seed`, then puts the caller's streams back.

    SB3 samples stochastic actions from torch's global generator and shuffles minibatches with
    numpy's: a block run inside leaves the training that follows it bit for bit unchanged.
    """
    py_state, np_state = random.getstate(), np.random.get_state()
    cuda = list(range(torch.cuda.device_count())) if torch.cuda.is_initialized() else []
    with torch.random.fork_rng(devices=cuda):
        random.seed(seed)
        np.random.seed(seed)
        torch.default_generator.manual_seed(seed)
        for device in cuda:
            torch.cuda.default_generators[device].manual_seed(seed)
        try:
            yield
        finally:
            random.setstate(py_state)
            np.random.set_state(np_state)


def evaluate(
    predict,
    venv: VecEnv,
    tasks: np.ndarray,
    seed: int = 0,
    episodes_per_task: int = 1,
) -> EvalResult:
    """Play every test task `episodes_per_task` times on the CurriculumEnv workers of `venv`.

    `predict(obs) -> actions` maps raw observations to actions (normalisation included).
    Workers that run out of test tasks replay the first one and their results are discarded.
    `seed` seeds the envs and the random streams `predict` draws from (sampled actions), so the
    same policy and seed give the same result, and the caller's random streams are untouched.
    """
    with own_random_streams(seed):
        return _play(predict, venv, tasks, seed, episodes_per_task)


def _play(predict, venv: VecEnv, tasks, seed: int, episodes_per_task: int) -> EvalResult:
    tasks = np.atleast_2d(np.asarray(tasks, dtype=np.float32))
    order = np.repeat(np.arange(len(tasks)), episodes_per_task)
    n_total = len(order)
    if n_total == 0:
        raise ValueError("evaluate: the test set is empty")
    n = venv.num_envs
    venv.env_method("clear_tasks")
    next_item = 0
    current = np.full(n, -1)
    pending = np.full(n, -1)

    def push(i: int) -> int:
        nonlocal next_item
        item = next_item if next_item < n_total else -1
        next_item += item >= 0
        task = tasks[order[item]] if item >= 0 else tasks[0]
        venv.env_method("push_task", task, indices=[i])
        return item

    for i in range(n):
        current[i] = push(i)
    venv.seed(seed)
    obs = venv.reset()
    raise_worker_errors(venv.reset_infos, "evaluation reset")  # every VecEnv keeps them
    for i in range(n):
        pending[i] = push(i)
    returns = np.full(n_total, np.nan)
    lengths = np.zeros(n_total, dtype=np.int64)
    successes = np.zeros(n_total, dtype=bool)
    done_count = 0
    while done_count < n_total:
        obs, _, dones, infos = venv.step(predict(obs))
        raise_worker_errors(infos, "evaluation step")
        for i in np.flatnonzero(dones):
            item = current[i]
            if item >= 0:
                ep = infos[i][INFO_KEY]
                if not np.allclose(ep["task"], tasks[order[item]], rtol=1e-6):
                    raise RuntimeError(
                        f"evaluation worker {i} played {ep['task']} instead of test task "
                        f"{tasks[order[item]]}: task queue out of sync"
                    )
                returns[item], lengths[item] = ep["return"], ep["length"]
                successes[item] = ep["success"]
                done_count += 1
            current[i], pending[i] = pending[i], push(int(i))
    threshold = float(venv.env_method("success_return", indices=[0])[0])
    return EvalResult(tasks[order].astype(np.float64), returns, lengths, successes, threshold)


def make_predict(model, deterministic: bool, normalize_obs=None):
    """obs -> actions with the SB3 model (VecNormalize statistics applied first when given)."""

    def predict(obs):
        if normalize_obs is not None:
            obs = normalize_obs(obs)
        actions, _ = model.predict(obs, deterministic=deterministic)
        return actions

    return predict


def evaluate_saved_model(
    model_path,
    env_name: str,
    body: str | None,
    tasks: np.ndarray,
    *,
    env_kwargs=None,
    n_envs: int = 1,
    deterministic: bool = True,
    seed: int = 0,
    episodes_per_task: int = 1,
    vec_env: str = "auto",
    start_method: str = "forkserver",
) -> EvalResult:
    """Evaluate a saved SB3 zip (with its `_vecnormalize` statistics when present)."""
    from acl3d.training import checkpoint, students
    from acl3d.training.workers import make_vec_env

    model = students.load(None, model_path)
    normalize = checkpoint.observation_normalizer(model_path)
    venv = make_vec_env(env_name, body, n_envs, env_kwargs, vec_env, start_method)
    try:
        if venv.observation_space.shape != model.observation_space.shape:
            raise ValueError(
                f"model {str(model_path)!r} expects observations of shape "
                f"{model.observation_space.shape}, env {env_name!r} with body {body!r} gives "
                f"{venv.observation_space.shape}"
            )
        predict = make_predict(model, deterministic, normalize)
        return evaluate(predict, venv, tasks, seed=seed, episodes_per_task=episodes_per_task)
    finally:
        venv.close()
