"""get_state() / set_state(): an env restored mid-episode continues bit-identically."""

import json

import gymnasium as gym
import numpy as np
import pytest

from acl3d.envs.env_state import get_env_state, is_serialisable, set_env_state

CASES = {
    "stump": ("acl3d/StumpTracks-v0", {"body": "fish"}, {"stump_height": 1.5}),
    "hexagon": (
        "acl3d/HexagonTracks-v0",
        {"body": "millipede", "body_options": {"nb_of_bodies": 3}},
        {"poly_shape": np.full(12, 0.5)},
    ),
    "parkour-water": ("acl3d/Parkour-v0", {"body": "fish"}, {"water_level": 0.8}),
    "parkour-climber": (
        "acl3d/Parkour-v0",
        {"body": "climbing_profile_chimpanzee"},
        {"creepers_height": 2.0, "creepers_spacing": 1.0},
    ),
    "parkour-movable-creepers": (
        "acl3d/Parkour-v0",
        {"body": "amphibious_bipedal", "movable_creepers": True},
        {"water_level": 0.6, "creepers_height": 3.0, "creepers_spacing": 0.5},
    ),
}


def save_and_load(state: dict, tmp_path) -> dict:
    """Through the run directory's formats: JSON for scalars, NPZ for arrays (no pickle)."""
    assert is_serialisable(state)
    arrays = {k: v for k, v in state.items() if isinstance(v, np.ndarray)}
    scalars = {k: v for k, v in state.items() if k not in arrays}
    (tmp_path / "state.json").write_text(json.dumps(scalars))
    np.savez(tmp_path / "state.npz", **arrays)
    with np.load(tmp_path / "state.npz", allow_pickle=False) as npz:
        return {**json.loads((tmp_path / "state.json").read_text()), **dict(npz)}


def play(env, actions) -> list:
    """Everything the agent sees; through the end of the episode and one more reset."""
    out = []
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        out.append((obs.tobytes(), reward, terminated, truncated, info["success"]))
        if terminated or truncated:
            break
    obs, _ = env.reset()  # the env's RNG draws the next terrain and push
    out.append((obs.tobytes(), env.unwrapped.model.hfield_data.tobytes()))
    return out


@pytest.mark.parametrize("case", CASES)
def test_restored_env_continues_bit_identically(case, tmp_path):
    env_id, kwargs, task = CASES[case]
    env = gym.make(env_id, **kwargs)
    actions = np.random.default_rng(1).uniform(-1, 1, (220, env.action_space.shape[0]))
    env.reset(seed=5, options={"task": task})
    for a in actions[:60]:
        assert not any(env.step(a)[2:4])
    state = save_and_load(get_env_state(env), tmp_path)
    expected = play(env, actions[60:])

    fresh = gym.make(env_id, **kwargs)  # a new instance that already played other episodes
    fresh.reset(seed=99)
    for a in actions[:30]:
        fresh.step(-a)
    fresh.reset(seed=3, options={"task": fresh.unwrapped.task_space.to_vector({})})
    set_env_state(fresh, state)
    assert play(fresh, actions[60:]) == expected
    assert len(expected) > 20 or expected[-2][2]  # a real stretch of episode, or its end


def test_water_and_grasp_state_round_trip():
    env = gym.make(CASES["parkour-climber"][0], **CASES["parkour-climber"][1])
    env.reset(seed=0, options={"task": {"creepers_height": 2.0, "water_level": 0.4}})
    state = env.unwrapped.get_state()
    assert state["climbing/holding"].any()  # hanging from the ceiling after reset
    assert {"terrain/creepers", "terrain/water_z", "survival/steps_under_water"} <= set(state)
    assert state["physics/eq_data"].shape[0] == 2  # one weld per hand


def test_time_limit_counter_restores_through_the_wrappers():
    env = gym.make("acl3d/StumpTracks-v0", body="fish", max_episode_steps=50)
    env.reset(seed=1)
    zeros = np.zeros(env.action_space.shape)
    for _ in range(40):
        env.step(zeros)
    state = get_env_state(env)
    fresh = gym.make("acl3d/StumpTracks-v0", body="fish", max_episode_steps=50)
    fresh.reset(seed=2)
    set_env_state(fresh, state)
    truncated = [fresh.step(zeros)[3] for _ in range(10)]
    assert truncated == [False] * 9 + [True]


def same_state(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


def test_rejected_states_change_nothing():
    env = gym.make("acl3d/StumpTracks-v0").unwrapped
    with pytest.raises(gym.error.ResetNeeded):
        env.get_state()
    env.reset(seed=0)
    env.step(np.full(4, 0.5))
    before = env.get_state()
    other = gym.make("acl3d/StumpTracks-v0", body="small_bipedal").unwrapped
    other.reset(seed=0)
    bad_physics = {**before, "physics/now": before["physics/now"] + 1e-3}
    bad_rng = {**before, "rng/state/state": "not a number"}
    for bad, match in [
        (other.get_state(), "signature"),
        (bad_physics, "replaying its last physics step"),
        (bad_rng, "rng/state/state"),
        ({**before, "task_vector": np.array([1.0, np.nan])}, "task_vector"),
        ({**before, "task_vector": np.array([100.0, 1.0])}, "stump_height"),
        ({**before, "episode_return": "3"}, "episode_return"),
        ({k: v for k, v in before.items() if k != "terrain/heights"}, "terrain/heights"),
        ({k: v for k, v in before.items() if k != "episode_return"}, "episode_return"),
        ({k: v for k, v in before.items() if k != "physics/now"}, "physics/now"),
        ([1, 2], "state"),
    ]:
        with pytest.raises(ValueError, match=match):
            env.set_state(bad)
        assert same_state(env.get_state(), before)
    env.set_state(before)  # and the good one still restores
    assert same_state(env.get_state(), before)
