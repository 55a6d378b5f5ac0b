"""Student hyperparameters: the presets of SAC and PPO, the network of any other algorithm,
and the checks of every value before Stable-Baselines3 or torch sees it.

`acl3d.training.students` asks for a student's parameters here and turns them into a model;
this module knows nothing of algorithm classes, so a new student's presets are one function
and one line of `PRESET_PARAMS`.

`benchmark` follows TeachMyAgent §4.4 as closely as SB3 allows (deviations are listed in the
docs: SB3's SAC has no separate V network and updates every 10 steps instead of at episode end;
SB3's PPO has separate policy/value MLPs instead of a shared trunk). `fast` keeps the same
algorithms with small networks and short rollouts so a CPU run shows learning within minutes.
"""

from __future__ import annotations

from typing import Any

import torch

from acl3d import validation as check

PRESETS: tuple[str, ...] = ("benchmark", "fast")
MANY_ENVS = 16  # from this many envs on, the fast presets use bigger collections
ACTIVATIONS = {"relu": torch.nn.ReLU, "tanh": torch.nn.Tanh, "elu": torch.nn.ELU}


def _sac(preset: str, n_envs: int) -> dict[str, Any]:
    if preset == "benchmark":
        # SpinningUp SAC v0.1.1: 400-300 ReLU, alpha 0.005 fixed, polyak 0.995, start_steps 10k,
        # one gradient step per 10 environment steps.
        return {
            "policy_kwargs": {"net_arch": [400, 300], "activation_fn": "relu"},
            "learning_rate": 1e-3,
            "batch_size": 1000,
            "buffer_size": 2_000_000,
            "ent_coef": 0.005,
            "tau": 0.005,
            "gamma": 0.99,
            "learning_starts": 10_000,
            "train_freq": 10,
            "gradient_steps": n_envs,
        }
    # fast: a learned entropy coefficient and RL Zoo's BipedalWalker SAC rates (lr 7.3e-4,
    # gamma 0.98, tau 0.02); with the fixed 0.005 of the benchmark it learned to stand, not walk
    return {
        "policy_kwargs": {"net_arch": [64, 64], "activation_fn": "relu"},
        "learning_rate": 7.3e-4,
        "batch_size": 256,
        "buffer_size": 300_000,
        "ent_coef": "auto",
        "tau": 0.02,
        "gamma": 0.98,
        "learning_starts": 1_000,
        "train_freq": 4,
        "gradient_steps": n_envs,
    }


def _ppo(preset: str, n_envs: int) -> dict[str, Any]:
    # Both presets share OpenAI Baselines ppo2's loss settings as run by TeachMyAgent.
    common = {
        "learning_rate": 3e-4,
        "clip_range": 0.2,
        "vf_coef": 0.5,
        "ent_coef": 0.0,
        "gamma": 0.99,
        "gae_lambda": 0.95,
        "max_grad_norm": 0.5,
    }
    if preset == "benchmark":
        # TeachMyAgent: 20k steps per update (split over the workers), minibatches of 1000, 5 epochs.
        return {
            **common,
            "policy_kwargs": {"net_arch": [400, 300], "activation_fn": "tanh"},
            "n_steps": max(1, 20_000 // n_envs),
            "batch_size": 1000,
            "n_epochs": 5,
        }
    # fast: 2048-step rollouts in minibatches of 256; from 16 envs on (the batched env's
    # default) 256 steps per env in minibatches of 512, i.e. half the gradient steps per sample:
    # on 2 cores the flat track is mastered in less wall time that way (docs/benchmarks.md, sanity run)
    many = n_envs >= MANY_ENVS
    return {
        **common,
        "policy_kwargs": {"net_arch": [64, 64], "activation_fn": "tanh"},
        "n_steps": 256 if many else max(1, 2048 // n_envs),
        "batch_size": 512 if many else 256,
        "n_epochs": 10,
    }


def network(preset: str) -> dict[str, Any]:
    """The preset's network for algorithms without a tuned preset."""
    if preset == "benchmark":
        return {"policy_kwargs": {"net_arch": [400, 300], "activation_fn": "relu"}}
    return {"policy_kwargs": {"net_arch": [64, 64], "activation_fn": "tanh"}}


PRESET_PARAMS = {"sac": _sac, "ppo": _ppo}


def check_params(student: str, params: dict, n_envs: int) -> None:
    """Every value's type and range, then the constraints between values."""
    _check_values(params, n_envs)
    _check_consistency(student, params, n_envs)


# Upper bounds that keep a run's buffers in memory (TeachMyAgent's largest: 2e6 transitions)
MAX_BUFFER_SIZE = 50_000_000
MAX_ROLLOUT = 10_000_000  # PPO's n_steps x n_envs
MAX_LAYER = 65_536  # units per hidden layer
MAX_HIDDEN_WEIGHTS = 50_000_000  # between the hidden layers of one network: 200 MB of float32


def _check_values(params: dict, n_envs: int) -> None:
    """Each hyperparameter's type and range, before SB3 or torch sees it (they would fail late,
    or not at all: a negative learning rate is accepted by SB3 and refused by torch's optimiser)."""
    name = "student_params[{!r}]".format
    for key, value in params.items():
        if key in _POSITIVE_REALS:
            check.positive(name(key), value)
        elif key in _NON_NEGATIVE_REALS:
            check.positive(name(key), value, allow_zero=True)
        elif key in _UNIT_REALS:
            check.real(name(key), value, 0.0, 1.0)
        elif key in _COUNTS:
            check.count(name(key), value, minimum=_COUNTS[key], allow_float=True)
        elif key in _BOOLS:
            check.flag(name(key), value)
        elif key in _OPTIONAL_POSITIVE_REALS and value is not None:
            check.positive(name(key), value)
    _check_ranges(params, n_envs, name)


def _check_ranges(params: dict, n_envs: int, name) -> None:
    if "buffer_size" in params:
        check.integer(name("buffer_size"), params["buffer_size"], 1, MAX_BUFFER_SIZE)
    if "n_steps" in params and int(params["n_steps"]) * n_envs > MAX_ROLLOUT:
        raise check.fail(
            name("n_steps"),
            params["n_steps"],
            f"n_steps x n_envs <= {MAX_ROLLOUT} (n_envs={n_envs})",
        )
    if "gradient_steps" in params and params["gradient_steps"] != -1:
        check.count(name("gradient_steps"), params["gradient_steps"], minimum=1)
    ent = params.get("ent_coef", 0.0)
    if not (isinstance(ent, str) and (ent == "auto" or ent.startswith("auto_"))):
        check.real(name("ent_coef"), ent, 0.0)
    freq = params.get("train_freq", 1)
    if isinstance(freq, (list, tuple)):
        if len(freq) != 2 or freq[1] not in ("step", "episode"):
            raise check.fail(name("train_freq"), freq, 'N, [N, "step"] or [N, "episode"]')
        freq = freq[0]
    check.count(name("train_freq"), freq)
    kwargs = params.get("policy_kwargs")
    if not isinstance(kwargs, dict):
        raise check.fail(name("policy_kwargs"), kwargs, "a mapping (net_arch, activation_fn)")
    arch = kwargs.get("net_arch", [])
    layers = [arch] if isinstance(arch, int) else arch
    if isinstance(layers, dict):
        layers = [n for v in layers.values() for n in (v if isinstance(v, list) else [v])]
    if not isinstance(layers, list) or not all(
        check.is_real(n) and isinstance(n, int) and 1 <= n <= MAX_LAYER for n in layers
    ):
        raise check.fail(
            "student_params['policy_kwargs']['net_arch']",
            arch,
            f"a list of layer sizes in [1, {MAX_LAYER}] (or {{'pi': [...], 'vf': [...]}})",
        )
    for chain in arch.values() if isinstance(arch, dict) else [layers]:
        chain = chain if isinstance(chain, list) else [chain]
        weights = sum(a * b for a, b in zip(chain, chain[1:]))
        if weights > MAX_HIDDEN_WEIGHTS:
            raise check.fail(
                "student_params['policy_kwargs']['net_arch']",
                arch,
                f"at most {MAX_HIDDEN_WEIGHTS:,} weights between hidden layers (the sum of the "
                f"products of consecutive sizes; {chain} has {weights:,})",
            )


_POSITIVE_REALS = ("learning_rate", "clip_range", "max_grad_norm")
_NON_NEGATIVE_REALS = ("vf_coef",)
_OPTIONAL_POSITIVE_REALS = ("target_kl", "clip_range_vf")
_UNIT_REALS = ("gamma", "gae_lambda", "tau")
_COUNTS = {"batch_size": 1, "n_steps": 1, "n_epochs": 1, "learning_starts": 0,
           "target_update_interval": 1}  # fmt: skip
_BOOLS = ("normalize_advantage", "optimize_memory_usage", "use_sde")


EXTRA_KEYS = {
    "sac": {"target_update_interval", "optimize_memory_usage", "use_sde"},
    "ppo": {"normalize_advantage", "target_kl", "clip_range_vf", "use_sde"},
}


def _check_consistency(student: str, params: dict, n_envs: int) -> None:
    if student == "ppo":
        rollout = int(params["n_steps"]) * n_envs
        if int(params["batch_size"]) > rollout:
            raise ValueError(
                f"ppo batch_size ({params['batch_size']}) must be <= n_steps x n_envs "
                f"({params['n_steps']} x {n_envs} = {rollout})"
            )
    elif student == "sac":
        if int(params["buffer_size"]) < int(params["batch_size"]):
            raise ValueError(
                f"sac buffer_size ({params['buffer_size']}) must be >= batch_size "
                f"({params['batch_size']})"
            )
    act = params["policy_kwargs"].get("activation_fn")
    if isinstance(act, str) and act not in ACTIVATIONS:
        raise ValueError(f"activation_fn {act!r} unknown; valid: {', '.join(ACTIVATIONS)}")
