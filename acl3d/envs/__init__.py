"""Gymnasium registration and `make()` with the short names used by the CLI."""

from __future__ import annotations

import importlib
import inspect
from typing import NamedTuple

import gymnasium as gym

from acl3d import validation

MAX_EPISODE_STEPS = 2000  # the students' cut in TeachMyAgent (40 s at 50 Hz), a truncation
# an episode above this return masters its task (TeachMyAgent's): every env's
# `CurriculumProfile.success_return` and Gymnasium's `reward_threshold`
REWARD_THRESHOLD = 230.0


class Registration(NamedTuple):
    """How one environment is registered with Gymnasium."""

    id: str  # the Gymnasium id
    entry_point: str  # "module:Class" of the single env
    kwargs: dict  # constructor arguments the id fixes
    vector_entry_point: str | None = None  # `gymnasium.make_vec(..., "vector_entry_point")`


# short name -> registration: adding an environment is one line here
REGISTRY: dict[str, Registration] = {
    "stump-tracks": Registration(
        "acl3d/StumpTracks-v0",
        "acl3d.envs.track_env:TrackEnv",
        {"track": "stump"},
        "acl3d.envs.batched_vector:stump_tracks",
    ),
    "hexagon-tracks": Registration(
        "acl3d/HexagonTracks-v0",
        "acl3d.envs.track_env:TrackEnv",
        {"track": "hexagon"},
        "acl3d.envs.batched_vector:hexagon_tracks",
    ),
    "parkour": Registration(
        "acl3d/Parkour-v0",
        "acl3d.envs.parkour_env:ParkourEnv",
        {},
        "acl3d.envs.batched_vector:parkour",
    ),
    "terrain3d": Registration(
        "acl3d/Terrain3D-v0",
        "acl3d.envs.terrain3d_env:Terrain3DEnv",
        {},
        "acl3d.envs.batched_vector:terrain3d",
    ),
}
ENV_IDS: dict[str, str] = {name: reg.id for name, reg in REGISTRY.items()}
ENV_NAMES: tuple[str, ...] = tuple(REGISTRY)

# Arguments of the batched vector env alone (`gymnasium.make_vec(..., "vector_entry_point")`).
VECTOR_ONLY_KWARGS = ("teacher", "curriculum_sync", "threads", "autoreset_mode", "device")


class SingleEnvEntryPoint:
    """Gymnasium's entry point of one acl3d env: its class (imported on first use), refusing the
    batched vector env's own arguments with a pointer to it, since `make_vec`'s "sync" and
    "async" modes hand every keyword to each single env."""

    def __init__(self, registration: Registration):
        self.registration = registration

    def __repr__(self) -> str:
        return f"SingleEnvEntryPoint({self.registration.entry_point!r})"

    def env_class(self) -> type:
        module, _, name = self.registration.entry_point.partition(":")
        return getattr(importlib.import_module(module), name)

    @property
    def metadata(self) -> dict:
        return self.env_class().metadata

    @property
    def __signature__(self) -> inspect.Signature:
        return inspect.signature(self.env_class())

    def __call__(self, **kwargs) -> gym.Env:
        given = [k for k in VECTOR_ONLY_KWARGS if k in kwargs]
        if given:
            raise TypeError(
                f"{self.registration.id}: {', '.join(given)} belong to the batched vector env; "
                f'build it with gymnasium.make_vec("{self.registration.id}", num_envs, '
                f'vectorization_mode="vector_entry_point", {given[0]}=...) (a single env, as '
                'gymnasium.make and make_vec\'s "sync" and "async" modes build, takes none)'
            )
        return self.env_class()(**kwargs)


for _reg in REGISTRY.values():
    if _reg.id not in gym.registry:
        gym.register(
            id=_reg.id,
            entry_point=SingleEnvEntryPoint(_reg),
            vector_entry_point=_reg.vector_entry_point,
            kwargs=_reg.kwargs,
            max_episode_steps=MAX_EPISODE_STEPS,
            reward_threshold=REWARD_THRESHOLD,
            # Gymnasium's passive checker, after a first reset that raised (a bad task), fails
            # the next step with a TypeError of its own; the test suite runs check_env instead
            disable_env_checker=True,
        )


def env_id(name: str) -> str:
    """Gymnasium id for a short name ("stump-tracks") or an id ("acl3d/StumpTracks-v0")."""
    if name in ENV_IDS:
        return ENV_IDS[name]
    if name in ENV_IDS.values():
        return name
    raise ValueError(f"unknown environment {name!r}; valid: {', '.join(ENV_NAMES)}")


def make(name: str, **kwargs) -> gym.Env:
    """`gymnasium.make` for acl3d environments, accepting the CLI's short names (a time limit
    is checked here, in acl3d's words, before Gymnasium's wrapper asserts on it)."""
    if "max_episode_steps" in kwargs:
        validation.integer("max_episode_steps", kwargs["max_episode_steps"], 1, 10**9)
    return gym.make(env_id(name), **kwargs)
