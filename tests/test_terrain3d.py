"""3D Terrain: the field, its task space and rules, the height scan, determinism and snapshots."""

from __future__ import annotations

import multiprocessing as mp

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import acl3d  # noqa: F401  (registers the ids)
from acl3d.envs.env_state import get_env_state, set_env_state
from acl3d.envs.height_scan import FORWARD, LATERAL
from acl3d.envs.track_rules import FAIL_REWARD
from acl3d.terrain import terrain3d_test_sets
from acl3d.terrain.terrain3d import HEIGHT_RANGE, Terrain3DGenerator, terrain3d_task_space
from tests.gl_support import require_offscreen_gl
from tests.test_determinism import rollout as hashed_rollout

ENV_ID = "acl3d/Terrain3D-v0"
TASK = {
    "block_height": 0.6,
    "block_width": 0.4,
    "block_spacing": 2.0,
    "cross_slope": 12.0,
    "hill_slope": 8.0,
    "roughness": 0.15,
}
SCAN = len(FORWARD) * len(LATERAL)


def rollout(**kwargs) -> str:
    """Hash of a big_quadru episode (resets included) on TASK: `tests.test_determinism`'s."""
    return hashed_rollout(ENV_ID, task=TASK, steps=120, planar=False, **kwargs)


# ---------------------------------------------------------------------- terrain
def test_the_easiest_task_is_flat_and_full_width_walls_span_the_field():
    gen = Terrain3DGenerator(start_pad=4.0)
    flat = gen.heights({"block_height": 0.0}, np.random.default_rng(0))
    assert flat.shape == (gen.grid.nrow, gen.grid.ncol) and not flat.any()
    walls = gen.heights({"block_height": 1.0, "block_width": 1.0}, np.random.default_rng(0))
    raised = walls.max(axis=0) > 0.5  # columns holding a wall
    assert raised.any() and (walls[:, raised] > 0.5).all()  # every row: nothing to walk around
    assert not walls[:, gen.grid.x < gen.start_pad].any()  # the start pad stays flat


def test_a_coarser_grid_samples_the_same_ground_and_bad_spacings_are_refused():
    fine = Terrain3DGenerator(4.0, cell=0.1, row_cell=0.25)
    coarse = Terrain3DGenerator(4.0, cell=0.5, row_cell=0.5)
    assert (coarse.grid.cell, coarse.grid.row_cell, coarse.grid.nrow) == (0.5, 0.5, 13)
    assert coarse.grid.x_min == fine.grid.x_min and coarse.grid.x_max >= fine.grid.x_max
    task = {"hill_slope": 10.0, "cross_slope": 5.0}  # no random heights: one smooth surface
    h_fine = fine.heights(task, np.random.default_rng(0))
    h_coarse = coarse.heights(task, np.random.default_rng(0))
    shared = h_fine[::2, ::5]  # every 0.5 m across and along
    np.testing.assert_allclose(h_coarse[:, : shared.shape[1]], shared, atol=1e-12)
    for name, value in (
        ("cell", 0.0),
        ("row_cell", 2.0),
        ("cell", float("nan")),
        ("row_cell", 0.35),
    ):
        with pytest.raises(ValueError, match=name):
            Terrain3DGenerator(4.0, **{name: value})


def test_narrow_blocks_leave_room_to_walk_around_and_slopes_vary_across_the_field():
    gen = Terrain3DGenerator(start_pad=4.0)
    blocks = gen.heights({"block_height": 1.0, "block_width": 0.3}, np.random.default_rng(1))
    covered = (blocks > 0.5).mean(axis=0)
    assert 0.25 < covered[covered > 0].mean() < 0.35  # 30% of the width per row of blocks
    twisted = gen.heights({"cross_slope": 20.0}, np.random.default_rng(1))
    across = np.diff(twisted, axis=0)  # height change from one row (y) to the next
    slope = np.tan(np.radians(20.0))
    assert np.abs(across).max() == pytest.approx(slope * gen.grid.row_cell, rel=0.01)


def test_blocks_keep_their_shape_on_the_grid():
    """A 0.5 m block is a block: flat on top over at least 0.4 m of its length, its front and
    back faces each rising within one 0.1 m cell (a wedge on 0.2 m cells had 0.2 m of top)."""
    gen = Terrain3DGenerator(start_pad=4.0)
    task = {"block_height": 1.0, "block_width": 1.0, "block_spacing": 3.0}
    h = gen.heights(task, np.random.default_rng(3))[0]  # flat ground: one row tells all
    raised = np.flatnonzero(h > 0)
    starts = raised[np.r_[True, np.diff(raised) > 1]]
    ends = raised[np.r_[np.diff(raised) > 1, True]]
    assert len(starts) == 6  # 1 m after the pad, then every 3.5 m of the 20 m course
    for first, last in zip(starts, ends):
        top = gen.grid.x[last] - gen.grid.x[first]  # the top's length (linear between points)
        assert 0.4 - 1e-9 <= top <= 0.5 and gen.grid.cell == pytest.approx(0.1)
        assert h[first - 1] == 0 and h[last + 1] == 0  # ground one cell before and after


def test_on_the_coarsest_grid_no_block_falls_between_its_points():
    gen = Terrain3DGenerator(start_pad=4.0, cell=0.5, row_cell=0.5)
    for seed, spacing in enumerate(np.linspace(1.0, 6.0, 11)):  # the benchmark's spacings
        task = {"block_height": 1.0, "block_width": 0.1, "block_spacing": spacing}  # 0.6 m wide
        h = gen.heights(task, np.random.default_rng(seed))
        columns = np.flatnonzero((h > 0.5).any(axis=0))
        rows_of_blocks = 1 + np.count_nonzero(np.diff(columns) > 1) if len(columns) else 0
        assert rows_of_blocks == len(list(gen.block_starts(spacing)))


def test_the_hardest_buildable_task_fits_the_heightfield_range():
    gen = Terrain3DGenerator(start_pad=4.0)
    worst = {
        "block_height": 3.0,
        "block_width": 1.0,
        "block_spacing": 0.0,
        "cross_slope": 40.0,
        "hill_slope": 40.0,
        "roughness": 0.5,
    }
    h = gen.heights(worst, np.random.default_rng(2))
    assert HEIGHT_RANGE[0] < h.min() and h.max() < HEIGHT_RANGE[1]


@pytest.mark.parametrize("spacing", [(0.1, 0.2), np.array([0.25, 0.5])])
def test_the_compiled_heightfield_is_what_mujoco_collides_with(spacing):
    env = gym.make(ENV_ID, grid_spacing=spacing).unwrapped
    env.reset(seed=0, options={"task": TASK})
    g, m, d = env.arena.grid, env.model, env.data
    assert (g.cell, g.row_cell) == tuple(spacing) and (m.hfield_nrow[0], m.hfield_ncol[0]) == (
        g.nrow,
        g.ncol,
    )
    geom = np.zeros(1, dtype=np.int32)
    for row, col in (
        (g.nrow // 10, g.ncol // 5),
        (g.nrow * 4 // 5, g.ncol // 3),
        (g.nrow // 2, g.ncol // 2),
    ):
        x, y = g.x[col], g.y[row]
        dist = mujoco.mj_ray(
            m, d, np.array([x, y, 20.0]), np.array([0, 0, -1.0]), None, 1, -1, geom
        )
        assert 20.0 - dist == pytest.approx(env.arena.heights[row, col], abs=1e-5)


# ---------------------------------------------------------------------- env API and inputs
@pytest.mark.parametrize(
    "body, observation, size",
    [
        ("big_quadru", "height_scan", 9 + 20 + SCAN + 1),
        ("big_quadru", "lidar", 9 + 20 + 10 + 1),
        ("classic_bipedal", "height_scan", 4 + 10 + SCAN + 1),
    ],
)
def test_check_env_and_observation_sizes(body, observation, size):
    env = gym.make(ENV_ID, body=body, observation=observation)
    assert env.observation_space.shape == (size,)
    check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(env, warn=False)


@pytest.mark.parametrize("body", ["spider", "dmc:ant", "dmc:cmu_humanoid", "small_bipedal"])
def test_other_walkers_run_on_the_field(body):
    """Each walker lands on the terrain and stays on the field, above the ground under it."""
    env = gym.make(ENV_ID, body=body)
    u = env.unwrapped
    env.reset(seed=0, options={"task": TASK})
    env.action_space.seed(0)
    terrain = u.model.geom("terrain").id
    root = u.model.cam_bodyid[u.model.camera(u.arena.camera).id]  # the camera rides the root
    grid, touched = u.arena.grid, 0
    for _ in range(40):
        obs, reward, terminated, _, _ = env.step(env.action_space.sample())
        assert np.isfinite(obs).all() and np.isfinite(reward)
        contacts = u.data.contact[: u.data.ncon]
        touched += any(terrain in (c.geom1, c.geom2) for c in contacts)
        x, y, z = u.data.xpos[root]
        assert grid.x_min < x < grid.x_max and abs(y) < grid.half_width
        row = round((y + grid.half_width) / grid.row_cell)
        col = round((x - grid.x_min) / grid.cell)
        assert z > u.arena.heights[row, col], f"{body}'s root below the ground at x={x:.2f}"
        if terminated:
            break
    assert touched, f"{body} never touched the terrain"


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"observation": "camera"}, "observation"),
        ({"task_parameters": ["block_height", "stump_height"]}, "task_parameters"),
        ({"task_parameters": "roughness"}, "task_parameters"),
        ({"task_parameters": []}, r"task_parameters=\[\]; valid: None or a non-empty list"),
        ({"task_parameters": ["roughness", 3]}, "terrain parameter names"),
        ({"grid_spacing": 0.2}, r"grid_spacing=0\.2; valid: two spacings"),
        ({"grid_spacing": (0.2, 0.2, 0.2)}, "grid_spacing"),
        ({"grid_spacing": [[0.2, 0.2]]}, "grid_spacing"),
        ({"grid_spacing": "0.2,0.2"}, "grid_spacing"),
        ({"grid_spacing": (0.01, 0.2)}, r"grid_spacing\[0\]=0\.01"),
        ({"grid_spacing": (0.2, 0.35)}, r"grid_spacing\[1\]=0\.35.*divides"),
        ({"grid_spacing": (0.6, 0.2)}, r"grid_spacing\[0\]=0\.6; valid: .*\[0\.05, 0\.5\]"),
        ({"grid_spacing": (0.2, 0.6)}, r"grid_spacing\[1\]=0\.6"),
    ],
)
def test_bad_options_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make(ENV_ID, **kwargs)


@pytest.mark.parametrize(
    "task, match",
    [
        ({"block_height": 3.5}, r"block_height.*3\.5"),
        ({"block_width": -0.1}, "block_width"),
        ({"roughness": np.nan}, "roughness"),
        ({"stump_height": 1.0}, "stump_height"),
    ],
)
def test_bad_tasks_raise_and_change_nothing(task, match):
    env = gym.make(ENV_ID).unwrapped
    env.reset(seed=0, options={"task": TASK})
    before = env.get_task()
    with pytest.raises(ValueError, match=match):
        env.reset(options={"task": task})
    assert env.get_task() == before


# ---------------------------------------------------------------------- rules
def _teleport(env, x=None, y=None):
    q = env.bound.root_qpos
    if x is not None:
        env.data.qpos[q] = x
    if y is not None:
        env.data.qpos[q + 1] = y
    mujoco.mj_forward(env.model, env.data)


def test_leaving_the_field_fails_and_crossing_the_line_succeeds():
    env = gym.make(ENV_ID).unwrapped
    env.reset(seed=0, options={"task": {"block_height": 0.0}})
    _teleport(env, y=env.arena.grid.half_width + 0.3)
    _, reward, terminated, _, info = env.step(np.zeros(env.action_space.shape))
    assert (reward, terminated, info["success"]) == (FAIL_REWARD, True, False)
    env.reset(seed=0)
    _teleport(env, x=env.rules.end_x + 0.2)
    _, reward, terminated, _, info = env.step(np.zeros(env.action_space.shape))
    assert terminated and info["success"] and reward > 100  # the progress of the jump


def test_progress_pays_and_drift_and_heading_cost():
    env = gym.make(ENV_ID).unwrapped
    env.reset(seed=0, options={"task": {"block_height": 0.0}})
    start = env.rows.prev_shaping[0]
    _teleport(env, x=env.data.qpos[env.bound.root_qpos] + 1.0)
    env.step(np.zeros(env.action_space.shape))
    forward = env.rows.prev_shaping[0] - start
    env.reset(seed=0)
    _teleport(env, x=env.data.qpos[env.bound.root_qpos] + 1.0, y=1.0)
    env.step(np.zeros(env.action_space.shape))
    assert forward == pytest.approx(15.0, abs=1.0)  # 15 per metre along x
    assert env.rows.prev_shaping[0] - start == pytest.approx(forward - 5.0, abs=1.0)


# ---------------------------------------------------------------------- determinism, snapshots
def test_two_instances_and_a_spawned_process_agree():
    with mp.get_context("spawn").Pool(1) as pool:
        other = pool.apply(rollout)
    assert rollout() == rollout() == other


@pytest.mark.parametrize(
    "observation, one_batch, spacing",
    [
        ("height_scan", True, (0.1, 0.5)),
        ("lidar", False, (0.1, 0.2)),
        ("height_scan", True, (0.5, 0.5)),
    ],
)
def test_batched_envs_match_single_envs(observation, one_batch, spacing):
    n, seed = 2, 5
    kwargs = {"observation": observation, "grid_spacing": spacing}
    vec = gym.make_vec(
        ENV_ID, num_envs=n, vectorization_mode="vector_entry_point", threads=2, **kwargs
    )
    # all sub-envs step as one MuJoCo batch; the height scan's rules run on (N, .) arrays,
    # ray-cast lidars' one sub-env after the other
    assert vec.unwrapped.batch.vectorised == one_batch
    singles = [gym.make(ENV_ID, **kwargs) for _ in range(n)]
    obs, _ = vec.reset(seed=seed, options={"task": TASK})
    for i, env in enumerate(singles):
        np.testing.assert_array_equal(obs[i], env.reset(seed=seed + i, options={"task": TASK})[0])
    rng = np.random.default_rng(0)
    for _ in range(60):
        actions = rng.uniform(-1, 1, (n, *vec.single_action_space.shape))
        obs, rewards, terminated, truncated, infos = vec.step(actions)
        for i, env in enumerate(singles):
            o, r, te, tr, info = env.step(actions[i])
            assert (r, te, tr, info["success"]) == (rewards[i], terminated[i], truncated[i], False)
            if te or tr:
                o, _ = env.reset()
            np.testing.assert_array_equal(o, obs[i])
    vec.close()


def test_a_snapshot_continues_identically_and_a_bad_one_changes_nothing():
    env, other = gym.make(ENV_ID), gym.make(ENV_ID)
    env.reset(seed=4, options={"task": TASK})
    for a in np.random.default_rng(6).uniform(-1, 1, (30, env.action_space.shape[0])):
        env.step(a)
    other.reset(seed=0)
    set_env_state(other, get_env_state(env))
    for a in np.random.default_rng(7).uniform(-1, 1, (40, env.action_space.shape[0])):
        o1, r1, t1, *_ = env.step(a)
        o2, r2, t2, *_ = other.step(a)
        np.testing.assert_array_equal(o1, o2)
        assert (r1, t1) == (r2, t2)
        if t1:
            break
    before = get_env_state(other)
    bad = dict(before, **{"terrain/heights": np.zeros((3, 3))})
    with pytest.raises(ValueError, match="terrain/heights"):
        set_env_state(other, bad)
    after = get_env_state(other)
    assert all(np.array_equal(np.asarray(before[k]), np.asarray(after[k])) for k in before)
    coarse = gym.make(ENV_ID, grid_spacing=(0.2, 0.2))  # a state of another grid: refused
    coarse.reset(seed=0)
    with pytest.raises(ValueError, match=r"state\['signature'\]"):
        set_env_state(other, get_env_state(coarse))
    assert all(
        np.array_equal(np.asarray(after[k]), np.asarray(v)) for k, v in get_env_state(other).items()
    )


# ---------------------------------------------------------------------- curriculum profile
def test_profile_prior_is_the_easy_corner_and_the_graded_set_rises_in_difficulty():
    env = gym.make(ENV_ID).unwrapped
    profile, space = env.curriculum_profile, env.task_space
    prior = profile.initial_distribution(space)
    easy = dict(zip(space.names, prior["mean"], strict=True))
    assert easy["block_height"] == 0.0 and easy["block_spacing"] == space.high[2]
    tasks = profile.test_sets["graded"](space, 50)
    assert tasks.shape == (50, 6) and np.array_equal(tasks, terrain3d_test_sets.graded(space, 50))
    assert ((space.low <= tasks) & (tasks <= space.high)).all()
    heights = tasks[:, space.names.index("block_height")]
    assert heights[:10].mean() < 0.2 < 1.3 < heights[-10:].mean()
    assert terrain3d_task_space(["roughness"]).names == ("roughness",)


# ---------------------------------------------------------------------- rendering
def test_offscreen_frames_show_the_new_terrain():
    require_offscreen_gl()
    env = gym.make(ENV_ID, render_mode="rgb_array", width=160, height=120)
    env.reset(seed=0, options={"task": {"block_height": 0.0}})
    flat = env.render()
    env.reset(seed=0, options={"task": dict(TASK, block_height=1.5, block_width=1.0)})
    walls = env.render()  # heights re-uploaded to the renderer after the new task
    env.close()
    assert flat.shape == (120, 160, 3) and flat.std() > 10
    assert not np.array_equal(flat, walls)
