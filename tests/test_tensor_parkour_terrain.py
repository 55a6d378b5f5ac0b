"""Parkour's records built for many worlds on tensors equal the CPU generator's, packed as the
single env's terrain would be (interpolated onto the grid, clipped, climbers shifted)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from acl3d.envs.parkour_arena import CEILING_RANGE, GROUND_RANGE
from acl3d.envs.world_families import ParkourWorlds


class Draws:
    """An RNG whose creeper draws are given (standard normals, in knot order)."""

    def __init__(self, normals: np.ndarray):
        self._normals = normals

    def normal(self, mean: float, std: float, size: int) -> np.ndarray:
        return mean + std * self._normals[:size]


def cpu_record(worlds: ParkourWorlds, task_vector: np.ndarray, rng) -> np.ndarray:
    """What the CPU generator gives one world (the reference the tensors must equal)."""
    env = worlds.template
    arena, x = env.arena, env.arena.grid.x
    t = arena.generator.generate(env.task_space.to_dict(task_vector), rng)
    hand_top = worlds.parkour_terrain.hand_top
    shift = hand_top - t.ceiling[0] if hand_top is not None else 0.0
    ground = np.clip(np.interp(x, t.x, t.ground + shift), *GROUND_RANGE)
    ceiling = np.clip(np.interp(x, t.x, t.ceiling + shift), *CEILING_RANGE)
    creepers = t.creepers + np.array([0.0, 0.0, shift, shift])
    return worlds.rules.record.terrain_row(ground, ceiling, t.water_z + shift, creepers)


@pytest.mark.parametrize("body", ["classic_bipedal", "climbing_profile_chimpanzee"])
def test_tensor_records_equal_the_cpu_generator_given_the_same_draws(body):
    worlds = ParkourWorlds(torch.device("cpu"), torch.float32, body=body)
    space = worlds.template.task_space
    rng = np.random.default_rng(0)
    vectors = [space.to_vector({}), space.low.astype(np.float64), space.high.astype(np.float64)]
    vectors += [rng.uniform(space.low, space.high) for _ in range(10)]
    # creepers from every knot to none, and a buildable task beyond the benchmark bounds
    wide = space.to_vector({"creepers_height": 3.0, "creepers_spacing": 0.0, "water_level": 1.0})
    vectors += [wide, space.to_vector({"creepers_height": 2.0, "terrain_cppn_scale": 40.0})]
    vectors = np.stack(vectors)
    terrain = worlds.parkour_terrain
    normals = terrain.draws(len(vectors), torch.Generator().manual_seed(3))
    built = terrain.records(torch.as_tensor(vectors), normals).numpy()
    for row, vector in enumerate(vectors):
        expected = cpu_record(worlds, vector, Draws(normals[row].numpy()))
        np.testing.assert_allclose(built[row], expected, rtol=1e-12, atol=1e-9)
    used = worlds.rules.record(torch.as_tensor(built), "creepers")[:, 2::4] > 0
    assert used.any() and not used.all()


def test_an_unbuildable_task_is_refused_naming_its_parameter():
    worlds = ParkourWorlds(torch.device("cpu"), torch.float32)
    space = worlds.template.task_space
    bad = space.to_vector({}).copy()
    bad[space.slice("terrain_cppn_scale")] = 500.0
    records, rows = worlds.terrain(np.arange(1), space.to_vector({})[None], torch.Generator(), [])
    assert records.shape == (1, worlds.rules.record.width) and rows.shape[:2] == (1, 2)
    with pytest.raises(ValueError, match="terrain_cppn_scale"):
        worlds.terrain(np.arange(1), bad[None], torch.Generator(), [])
