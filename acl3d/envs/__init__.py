"""Gymnasium registration and `make()` with the short names used by the CLI."""

from __future__ import annotations

import gymnasium as gym

MAX_EPISODE_STEPS = 2000  # the students' cut in TeachMyAgent (40 s at 50 Hz), a truncation

ENV_IDS: dict[str, str] = {
    "stump-tracks": "acl3d/StumpTracks-v0",
    "hexagon-tracks": "acl3d/HexagonTracks-v0",
    "parkour": "acl3d/Parkour-v0",
}
ENV_NAMES: tuple[str, ...] = tuple(ENV_IDS)

_ENTRY_POINTS = {
    "acl3d/StumpTracks-v0": ("acl3d.envs.track_env:TrackEnv", {"track": "stump"}),
    "acl3d/HexagonTracks-v0": ("acl3d.envs.track_env:TrackEnv", {"track": "hexagon"}),
    "acl3d/Parkour-v0": ("acl3d.envs.parkour_env:ParkourEnv", {}),
}
# gymnasium.make_vec(id, num_envs, vectorization_mode="vector_entry_point"): the batched env
_VECTOR_ENTRY_POINTS = {
    "acl3d/StumpTracks-v0": "acl3d.envs.batched_vector:stump_tracks",
    "acl3d/HexagonTracks-v0": "acl3d.envs.batched_vector:hexagon_tracks",
    "acl3d/Parkour-v0": "acl3d.envs.batched_vector:parkour",
}

for _id, (_entry, _kwargs) in _ENTRY_POINTS.items():
    if _id not in gym.registry:
        gym.register(
            id=_id,
            entry_point=_entry,
            vector_entry_point=_VECTOR_ENTRY_POINTS[_id],
            kwargs=_kwargs,
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
