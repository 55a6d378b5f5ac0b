"""The height scan: 3D Terrain's heights around the body in its heading frame, on N envs at
once, and on the tracks' height lines."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import acl3d  # noqa: F401  (registers the ids)
from acl3d.envs.height_scan import FORWARD, LATERAL
from tests.test_terrain3d import ENV_ID, SCAN, TASK, _teleport


@pytest.mark.parametrize("spacing", [(0.1, 0.2), (0.25, 0.5)])
def test_height_scan_reads_the_terrain_around_the_body_in_its_heading_frame(spacing):
    env = gym.make(ENV_ID, grid_spacing=spacing).unwrapped
    env.reset(seed=0, options={"task": TASK})
    _teleport(env, x=12.0, y=-0.5)
    g, h = env.arena.grid, env.arena.heights
    scan, root = env.rules.lidar, env.bound.root_id
    origin = env.data.xpos[root].copy()
    for yaw in (0.0, 0.7, np.pi / 2):  # turn the body: the grid turns with it
        q = env.bound.root_qpos
        env.data.qpos[q + 3 : q + 7] = (np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2))
        mujoco.mj_forward(env.model, env.data)
        got = scan.read_batch(
            env.rows.heights, env.data.xpos[root][None], env.data.xmat[root][None]
        )
        dx, dy = np.meshgrid(FORWARD, LATERAL)
        px = origin[0] + np.cos(yaw) * dx - np.sin(yaw) * dy
        py = origin[1] + np.sin(yaw) * dx + np.cos(yaw) * dy
        u, v = (px - g.x_min) / g.cell, (py + g.half_width) / g.row_cell
        i, j = np.floor(u).astype(int), np.floor(v).astype(int)
        a, b = u - i, v - j
        expected = (
            h[j, i] * (1 - a) * (1 - b)
            + h[j, i + 1] * a * (1 - b)
            + h[j + 1, i] * (1 - a) * b
            + h[j + 1, i + 1] * a * b
        )
        np.testing.assert_allclose(got[0], expected.ravel() - origin[2], atol=1e-9)


def test_height_scan_of_n_envs_is_bit_identical_to_each_alone():
    env = gym.make(ENV_ID).unwrapped
    scan, root, heights, origins, rotations = env.rules.lidar, env.bound.root_id, [], [], []
    for seed in range(3):
        env.reset(seed=seed, options={"task": TASK})
        for _ in range(10 * seed + 5):
            env.step(env.action_space.sample())
        heights.append(env.rows.heights[0].copy())
        origins.append(env.data.xpos[root].copy())
        rotations.append(env.data.xmat[root].copy())
    batch = scan.read_batch(np.stack(heights), np.stack(origins), np.stack(rotations))
    for i in range(3):
        alone = scan.read_batch(heights[i][None], origins[i][None], rotations[i][None])
        np.testing.assert_array_equal(batch[i], alone[0])


def test_height_scan_on_stump_tracks_reads_the_height_line_at_every_lateral_offset():
    env = gym.make("acl3d/StumpTracks-v0", observation="height_scan").unwrapped
    obs, _ = env.reset(seed=0, options={"task": {"stump_height": 2.0, "obstacle_spacing": 1.0}})
    assert obs.shape == (4 + 10 + SCAN,)
    x0, _, z0 = env.data.xpos[env.bound.root_id]
    expected = np.interp(x0 + FORWARD, env.arena.grid.x, env.arena.heights) - z0
    np.testing.assert_allclose(
        obs[14:].reshape(len(LATERAL), -1), np.tile(expected, (7, 1)), atol=1e-5
    )
    with pytest.raises(ValueError, match="observation"):
        gym.make("acl3d/StumpTracks-v0", observation="heights")


def test_height_scan_on_stump_tracks_batched_matches_single_envs():
    from tests.test_batched_env import assert_matches_single_envs

    task = {"stump_height": 1.5, "obstacle_spacing": 1.0}
    kw = {"body": "spider", "planar": False, "observation": "height_scan"}
    assert_matches_single_envs("acl3d/StumpTracks-v0", 2, 2, 50, task=task, limit=30, **kw)
