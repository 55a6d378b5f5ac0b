"""The hyper-parameters of the torch-native PPO student (`rsl-ppo`), written out per preset.

Both presets start from rsl_rl's legged-robot PPO (adaptive learning rate on a KL target of
0.01, 5 epochs of 4 minibatches, clipped value loss, ELU networks, empirical observation
normalisation) and adapt the rollout length to how many worlds a machine runs:

* `fast` (CPU, tens of worlds): 128 steps per world from 16 worlds on (2,048 steps below 16
  worlds, split over them), a [64, 64] network, and 10 epochs of 8 minibatches with no entropy
  bonus. On Stump Tracks at stump-v1's 1M steps (64 worlds, 4 seeds; docs/benchmarks.md),
  5 x 4 with entropy 0.005 mastered 0-6% of the grid; 10 x 8 without entropy masters as much
  as SB3 PPO (Random 4.0%, ALP-GMM 7.5% against SB3's 3.8% and 8.5%) with [64, 64] as with
  [128, 128] (3.8%, 9.5%), and [64, 64] trains faster: its matrix products scale with the
  hidden layers' widths (with `LeanPPO`, 1.36-1.60x SB3 PPO's steps/s on 2 cores). More worlds
  learned less at 1M: 256 worlds' 8 minibatches grow (fewer gradient steps per sample) and
  nothing was mastered; 128 worlds x 64 steps (the same update) mastered less with ALP-GMM.
  With no entropy bonus the action noise only shrinks, and past a few million steps the
  student stopped learning; a floor of 0.3 under it (`min_noise_std`) kept a 12M-step Random
  run learning and masters as much at 2M (8 seeds: Random 15.9% against 15.2%, ALP-GMM 18.1%
  against 17.6%; docs/results.md).
* `benchmark` (a GPU, thousands of worlds): rsl_rl's 24 steps per world (at least 20,000 steps
  per update, TeachMyAgent's PPO batch, on few worlds) and [256, 128, 64].

`min_noise_std` puts a floor under the learned action std (rsl_rl's `std_range`): sampling,
the entropy and the KL of the adaptive learning rate all see the std clamped to it.

Rewards are divided by a running standard deviation of the discounted return (as the SB3
students' VecNormalize does), since the tracks' fall penalty of -100 dwarfs a step's reward.
"""

from __future__ import annotations

from typing import Any

from acl3d import validation as check

PRESETS = ("benchmark", "fast")
ACTIVATIONS = ("elu", "relu", "tanh")
MAX_ROLLOUT = 10_000_000  # num_steps_per_env x n_envs
MAX_LAYER = 65_536
# Parameters added after runs shipped, at the value that trains as rsl-ppo did before each
# (`students.added_parameters`): min_noise_std 0 is no floor, as before it existed.
ADDED_PARAMETERS = {"min_noise_std": 0.0}


def _common() -> dict[str, Any]:
    return {
        "learning_rate": 1e-3,
        "schedule": "adaptive",
        "desired_kl": 0.01,
        "num_learning_epochs": 5,
        "num_mini_batches": 4,
        "clip_param": 0.2,
        "gamma": 0.99,
        "lam": 0.95,
        "value_loss_coef": 1.0,
        "entropy_coef": 0.005,
        "max_grad_norm": 1.0,
        "use_clipped_value_loss": True,
        "init_noise_std": 1.0,
        "min_noise_std": 0.0,
        "activation": "elu",
        "normalize_rewards": True,
    }


def hyperparameters(preset: str, n_envs: int, overrides=None) -> dict[str, Any]:
    """The student's settings for `preset` and `n_envs` worlds, with `overrides` (checked)."""
    check.choice("preset", preset, PRESETS)
    params = _common()
    if preset == "benchmark":
        params["hidden_dims"] = [256, 128, 64]
        params["num_steps_per_env"] = max(24, -(-20_000 // n_envs))
    else:
        params["hidden_dims"] = [64, 64]
        params["num_steps_per_env"] = 128 if n_envs >= 16 else max(1, 2048 // n_envs)
        params.update(
            num_learning_epochs=10, num_mini_batches=8, entropy_coef=0.0, min_noise_std=0.3
        )
    for key, value in (overrides or {}).items():
        if key not in params:
            raise ValueError(
                f"unknown student parameter {key!r} for rsl-ppo; valid: {sorted(params)}"
            )
        params[key] = value
    _check(params, n_envs)
    return params


def _check(params: dict, n_envs: int) -> None:
    name = "student_params[{!r}]".format
    for key in ("learning_rate", "clip_param", "max_grad_norm", "init_noise_std", "desired_kl"):
        check.positive(name(key), params[key])
    for key in ("value_loss_coef", "entropy_coef", "min_noise_std"):
        check.positive(name(key), params[key], allow_zero=True)
    for key in ("gamma", "lam"):
        check.real(name(key), params[key], 0.0, 1.0)
    for key in ("num_learning_epochs", "num_mini_batches"):
        check.integer(name(key), params[key], 1, 10_000)
    if params["min_noise_std"] >= params["init_noise_std"]:
        raise check.fail(
            name("min_noise_std"),
            params["min_noise_std"],
            f"[0, init_noise_std) = [0, {params['init_noise_std']})",
        )
    check.integer(name("num_steps_per_env"), params["num_steps_per_env"], 1, MAX_ROLLOUT)
    for key in ("use_clipped_value_loss", "normalize_rewards"):
        check.flag(name(key), params[key])
    check.choice(name("schedule"), params["schedule"], ("adaptive", "fixed"))
    check.choice(name("activation"), params["activation"], ACTIVATIONS)
    dims = params["hidden_dims"]
    if not (
        isinstance(dims, list)
        and dims
        and all(
            isinstance(n, int) and not isinstance(n, bool) and 1 <= n <= MAX_LAYER for n in dims
        )
    ):
        raise check.fail(name("hidden_dims"), dims, f"a list of layer sizes in [1, {MAX_LAYER}]")
    rollout = params["num_steps_per_env"] * n_envs
    if rollout > MAX_ROLLOUT:
        raise check.fail(
            name("num_steps_per_env"),
            params["num_steps_per_env"],
            f"num_steps_per_env x n_envs <= {MAX_ROLLOUT} (n_envs={n_envs})",
        )
    if params["num_mini_batches"] > rollout:
        raise check.fail(
            name("num_mini_batches"),
            params["num_mini_batches"],
            f"at most num_steps_per_env x n_envs = {rollout}",
        )
