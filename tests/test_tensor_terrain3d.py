"""3D Terrain's fields built for many worlds on tensors equal the CPU generator's."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from acl3d.envs.tensor_terrain3d import TensorTerrain3D
from acl3d.envs.terrain3d_env import Terrain3DEnv


class Draws:
    """An RNG whose draws are given, in the CPU generator's order (twist sign, lattice, then
    per row of blocks its height's normal and its centre's uniform)."""

    def __init__(self, draws: dict, row: int):
        self._sign = float(draws["sign"][row])
        self._lattice = draws["lattice"][row].numpy()
        self._normals = iter(draws["normal"][row].tolist())
        self._uniforms = iter(draws["uniform"][row].tolist())

    def random(self) -> float:
        return self._sign

    def uniform(self, low, high, size=None):
        if size is not None:  # the roughness lattice, drawn as U(-1, 1)
            assert (low, high) == (-1.0, 1.0) and tuple(size) == self._lattice.shape
            return self._lattice
        return low + (high - low) * next(self._uniforms)

    def normal(self, mean: float, std: float) -> float:
        return mean + std * next(self._normals)


@pytest.mark.parametrize(
    "parameters, spacing",
    [
        (None, (0.1, 0.5)),
        (("block_height", "hill_slope", "roughness"), (0.1, 0.2)),
        (None, (0.25, 0.5)),  # a coarser grid (the env's `grid_spacing`)
    ],
)
def test_tensor_fields_equal_the_cpu_generator_given_the_same_draws(parameters, spacing):
    env = Terrain3DEnv(task_parameters=parameters, grid_spacing=spacing)
    assert (env.arena.grid.cell, env.arena.grid.row_cell) == spacing
    space, generator = env.task_space, env.arena.generator
    fields = TensorTerrain3D(generator, tuple(space.names), "cpu")
    rng = np.random.default_rng(0)
    vectors = [space.to_vector({}), space.high.astype(np.float64)]
    vectors += [rng.uniform(space.low, space.high) for _ in range(14)]
    if parameters is None:  # blocks back to back (no spacing), and a full-width wall
        wall = dict(zip(space.names, vectors[2]), block_spacing=1.0, block_width=1.0)
        vectors += [space.to_vector({**wall, "block_spacing": 1.0}), space.to_vector(wall)]
    vectors = np.stack(vectors)
    draws = fields.draws(len(vectors), torch.Generator().manual_seed(2))
    built = fields.heights(torch.as_tensor(vectors), draws).numpy()
    for row, vector in enumerate(vectors):
        cpu = generator.heights(space.to_dict(vector), Draws(draws, row))
        np.testing.assert_allclose(built[row], cpu, rtol=0, atol=1e-9)
    assert np.ptp(built, axis=(1, 2)).max() > 0.5  # fields with relief


def test_an_unbuildable_task_is_refused_naming_its_parameter():
    from acl3d.envs.world_families import Terrain3DWorlds

    worlds = Terrain3DWorlds(torch.device("cpu"), torch.float32)
    space = worlds.template.task_space
    good = space.to_vector({})
    bad = space.to_vector({}).copy()
    bad[list(space.names).index("hill_slope")] = 50.0
    g = torch.Generator().manual_seed(0)
    field, rows = worlds.terrain(np.arange(2), np.stack([good, good]), g, [])
    assert field.shape[0] == 2 and float(rows.min()) >= 0.0 and float(rows.max()) <= 1.0
    with pytest.raises(ValueError, match="hill_slope"):
        worlds.terrain(np.arange(2), np.stack([good, bad]), g, [])
