"""Gymnasium registration and `make()` with the short names used by the CLI."""

from __future__ import annotations

from typing import NamedTuple

import gymnasium as gym

MAX_EPISODE_STEPS = 2000  # the students' cut in TeachMyAgent (40 s at 50 Hz), a truncation


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

for _reg in REGISTRY.values():
    if _reg.id not in gym.registry:
        gym.register(
            id=_reg.id,
            entry_point=_reg.entry_point,
            vector_entry_point=_reg.vector_entry_point,
            kwargs=_reg.kwargs,
            max_episode_steps=MAX_EPISODE_STEPS,
        )


def env_id(name: str) -> str:
    """Gymnasium id for a short name ("stump-tracks") or an id ("acl3d/StumpTracks-v0")."""
    if name in ENV_IDS:
        return ENV_IDS[name]
    if name in ENV_IDS.values():
        return name
    raise ValueError(f"unknown environment {name!r}; valid: {', '.join(ENV_NAMES)}")


def make(name: str, **kwargs) -> gym.Env:
    """`gymnasium.make` for acl3d environments, accepting the CLI's short names."""
    return gym.make(env_id(name), **kwargs)
