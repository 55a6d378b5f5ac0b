"""The Gymnasium API of Stump Tracks and Hexagon Tracks: spaces, tasks, rewards, termination, errors."""

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import acl3d
from acl3d.envs.track_rules import FAIL_REWARD, PROGRESS_GAIN


def make(name="acl3d/StumpTracks-v0", **kw):
    return gym.make(name, **kw)


@pytest.mark.parametrize("env_id", ["acl3d/StumpTracks-v0", "acl3d/HexagonTracks-v0"])
@pytest.mark.parametrize("planar", [True, False])
def test_env_checkers_pass(env_id, planar):
    env = make(env_id, planar=planar)
    check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env.unwrapped, warn=False)


def test_spaces_match_the_original_biped():
    env = make()
    assert env.action_space.shape == (4,)
    assert np.all(env.action_space.low == -1) and np.all(env.action_space.high == 1)
    obs, info = env.reset(seed=0)
    assert obs.shape == (24,) and obs.dtype == np.float32
    assert "success" in info
    lidar = obs[-10:]
    assert np.all((lidar >= 0) & (lidar <= 1))
    assert make(planar=False).observation_space.shape == (
        29,
    )  # + roll, yaw, lateral velocity and rates


def test_short_names_and_bad_names():
    assert acl3d.make("stump-tracks").spec.id == "acl3d/StumpTracks-v0"
    with pytest.raises(ValueError, match="stump-tracks"):
        acl3d.make("stumps")
    with pytest.raises(ValueError, match="classic_bipedal"):
        make(body="no_such_body")


def test_task_from_reset_options_persists_and_partial_dicts_use_defaults():
    env = make().unwrapped
    env.reset(seed=0, options={"task": {"stump_height": 2.5, "obstacle_spacing": 1.0}})
    first = env.arena.heights.copy()
    env.reset(seed=0)
    assert env.get_task() == {"stump_height": 2.5, "obstacle_spacing": 1.0}
    assert np.array_equal(env.arena.heights, first)
    env.set_task({"stump_height": 0.5})  # a partial dict: the other parameters at their defaults
    env.reset(seed=0)
    assert env.get_task() == {"stump_height": 0.5, "obstacle_spacing": 8.0}
    env.set_task(np.array([1.0, 2.0]))
    assert env.get_task() == {"stump_height": 1.0, "obstacle_spacing": 2.0}


def test_new_task_rewrites_heights_in_place_without_recompiling():
    env = make().unwrapped
    model = env.model
    env.reset(seed=0, options={"task": {"stump_height": 0.0, "obstacle_spacing": 6.0}})
    low = env.model.hfield_data.copy()
    env.reset(seed=0, options={"task": {"stump_height": 3.0, "obstacle_spacing": 0.5}})
    assert env.model is model
    assert env.model.hfield_data.max() > low.max()
    # collisions see the new terrain at once: a ray down onto the first stump hits its top
    hit = np.zeros(1, np.int32)
    x = env.generator.x[np.argmax(env.arena.heights > 0)] + 0.2
    dist = mujoco.mj_ray(
        env.model, env.data, np.array([x, 0.0, 5.0]), np.array([0, 0, -1.0]), None, 1, -1, hit
    )
    assert dist == pytest.approx(5.0 - env.arena.ground_height(x), abs=0.05)


@pytest.mark.parametrize(
    "task, match",
    [
        ({"stump_hieght": 1.0}, "stump_hieght"),
        ({"stump_height": float("nan")}, "stump_height"),
        ({"stump_height": [1.0, 2.0]}, "stump_height"),
        ({"stump_height": 100.0}, "stump_height"),
        (np.array([1.0, 2.0, 3.0]), "shape"),
    ],
)
def test_bad_tasks_raise_clear_errors(task, match):
    env = make().unwrapped
    env.reset(seed=0)
    before = env.get_task()
    with pytest.raises(ValueError, match=match):
        env.reset(seed=0, options={"task": task})
    assert env.get_task() == before


def test_values_beyond_benchmark_bounds_are_accepted():
    env = make().unwrapped
    env.reset(seed=0, options={"task": {"stump_height": 9.0, "obstacle_spacing": 12.0}})
    assert env.arena.heights.max() > 3.5


def test_bad_actions_raise():
    env = make()
    env.reset(seed=0)
    before = env.unwrapped.get_state()
    for action in (np.zeros(3), np.array([0, np.nan, 0, 0]), np.array([0.5j, 0, 0, 0]), ["1"] * 4):
        with pytest.raises(ValueError, match="action="):
            env.step(action)
    after = env.unwrapped.get_state()
    assert all(np.array_equal(before[k], after[k]) for k in before)


def same_state(env, before) -> bool:
    after = env.get_state()
    return all(np.array_equal(before[k], after[k]) for k in before)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"options": {"task": {"stump_height": 2.0}, "tsk": 1}}, "tsk"),
        ({"seed": 7, "options": {"task": {"stump_height": np.nan}}}, "stump_height"),
        ({"seed": 7, "options": {"task": {"stump_height": "2"}}}, "stump_height='2'"),
        ({"seed": True}, "seed=True"),
        ({"seed": -1}, "seed=-1"),
        ({"seed": 1.0}, "seed=1.0"),
        ({"options": [("task", {})]}, "options="),
    ],
)
def test_a_rejected_reset_changes_nothing(kwargs, match):
    env = make().unwrapped
    env.reset(seed=0)
    env.step(np.full(4, 0.3))
    before = env.get_state()
    with pytest.raises(ValueError, match=match):
        env.reset(**kwargs)
    assert same_state(env, before)  # task, RNG (no reseed), terrain and physics untouched


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"planar": "False"}, "planar='False'"),
        ({"frame_skip": 2.0}, "frame_skip=2.0"),
        ({"frame_skip": True}, "frame_skip=True"),
        ({"width": 0}, "width=0"),
        ({"camera": "nowhere"}, "camera='nowhere'"),
        ({"body_options": [("nb_of_bodies", 3)]}, "body_options="),
        ({"task_parameters": "stump_height"}, "task_parameters="),
        ({"task_parameters": ()}, "task_parameters=()"),
        ({"body": 3}, "body=3"),
        ({"quality": "best"}, "quality='best'"),
    ],
)
def test_bad_constructor_arguments_name_the_argument(kwargs, match):
    with pytest.raises(ValueError, match=match):
        make(**kwargs)


def test_forward_progress_reward_and_success_flag():
    env = make().unwrapped
    env.reset(seed=0, options={"task": {"stump_height": 0.0, "obstacle_spacing": 6.0}})
    env.data.qpos[env.bound.root_qpos] += 1.0  # teleport 1 m forward
    mujoco.mj_forward(env.model, env.data)
    _, reward, terminated, _, info = env.step(np.zeros(4))
    assert not terminated
    assert reward == pytest.approx(PROGRESS_GAIN * 1.0, abs=0.3)
    assert info["success"] is False


def test_hull_contact_terminates_with_minus_100():
    env = make().unwrapped
    env.reset(seed=0)
    env.data.qpos[env.bound.root_qpos + 2] = np.pi  # upside down: the hull lands first
    mujoco.mj_forward(env.model, env.data)
    for _ in range(200):
        _, reward, terminated, _, _ = env.step(np.zeros(4))
        if terminated:
            break
    assert terminated and reward == FAIL_REWARD


def test_going_behind_the_start_terminates():
    env = make().unwrapped
    env.reset(seed=0)
    env.data.qpos[env.bound.root_qpos] = -env.arena.start_x - 0.5
    mujoco.mj_forward(env.model, env.data)
    _, reward, terminated, _, _ = env.step(np.zeros(4))
    assert terminated and reward == FAIL_REWARD


def test_crossing_the_end_line_terminates():
    env = make().unwrapped
    env.reset(seed=0, options={"task": {"stump_height": 0.0, "obstacle_spacing": 6.0}})
    env.data.qpos[env.bound.root_qpos] = 89.0 - env.arena.start_x
    mujoco.mj_forward(env.model, env.data)
    _, reward, terminated, _, info = env.step(np.zeros(4))
    # the whole track's progress (start to end line) is worth ~364 > 230, hence success
    assert terminated and reward == pytest.approx(
        PROGRESS_GAIN * (89.0 - env.arena.start_x), abs=0.5
    )
    assert info["success"] is True


def test_time_limit_truncates_at_2000_steps():
    env = make()
    assert env.spec.max_episode_steps == 2000
    env = make(max_episode_steps=3)
    env.reset(seed=0)
    out = [env.step(np.zeros(4)) for _ in range(3)]
    assert out[-1][3] is True and not out[-1][2]


def test_zero_action_settles_without_exploding():
    env = make().unwrapped
    env.reset(seed=0)
    for _ in range(300):
        obs, *_ = env.step(np.zeros(4))
    assert np.all(np.isfinite(obs))
    assert np.all(env.data.warning.number == 0)
    assert np.abs(env.data.qvel).max() < 1.0  # at rest (fallen or crouched)


def test_random_actions_stay_stable():
    env = make().unwrapped
    rng = np.random.default_rng(0)
    env.reset(seed=0, options={"task": {"stump_height": 2.0, "obstacle_spacing": 1.0}})
    for _ in range(2000):
        obs, _, terminated, _, _ = env.step(rng.uniform(-1, 1, 4))
        assert np.all(np.isfinite(obs))
        if terminated:
            env.reset()
    assert np.all(env.data.warning.number == 0)


def test_lidar_matches_mujoco_ray_casting_and_ignores_the_body():
    from acl3d.envs.lidar import Lidar

    env = make().unwrapped
    rng = np.random.default_rng(0)
    reference = Lidar("down")  # mj_multiRay on the compiled heightfield, terrain group only
    for episode in range(5):
        env.reset(
            seed=episode,
            options={
                "task": {"stump_height": rng.uniform(0, 5), "obstacle_spacing": rng.uniform(0, 4)}
            },
        )
        for _ in range(100):
            origin = np.array([rng.uniform(-4, 100), rng.uniform(-1, 1), rng.uniform(0.05, 6)])
            if origin[2] <= env.arena.ground_height(origin[0]):
                continue
            expected = reference.read(env.model, env.data, origin).copy()
            assert np.allclose(
                env.rules.lidar.read(env.model, env.data, origin), expected, atol=1e-5
            )
    # the body is never seen: rays from inside the hull still reach the ground below
    obs, _ = env.reset(seed=0, options={"task": {"stump_height": 0.0, "obstacle_spacing": 6.0}})
    assert obs[-10] == pytest.approx((env.data.xpos[env.bound.root_id][2]) / (160 / 30), abs=1e-3)


def test_height_line_lidar_reads_flat_ground_alone_and_in_a_batch():
    """Over flat ground h below, ray i (angle t_i from the vertical) reads h / cos(t_i) as a
    fraction of the range, or 1 where that is out of range (also when the ground falls away
    out of range: the line through the last segment in reach is no hit); the same row in a
    batch of three."""
    env = make().unwrapped
    env.reset(seed=0, options={"task": {"stump_height": 0.0, "obstacle_spacing": 6.0}})
    lidar, grid = env.rules.lidar, env.arena.grid
    angles = 1.5 * np.arange(10) / 10
    heights = lidar.batch_heights(3)
    beyond = grid.x - (10.0 + 160 / 30)
    heights[2, : grid.ncol] = np.where(beyond > 0.0, -2.0 * beyond, 0.0)
    origins = np.array([[10.0, 0.0, h] for h in (1.0, 5.0, 5.5)])
    out = lidar.read_batch(heights, origins)
    for row, h in zip(out, origins[:, 2]):
        expected = np.minimum(h / np.cos(angles) / (160 / 30), 1.0)
        np.testing.assert_allclose(row, expected, rtol=1e-12)
    for i in range(3):
        alone = lidar.read_batch(heights[i : i + 1], origins[i : i + 1])
        assert np.array_equal(alone, out[i : i + 1])
