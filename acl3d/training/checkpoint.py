"""Student-side state files: model, observation/return normalisation, replay buffer, RNG states.

Everything except SB3's own model zip is JSON + NPZ (acl3d.teachers.save_state), so a run can be
inspected or resumed without unpickling. A model `X.zip` keeps its normalisation statistics
beside it as `X_vecnormalize.json/.npz`.
"""

from __future__ import annotations

import random
from collections import deque
from pathlib import Path

import numpy as np
import torch
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.vec_env import VecNormalize

from acl3d.teachers.state_files import load_state, save_state
from acl3d.training.exclusion import ExcludingReplayBuffer
from acl3d.training.run_dir import read_state

_RMS = ("mean", "var", "count")
MODEL_MEMBERS = ("data", "policy.pth")  # what every SB3 model zip holds


def normalization_path(model_path) -> Path:
    path = Path(model_path)
    return path.with_name(path.stem + "_vecnormalize")


def save_normalization(vecnorm: VecNormalize, model_path) -> None:
    save_state(normalization_path(model_path), normalization_state(vecnorm))


def normalization_state(vecnorm: VecNormalize) -> dict:
    """The statistics and settings `observation_normalizer` needs (JSON + arrays)."""
    return {
        "obs_rms": {k: np.asarray(getattr(vecnorm.obs_rms, k)) for k in _RMS},
        "ret_rms": {k: np.asarray(getattr(vecnorm.ret_rms, k)) for k in _RMS},
        "clip_obs": vecnorm.clip_obs,
        "clip_reward": vecnorm.clip_reward,
        "gamma": vecnorm.gamma,
        "epsilon": vecnorm.epsilon,
        "norm_obs": vecnorm.norm_obs,
        "norm_reward": vecnorm.norm_reward,
    }


def load_normalization_into(vecnorm: VecNormalize, model_path) -> None:
    state = load_state(normalization_path(model_path))
    for key in ("obs_rms", "ret_rms"):
        rms = getattr(vecnorm, key)
        for k in _RMS:
            value = np.asarray(state[key][k], dtype=np.float64)
            setattr(rms, k, value if value.ndim else float(value))


def normalization_runtime(vecnorm: VecNormalize) -> dict:
    """What VecNormalize carries between steps besides its statistics: the running discounted
    return of each env (reward normalisation) and the last raw observations and rewards."""
    return {
        "returns": vecnorm.returns,
        "old_obs": vecnorm.old_obs,
        "old_reward": vecnorm.old_reward,
    }


def set_normalization_runtime(vecnorm: VecNormalize, state: dict) -> None:
    vecnorm.returns = np.asarray(state["returns"], dtype=np.float64).copy()
    vecnorm.old_obs, vecnorm.old_reward = state["old_obs"], state["old_reward"]


def algorithm_state(model) -> dict:
    """SB3's between-rollouts state that its zip stores only by pickle or not at all: the last
    observations and episode starts, the episode-info windows and the action space's RNG
    (SAC's random warm-up actions)."""
    return {
        "last_obs": model._last_obs,
        "last_episode_starts": model._last_episode_starts,
        "last_original_obs": model._last_original_obs,
        "ep_info_buffer": [_plain(info) for info in model.ep_info_buffer or ()],
        "ep_success_buffer": [bool(v) for v in model.ep_success_buffer or ()],
        "num_timesteps": int(model.num_timesteps),
        "episode_num": int(model._episode_num),
        "action_space_rng": model.action_space.np_random.bit_generator.state,
    }


def set_algorithm_state(model, state: dict) -> None:
    """Inverse of `algorithm_state` on a model loaded from the same checkpoint's zip."""
    model._last_obs = state["last_obs"]
    model._last_episode_starts = np.asarray(state["last_episode_starts"], dtype=bool)
    if state["last_original_obs"] is not None:
        model._last_original_obs = state["last_original_obs"]
    window = model._stats_window_size
    model.ep_info_buffer = deque(state["ep_info_buffer"], maxlen=window)
    model.ep_success_buffer = deque(state["ep_success_buffer"], maxlen=window)
    model.num_timesteps = int(state["num_timesteps"])
    model._episode_num = int(state["episode_num"])
    model.action_space.np_random.bit_generator.state = state["action_space_rng"]


def _plain(info: dict) -> dict:
    return {k: v.item() if isinstance(v, np.generic) else v for k, v in info.items()}


def observation_normalizer(model_path):
    """obs -> normalised obs with the statistics saved beside `model_path`, or None if none."""
    path = normalization_path(model_path)
    if not path.with_suffix(".json").exists():
        return None
    state = read_state(path)  # a damaged file is named
    if not state["norm_obs"]:
        return None
    mean = np.asarray(state["obs_rms"]["mean"])
    std = np.sqrt(np.asarray(state["obs_rms"]["var"]) + state["epsilon"])
    clip = state["clip_obs"]
    return lambda obs: np.clip((obs - mean) / std, -clip, clip).astype(np.float32)


def save_replay_buffer(buffer: ReplayBuffer, path) -> None:
    """The filled part of an SB3 replay buffer as NPZ (plus its write position, and the
    `excluded` flags of an `acl3d.training.exclusion.ExcludingReplayBuffer`)."""
    end = buffer.buffer_size if buffer.full else buffer.pos
    # a memory-saving buffer keeps each next observation in the next slot of `observations`
    nexts = () if buffer.optimize_memory_usage else ("next_observations",)
    names = ("observations", *nexts, "actions", "rewards", "dones", "timeouts")
    if isinstance(buffer, ExcludingReplayBuffer):
        names += ("excluded",)
    arrays = {name: getattr(buffer, name)[:end] for name in names}
    np.savez(Path(path), pos=np.int64(buffer.pos), full=np.bool_(buffer.full), **arrays)


def load_replay_buffer(buffer: ReplayBuffer, path) -> None:
    with np.load(Path(path), allow_pickle=False) as data:
        end = len(data["rewards"])
        if end > buffer.buffer_size:
            raise ValueError(
                f"replay buffer file {path} holds {end} transitions; buffer_size is {buffer.buffer_size}"
            )
        for name in data.files:
            if name == "excluded":
                buffer.set_excluded(data[name])  # also recounts what sampling may draw
            elif name not in ("pos", "full"):
                getattr(buffer, name)[:end] = data[name]
        buffer.pos, buffer.full = int(data["pos"]), bool(data["full"])


def rng_state() -> dict:
    """The global RNG states SB3 draws from (numpy for buffer sampling, torch, random)."""
    np_state = np.random.get_state(legacy=False)
    version, internal, gauss = random.getstate()
    return {
        "numpy": np_state,
        "torch": torch.get_rng_state().numpy(),
        "python": {
            "version": version,
            "state": np.asarray(internal, dtype=np.uint64),
            "gauss": gauss,
        },
    }


def set_rng_state(state: dict) -> None:
    np_state = dict(state["numpy"])
    np_state["state"] = {k: np.asarray(v, dtype=np.uint64) for k, v in np_state["state"].items()}
    np.random.set_state(np_state)
    torch.set_rng_state(torch.from_numpy(np.asarray(state["torch"], dtype=np.uint8)))
    py = state["python"]
    random.setstate((py["version"], tuple(int(v) for v in py["state"]), py["gauss"]))
