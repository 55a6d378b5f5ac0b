"""Students: Stable-Baselines3 SAC and PPO with TeachMyAgent's settings or a CPU-friendly
preset, and any other Stable-Baselines3 algorithm with its own hyperparameters.

Other algorithms are named "sb3:TD3" (any algorithm class of `stable_baselines3`) or
"package.module:Class" (any `BaseAlgorithm` subclass, e.g. from sb3-contrib). The preset sets
only their network (`benchmark` 400-300, `fast` 64-64); everything else is the algorithm's own
default unless given in `student_params`, checked against its constructor. `action_noise_std`
adds Gaussian exploration noise to the algorithms that take an `action_noise` (TD3, DDPG).
The presets' values and the checks of every hyperparameter are in `student_presets`.
"""

from __future__ import annotations

import importlib
import inspect
import json
import zipfile
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import stable_baselines3
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.vec_env import DummyVecEnv

from acl3d import validation as check
from acl3d.training import student_presets as presets
from acl3d.training.exclusion import (
    ExcludingPPO,
    ExcludingReplayBuffer,
    ExcludingRolloutBuffer,
    ExcludingSAC,
)

PRESETS = presets.PRESETS
STUDENTS: tuple[str, ...] = ("sac", "ppo")  # with presets; "sb3:TD3", "pkg.mod:Class" too
TORCH_STUDENTS: tuple[str, ...] = ("rsl-ppo",)  # torch-native: acl3d.training.torch_student

# SB3's SAC and PPO, unless their buffer excludes transitions (acl3d.training.exclusion)
_ALGOS = {"sac": ExcludingSAC, "ppo": ExcludingPPO}


def spec(student) -> str:
    """The name a run records for `student`: itself for a name, "module:Class" for a class."""
    if isinstance(student, type):
        return f"{student.__module__}:{student.__qualname__}"
    return student


def algorithm_class(student: str) -> type[BaseAlgorithm]:
    """The SB3 algorithm class of a student name (see the module docstring)."""
    names = ", ".join(STUDENTS + TORCH_STUDENTS)
    valid = f"valid students: {names}, sb3:NAME (e.g. sb3:TD3) or pkg.module:Class"
    if student in _ALGOS:
        return _ALGOS[student]
    if not isinstance(student, str) or ":" not in student:
        raise ValueError(f"unknown student {student!r}; {valid}")
    module, _, name = student.partition(":")
    try:
        owner = stable_baselines3 if module == "sb3" else importlib.import_module(module)
        cls = getattr(owner, name)
    except (ImportError, AttributeError, ValueError) as exc:
        raise ValueError(f"unknown student {student!r} ({exc}); {valid}") from None
    if not (isinstance(cls, type) and issubclass(cls, BaseAlgorithm)):
        raise ValueError(f"student {student!r} is not a Stable-Baselines3 algorithm class; {valid}")
    return cls


class _Spaces(gymnasium.Env):
    """A stand-in env that only has spaces: what an algorithm's constructor checks."""

    def __init__(self, observation_space, action_space):
        self.observation_space, self.action_space = observation_space, action_space


def check_action_space(student: str, observation_space, action_space) -> None:
    """Refuse an algorithm that cannot act in the env's action space (DQN: Discrete only).

    SB3 declares an algorithm's supported action spaces as a constructor argument that
    `BaseAlgorithm.__init__` asserts on, not as a class attribute; so the algorithm is constructed
    on a stand-in env with the run's spaces and without its networks (`_init_setup_model=False`).
    An algorithm whose constructor lacks that argument (not SB3's) is left to its own checks.
    """
    cls = algorithm_class(student)
    if "_init_setup_model" not in inspect.signature(cls.__init__).parameters:
        return
    venv = DummyVecEnv([lambda: _Spaces(observation_space, action_space)])
    try:
        cls("MlpPolicy", venv, device="cpu", _init_setup_model=False)
    except AssertionError as exc:
        if "action space" not in str(exc):
            raise
        raise ValueError(
            f"student={student!r}; {cls.__name__} does not support the environment's action "
            f"space {action_space}; valid: sac, ppo or an algorithm for continuous (Box) "
            "actions (sb3:TD3, sb3:A2C, sb3:DDPG, ...)"
        ) from None


def is_torch_native(student) -> bool:
    """Whether `student` trains on tensor worlds in its own loop (not an SB3 algorithm)."""
    return student in TORCH_STUDENTS


def added_parameters(student: str) -> dict[str, Any]:
    """The parameters `student` gained after runs of it had shipped, each at the value that
    trains as the student did before it existed: a spec that pinned the student's other
    parameters describes the same runs as one that pins these at those values."""
    if is_torch_native(student):
        from acl3d.training.torch_student import presets as torch_presets

        return dict(torch_presets.ADDED_PARAMETERS)
    return {}


def is_on_policy(student: str) -> bool:
    return is_torch_native(student) or issubclass(algorithm_class(student), OnPolicyAlgorithm)


def check_student(student: str, preset: str) -> None:
    if not is_torch_native(student):
        algorithm_class(student)
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; valid presets: {', '.join(PRESETS)}")


def hyperparameters(student: str, preset: str, n_envs: int, overrides=None) -> dict[str, Any]:
    """SB3 constructor kwargs (JSON-friendly: activation as a name) for a student and preset.

    `overrides` replaces top-level keys (e.g. `{"buffer_size": 100000}`); unknown keys fail.
    """
    check_student(student, preset)
    if is_torch_native(student):
        from acl3d.training.torch_student import presets as torch_presets

        return torch_presets.hyperparameters(preset, n_envs, overrides)
    if student in presets.PRESET_PARAMS:
        params = presets.PRESET_PARAMS[student](preset, n_envs)
        accepted = set(params) | presets.EXTRA_KEYS[student]
    else:
        params = presets.network(preset)
        accepted = _constructor_keys(algorithm_class(student))
    for key, value in (overrides or {}).items():
        if key not in params and key not in accepted:
            raise ValueError(
                f"unknown student parameter {key!r} for {student}; valid: {sorted(accepted)}"
            )
        params[key] = value
    presets.check_params(student, params, n_envs)
    return params


# set by acl3d itself (build) or meaningless in a run: not student parameters
_RESERVED = {
    "self",
    "policy",
    "env",
    "seed",
    "tensorboard_log",
    "device",
    "verbose",
    "_init_setup_model",
}


def _constructor_keys(cls: type[BaseAlgorithm]) -> set[str]:
    keys = set(inspect.signature(cls.__init__).parameters) - _RESERVED
    if "action_noise" in keys:
        keys = (keys - {"action_noise"}) | {"action_noise_std"}
    return keys


def collection_steps(student: str, params: dict, n_envs: int) -> int:
    """Env steps SB3 collects between two checks of its step budget: an on-policy rollout
    (n_steps x n_envs), or an off-policy algorithm's train_freq x n_envs (1 x n_envs for an
    episode-based train_freq); the algorithm's own default where `params` does not say."""
    if is_torch_native(student):
        return int(params["num_steps_per_env"]) * n_envs
    defaults = inspect.signature(algorithm_class(student).__init__).parameters
    if is_on_policy(student):
        return int(params.get("n_steps", defaults["n_steps"].default)) * n_envs
    freq = params.get("train_freq", defaults["train_freq"].default)
    if isinstance(freq, (list, tuple)):
        freq = freq[0] if len(freq) == 2 and freq[1] == "step" else 1
    return int(freq) * n_envs


def uses_vecnormalize(student: str) -> bool:
    """TeachMyAgent normalises observations and returns for PPO (clip 10); acl3d does it for
    every on-policy algorithm (A2C too), as RL Zoo does on MuJoCo tasks."""
    return is_on_policy(student)


def build(
    student: str,
    params: dict[str, Any],
    env,
    seed: int,
    tensorboard_log: str | None = None,
    device: str = "cpu",
    exclude_exploratory: bool = False,
) -> BaseAlgorithm:
    """Instantiate the SB3 model from `hyperparameters(...)` output; `exclude_exploratory`
    gives it a rollout / replay buffer that leaves marked transitions out of the updates."""
    kwargs = dict(params)
    if exclude_exploratory and student == "ppo":
        kwargs["rollout_buffer_class"] = ExcludingRolloutBuffer
    elif exclude_exploratory:
        kwargs["replay_buffer_class"] = ExcludingReplayBuffer
    policy_kwargs = dict(kwargs.pop("policy_kwargs"))
    act = policy_kwargs.get("activation_fn")
    if isinstance(act, str):
        policy_kwargs["activation_fn"] = presets.ACTIVATIONS[act]
    noise_std = kwargs.pop("action_noise_std", None)
    if noise_std is not None:
        size = env.action_space.shape[0]
        std = check.real("action_noise_std", noise_std, 0.0)
        kwargs["action_noise"] = NormalActionNoise(np.zeros(size), np.full(size, std))
    return algorithm_class(student)(
        "MlpPolicy",
        env,
        policy_kwargs=policy_kwargs,
        seed=seed,
        tensorboard_log=tensorboard_log,
        device=device,
        verbose=0,
        **kwargs,
    )


def load(student: str | None, path, env=None, device: str = "cpu") -> BaseAlgorithm:
    """Load an SB3 zip; `student=None` recognises SAC/PPO from the zip's own metadata."""
    path = Path(path)
    if not path.exists():
        raise ValueError(f"model file {str(path)!r} does not exist")
    if student is None:
        student = detect(path)
    return algorithm_class(student).load(str(path), env=env, device=device)


def detect(path) -> str:
    """Which student wrote this SB3 zip: by its policy's module for SB3's off-policy
    algorithms, else by the hyperparameters stored in it (PPO, A2C)."""
    try:
        with zipfile.ZipFile(path) as z:
            data = json.loads(z.read("data"))
    except (OSError, KeyError, zipfile.BadZipFile, json.JSONDecodeError) as exc:
        raise ValueError(f"{str(path)!r} is not a Stable-Baselines3 model zip ({exc})") from None
    policy_module = str((data.get("policy_class") or {}).get("__module__", "")).split(".")
    if len(policy_module) > 2 and policy_module[0] == "stable_baselines3":  # sb3.<algo>.policies
        name = policy_module[1]
        if name in _ALGOS:
            return name
        if isinstance(getattr(stable_baselines3, name.upper(), None), type):
            return f"sb3:{name.upper()}"
    if "n_epochs" in data:
        return "ppo"
    if "n_steps" in data and "gae_lambda" in data:  # on-policy without PPO's epochs
        return "sb3:A2C"
    if "tau" in data and "buffer_size" in data:
        return "sac"
    raise ValueError(
        f"{str(path)!r}: not a Stable-Baselines3 algorithm's model; valid students: "
        f"{', '.join(STUDENTS)} or sb3:NAME"
    )


def value_estimator(model: BaseAlgorithm, normalize_obs=None):
    """The student's value function V(s) on raw observations, for teachers that need it.

    On-policy students (PPO, A2C): the critic on the observations as the policy sees them
    (normalised by VecNormalize when used; TeachMyAgent fed raw ones, §6.16). Off-policy ones
    (SAC, TD3, ...): min of the critics at the policy's deterministic action. Reads
    `model.policy` at call time, so it follows student resets.
    """

    def estimate(states) -> np.ndarray:
        obs = np.asarray(states, dtype=np.float32)
        if obs.ndim == 1:
            obs = obs[None]
        if normalize_obs is not None:
            obs = normalize_obs(obs)
        policy = model.policy
        with torch.no_grad():
            obs_t = torch.as_tensor(obs, dtype=torch.float32, device=policy.device)
            if isinstance(model, OnPolicyAlgorithm):
                values = policy.predict_values(obs_t)
            else:
                actions = policy._predict(obs_t, deterministic=True)
                values = torch.min(torch.cat(policy.critic(obs_t, actions), dim=1), dim=1).values
        return values.reshape(-1).cpu().numpy()

    return estimate


def reinitialise(model: BaseAlgorithm) -> None:
    """Fresh networks and optimisers (and an empty replay buffer for off-policy students): a
    forgetting student."""
    extra = {"use_sde": model.use_sde} if isinstance(model, OnPolicyAlgorithm) else {}
    model.policy = model.policy_class(
        model.observation_space,
        model.action_space,
        model.lr_schedule,
        **extra,
        **model.policy_kwargs,
    ).to(model.device)
    if isinstance(model, OffPolicyAlgorithm):
        model._create_aliases()  # actor / critic / target attributes point at the new policy
        model.replay_buffer.reset()
    if isinstance(model, SAC) and model.ent_coef_optimizer is not None:
        # a learned entropy coefficient starts afresh
        model.log_ent_coef = torch.zeros(1, device=model.device).requires_grad_(True)
        model.ent_coef_optimizer = torch.optim.Adam([model.log_ent_coef], lr=model.lr_schedule(1))
