"""The batched env: bit-identical to single envs, Gymnasium and SB3 vector conventions, inputs."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import acl3d  # noqa: F401  (registers the ids)
from acl3d.envs.batched import BatchedEnvs
from acl3d.vec.batched_sb3 import BatchedVecEnv

PARKOUR_WATER = {
    "input_vector": [0.2, -0.3, 0.1],
    "water_level": 0.9,
    "creepers_height": 2.0,
}  # both bodies wet, the climber grasps


def assert_matches_single_envs(
    env_id, n, threads, steps, seed=11, task=None, limit=None, mode=AutoresetMode.SAME_STEP, **kw
):
    """Sub-env i seeded seed + i == a single `gymnasium.make` env seeded seed + i, step by step,
    on the same tasks and actions, the single env reset as the vector env's `mode` says."""
    vec = gym.make_vec(
        env_id,
        num_envs=n,
        vectorization_mode="vector_entry_point",
        threads=threads,
        autoreset_mode=mode,
        **kw,
    )
    if limit is not None:
        vec.unwrapped.batch.max_episode_steps = limit
    singles = [gym.make(env_id, max_episode_steps=limit, **kw) for _ in range(n)]
    options = {"task": task} if task is not None else None
    obs, _ = vec.reset(seed=seed, options=options)
    for i, env in enumerate(singles):
        np.testing.assert_array_equal(obs[i], env.reset(seed=seed + i, options=options)[0])
    rng = np.random.default_rng(0)
    ends = 0
    ended = [False] * n
    for _ in range(steps):
        actions = rng.uniform(-1.1, 1.1, (n, *vec.single_action_space.shape)).astype(np.float32)
        obs, rewards, terminated, truncated, infos = vec.step(actions)
        for i, env in enumerate(singles):
            if ended[i]:  # NEXT_STEP: this step resets
                o, info = env.reset()
                r, te, tr = 0.0, False, False
            else:
                o, r, te, tr, info = env.step(actions[i])
            assert (r, te, tr) == (rewards[i], terminated[i], truncated[i])
            assert info["success"] == infos["success"][i]
            ended[i] = mode == AutoresetMode.NEXT_STEP and (te or tr)
            if (te or tr) and mode == AutoresetMode.SAME_STEP:
                np.testing.assert_array_equal(o, infos["final_obs"][i])
                o, _ = env.reset()
            ends += te or tr
            np.testing.assert_array_equal(o, obs[i])
    vec.close()
    return ends


@pytest.mark.parametrize("threads", [1, 2])
def test_stump_tracks_match_single_envs(threads):
    task = {"stump_height": 1.5, "obstacle_spacing": 1.0}
    assert assert_matches_single_envs("acl3d/StumpTracks-v0", 3, threads, 150, task=task, limit=40)


def test_next_step_autoreset_matches_single_envs():
    task = {"stump_height": 1.5, "obstacle_spacing": 1.0}
    ends = assert_matches_single_envs(
        "acl3d/StumpTracks-v0", 3, 2, 120, task=task, limit=30, mode=AutoresetMode.NEXT_STEP
    )
    assert ends >= 6


def test_free_3d_body_on_hexagon_tracks_matches_single_envs():
    kw = {"body": "spider", "planar": False}
    assert_matches_single_envs("acl3d/HexagonTracks-v0", 3, 3, 60, **kw)


@pytest.mark.parametrize("body", ["classic_bipedal", "climbing_profile_chimpanzee"])
def test_parkour_with_water_matches_single_envs(body):
    assert_matches_single_envs(
        "acl3d/Parkour-v0", 2, 2, 60, task=PARKOUR_WATER, body=body, mode=AutoresetMode.NEXT_STEP
    )


@pytest.mark.parametrize(
    "env_id, kw",
    [
        ("acl3d/StumpTracks-v0", {"task": {"stump_height": 1.5, "obstacle_spacing": 1.0}}),
        ("acl3d/Parkour-v0", {"task": PARKOUR_WATER, "body": "climbing_profile_chimpanzee"}),
    ],
)
def test_a_batch_of_one_matches_a_single_env(env_id, kw):
    """A batch of one steps its sub-env's own physics instead of MuJoCo's batch."""
    assert_matches_single_envs(env_id, 1, 1, 80, limit=40, mode=AutoresetMode.NEXT_STEP, **kw)


def test_state_moves_between_a_batch_of_one_and_a_batch():
    one, two = BatchedVecEnv("stump-tracks", 1), BatchedVecEnv("stump-tracks", 2, threads=2)
    one.seed(3)
    one.reset()
    two.reset()
    rng = np.random.default_rng(1)
    for _ in range(12):
        one.step(rng.uniform(-1, 1, (1, 4)))
    two.env_method("set_state", one.env_method("get_state")[0], indices=[1])
    for _ in range(25):
        actions = rng.uniform(-1, 1, (2, 4))
        o1, r1, d1, _ = one.step(actions[1:])
        o2, r2, d2, _ = two.step(actions)
        np.testing.assert_array_equal(o1[0], o2[1])
        assert (r1[0], d1[0]) == (r2[1], d2[1])
    one.env_method("set_state", two.env_method("get_state")[0], indices=[0])
    for _ in range(25):
        actions = rng.uniform(-1, 1, (2, 4))
        o1, r1, _, _ = one.step(actions[:1])
        o2, r2, _, _ = two.step(actions)
        np.testing.assert_array_equal(o1[0], o2[0])
        assert r1[0] == r2[0]


def test_make_vec_declares_next_step_autoreset_and_seeds_per_env():
    vec = gym.make_vec("acl3d/StumpTracks-v0", num_envs=3, vectorization_mode="vector_entry_point")
    assert vec.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert vec.observation_space.shape == (3, *vec.single_observation_space.shape)
    a, _ = vec.reset(seed=[4, 5, 6])
    b, _ = vec.reset(seed=4)
    np.testing.assert_array_equal(a, b)
    tasks = vec.unwrapped.batch.envs
    vec.reset(options=[{"task": {"stump_height": h}} for h in (0.0, 1.0, 2.0)])
    assert [env.get_task()["stump_height"] for env in tasks] == [0.0, 1.0, 2.0]
    vec.close()


def test_sb3_conventions_terminal_observation_and_time_limit():
    venv = BatchedVecEnv("stump-tracks", 2, max_episode_steps=5)
    venv.seed(3)
    venv.reset()
    single = gym.make("acl3d/StumpTracks-v0", max_episode_steps=5)
    single.reset(seed=3)
    zero = np.zeros((2, 4), dtype=np.float32)
    for _ in range(4):
        _, _, dones, _ = venv.step(zero)
        last, *_ = single.step(zero[0])
        assert not dones.any()
    obs, rewards, dones, infos = venv.step(zero)
    last, reward, *_ = single.step(zero[0])
    assert dones.all() and rewards.dtype == np.float32
    assert infos[0]["TimeLimit.truncated"] is True
    np.testing.assert_array_equal(infos[0]["terminal_observation"], last)
    assert rewards[0] == np.float32(reward)
    np.testing.assert_array_equal(obs[0], single.reset()[0])  # reset within the same step
    assert venv.get_attr("frame_skip", indices=[1]) == [single.unwrapped.frame_skip]
    venv.close()


def test_state_of_a_sub_env_restores_exactly():
    a, b = BatchedVecEnv("stump-tracks", 2, threads=2), BatchedVecEnv("stump-tracks", 2, threads=1)
    a.seed(5)
    a.reset()
    b.reset()
    rng = np.random.default_rng(0)
    for _ in range(10):
        a.step(rng.uniform(-1, 1, (2, 4)))
    for i, state in enumerate(a.env_method("get_state")):
        b.env_method("set_state", state, indices=[i])
    for _ in range(30):
        actions = rng.uniform(-1, 1, (2, 4))
        oa, ra, da, _ = a.step(actions)
        ob, rb, db, _ = b.step(actions)
        np.testing.assert_array_equal(oa, ob)
        np.testing.assert_array_equal(ra, rb)
        np.testing.assert_array_equal(da, db)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"num_envs": 0}, "num_envs"),
        ({"num_envs": "4"}, "num_envs"),
        ({"num_envs": True}, "num_envs"),
        ({"num_envs": 2, "threads": 0}, "threads"),
        ({"num_envs": 2, "threads": 1.5}, "threads"),
    ],
)
def test_bad_construction_arguments_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        BatchedEnvs("acl3d/StumpTracks-v0", **kwargs)


def test_bad_actions_raise_and_change_nothing():
    a, b = BatchedEnvs("stump-tracks", 2, threads=1), BatchedEnvs("stump-tracks", 2, threads=1)
    a.reset_one(0, seed=0)
    with pytest.raises(gym.error.ResetNeeded, match="reset"):  # sub-env 1 has no episode yet
        a.step(np.zeros((2, 4)))
    a.reset(seed=0)
    b.reset(seed=0)
    bad_nan = np.zeros((2, 4))
    bad_nan[1, 2] = np.nan
    for bad, match in [
        (np.zeros((3, 4)), "shape"),
        (np.zeros(4), "shape"),
        (bad_nan, "non-finite"),
        (np.full((2, 4), 1j), "real"),
    ]:
        with pytest.raises(ValueError, match=match):
            a.step(bad)
    ok = np.full((2, 4), 0.5)
    np.testing.assert_array_equal(a.step(ok)[0], b.step(ok)[0])
    with pytest.raises(ValueError, match="seed"):
        a.reset(seed=[1, 2, 3])


def _stacked_one_by_one(infos: list[dict], mask: np.ndarray) -> dict:
    """Gymnasium's vector info layout built from one dict per sub-env (the reference)."""
    out = {}
    for key in sorted(set().union(*infos)):
        values = [info.get(key) for info in infos]
        has = np.array([key in info for info in infos]) & mask
        if all(type(v) is bool or v is None for v in values):
            arr = np.array([bool(v) for v in values]) & has
        else:
            arr = np.zeros(len(infos), dtype=object)
            arr[has] = [values[i] for i in has.nonzero()[0]]
        out[key], out["_" + key] = arr, has
    return out


@pytest.mark.parametrize("seed", range(6))
def test_infos_laid_out_from_flags_equal_those_stacked_one_by_one(seed):
    from acl3d.envs.batched_vector import _stack_infos

    rng = np.random.default_rng(seed)
    n = 7
    success, unstable = rng.random(n) < 0.5, rng.random(n) < 0.3 * (seed % 2)
    mask = rng.random(n) < 0.8
    special = {}
    for i in rng.choice(n, size=3, replace=False).tolist():  # resets and finished episodes
        special[i] = {"success": bool(rng.random() < 0.5)} if rng.random() < 0.5 else {}
        if rng.random() < 0.7:
            special[i]["curriculum"] = {"return": float(i)}
    infos = [
        {"success": bool(s)} | ({"unstable": True} if u else {}) for s, u in zip(success, unstable)
    ]
    if seed in (0, 1):  # no reset and no finished episode: every info is the flags'
        special = {}
    if seed == 5:  # the only unstable sub-env is reset: no info holds "unstable"
        unstable[:] = False
        unstable[next(iter(special))] = True
        infos = [{"success": bool(s)} for s in success]
    for i, info in special.items():
        infos[i] = info
    flags = {"success": (success, np.ones(n, bool))}
    if unstable.any():
        flags["unstable"] = (unstable, unstable)
    got = _stack_infos(n, mask, special, flags)
    expected = _stacked_one_by_one(infos, mask)
    assert sorted(got) == sorted(expected)
    for key, value in expected.items():
        assert got[key].dtype == value.dtype, key
        assert [v for v in got[key]] == [v for v in value], key
