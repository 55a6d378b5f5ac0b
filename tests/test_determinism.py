"""Same seed + same task + same actions => bit-identical observations, rewards, flags and terrain."""

import hashlib
import multiprocessing as mp

import gymnasium as gym
import numpy as np
import pytest

TASK = {"stump_height": 1.8, "obstacle_spacing": 1.5}


def rollout(
    env_id="acl3d/StumpTracks-v0", seed=7, task=TASK, steps=300, env=None, planar=True
) -> str:
    """Hash of everything an episode produces (terrain included), for exact comparison."""
    import acl3d  # noqa: F401  (spawned processes register the ids themselves)

    env = env or gym.make(env_id, planar=planar)
    actions = np.random.default_rng(123).uniform(-1, 1, (steps, env.action_space.shape[0]))
    h = hashlib.sha256()
    obs, _ = env.reset(seed=seed, options={"task": task})
    h.update(env.unwrapped.model.hfield_data.tobytes())
    h.update(obs.tobytes())
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        h.update(obs.tobytes())
        h.update(np.float64(reward).tobytes())
        h.update(bytes([terminated, truncated, info["success"]]))
        if terminated or truncated:
            obs, _ = env.reset()
            h.update(env.unwrapped.model.hfield_data.tobytes())
            h.update(obs.tobytes())
    return h.hexdigest()


@pytest.mark.parametrize("env_id", ["acl3d/StumpTracks-v0", "acl3d/HexagonTracks-v0"])
def test_two_instances_agree(env_id):
    task = TASK if "Stump" in env_id else {"poly_shape": np.full(12, 1.5)}
    assert rollout(env_id, task=task) == rollout(env_id, task=task)


def test_free_body_two_instances_agree():
    assert rollout(planar=False) == rollout(planar=False)


def test_reset_of_the_same_instance_agrees():
    env = gym.make("acl3d/StumpTracks-v0")
    first = rollout(env=env)
    env.reset(seed=99, options={"task": {"stump_height": 0.2, "obstacle_spacing": 5.0}})
    assert rollout(env=env) == first


def test_spawned_processes_agree():
    ctx = mp.get_context("spawn")
    with ctx.Pool(2) as pool:
        a, b = pool.map(rollout, ["acl3d/StumpTracks-v0"] * 2)
    assert a == b == rollout()


def test_seed_or_task_changes_the_terrain():
    env = gym.make("acl3d/StumpTracks-v0").unwrapped
    env.reset(seed=1, options={"task": TASK})
    base = env.arena.heights.copy()
    env.reset(seed=2, options={"task": TASK})
    assert not np.array_equal(env.arena.heights, base)
    env.reset(seed=1, options={"task": {"stump_height": 1.9, "obstacle_spacing": 1.5}})
    assert not np.array_equal(env.arena.heights, base)
    env.reset(seed=1, options={"task": TASK})
    assert np.array_equal(env.arena.heights, base)


def play_hash(env, steps: int = 150) -> str:
    h = hashlib.sha256()
    for a in np.random.default_rng(5).uniform(-1, 1, (steps, env.action_space.shape[0])):
        obs, reward, terminated, truncated, _ = env.step(a)
        h.update(obs.tobytes())
        h.update(np.float64(reward).tobytes())
        h.update(bytes([terminated, truncated]))
    return h.hexdigest()


def continue_from(state: dict) -> str:
    """What a fresh Parkour env plays after restoring `state` (run in another process)."""
    import acl3d  # noqa: F401
    from acl3d.envs.env_state import set_env_state

    env = gym.make("acl3d/Parkour-v0", body="fish")
    env.reset(seed=0)
    set_env_state(env, state)
    return play_hash(env)


def test_a_saved_state_continues_identically_in_another_process():
    from acl3d.envs.env_state import get_env_state

    env = gym.make("acl3d/Parkour-v0", body="fish")
    env.reset(seed=4, options={"task": {"water_level": 0.7}})
    for a in np.random.default_rng(6).uniform(-1, 1, (40, env.action_space.shape[0])):
        env.step(a)
    state = get_env_state(env)
    with mp.get_context("spawn").Pool(1) as pool:
        other = pool.apply(continue_from, (state,))
    assert other == play_hash(env)
