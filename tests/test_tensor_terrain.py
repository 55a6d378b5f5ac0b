"""Stump Tracks' height lines built for many worlds on tensors equal the CPU generator's."""

from __future__ import annotations

import numpy as np
import torch

from acl3d.envs.tensor_terrain import TensorStumpTracks
from acl3d.envs.track_env import TrackEnv


class Draws:
    """An RNG whose normal draws are given: the CPU generator then builds the same stumps."""

    def __init__(self, normals: np.ndarray):
        self._normals = iter(normals.tolist())

    def normal(self, mean: float, std: float) -> float:
        return mean + std * next(self._normals)


def test_tensor_stumps_equal_the_cpu_generator_given_the_same_draws():
    env = TrackEnv()
    space = env.task_space
    stumps = TensorStumpTracks(env.arena.grid, tuple(space.names), env.arena.start_pad, "cpu")
    assert stumps.supported
    rng = np.random.default_rng(0)
    tasks = [
        {"stump_height": 0.0, "obstacle_spacing": 0.0},
        {"stump_height": 3.0, "obstacle_spacing": 6.0},
    ]
    tasks += [dict(zip(space.names, rng.uniform([0, 0], [3, 6]))) for _ in range(14)]
    vectors = np.stack([space.to_vector(t) for t in tasks])
    normals = stumps.draws(len(tasks), torch.Generator().manual_seed(1))
    built = stumps.heights(torch.as_tensor(vectors), normals).numpy()
    for row, vector in enumerate(vectors):
        cpu = env.generator.heights(
            space.to_dict(vector), Draws(normals[row].numpy()), env.arena.start_pad
        )
        np.testing.assert_allclose(built[row], cpu, rtol=0, atol=1e-12)
    assert built.max() > 0


def test_other_track_kinds_stay_on_the_cpu_generator():
    env = TrackEnv(track="hexagon")
    stumps = TensorStumpTracks(
        env.arena.grid, tuple(env.task_space.names), env.arena.start_pad, "cpu"
    )
    assert not stumps.supported
