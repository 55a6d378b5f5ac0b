"""Each world's heightfield on MuJoCo Warp only as tall as its own ground (`set_terrain`).

MuJoCo Warp skips a geom above a heightfield's top without visiting the prisms under it; a
world's copy topped at the compiled range (3D Terrain's reaches 10 m) made every geom visit
them. These check that the tops are each world's own, the heights and the physics the same.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

pytest.importorskip("mujoco_warp", reason="the [gpu] extra: pip install 'acl3d[gpu]'")

from acl3d.envs.many_worlds import many_worlds  # noqa: E402

TASK = {"roughness": 0.1, "block_height": 0.3}


@pytest.fixture(scope="module")
def fields():
    """Two 3D Terrain simulations of two worlds and the elevations of two draws of `TASK`."""
    envs = [many_worlds("terrain3d", 2, "cpu", body="big_quadru") for _ in range(2)]
    arena = envs[0].template.arena
    draws = [arena.generator.heights(TASK, np.random.default_rng(k)) for k in range(2)]
    elevations = torch.as_tensor(arena.fractions(np.stack(draws)), dtype=torch.float32)
    return envs, elevations


def _compiled_top(env) -> float:
    return float(env.template.model.hfield("terrain").size[2])


def test_each_world_gets_a_top_of_its_own_and_the_same_heights(fields):
    (env, _), elevations = fields
    sim, compiled = env.sim, _compiled_top(env)
    sim.set_terrain("terrain", None, elevations)
    tops, data = sim.terrain_tops("terrain"), sim.terrain("terrain")
    highest = elevations.flatten(1).amax(1)
    torch.testing.assert_close(tops, highest * compiled)
    assert (tops < 0.4 * compiled).all() and tops[0] != tops[1]  # ~0.5 m, not the 10 m range
    assert torch.equal(data.flatten(1).amax(1), torch.ones(2))  # each world's highest point
    torch.testing.assert_close(data * tops[:, None, None], elevations * compiled)
    flat = torch.zeros_like(elevations[:1])  # a world all at the field's floor
    sim.set_terrain("terrain", torch.tensor([1]), flat)
    assert torch.equal(data[1], flat[0]) and 0 < float(tops[1]) < 1e-5 * compiled
    assert float(tops[0]) == pytest.approx(float(highest[0]) * compiled)  # untouched


def test_the_bodies_step_as_on_heightfields_at_the_compiled_top(fields):
    envs, elevations = fields
    fitted, compiled = (env.sim for env in envs)
    fitted.set_terrain("terrain", None, elevations)
    compiled.terrain("terrain").copy_(elevations)  # as before: every copy at the compiled top
    compiled.terrain_tops("terrain").fill_(_compiled_top(envs[1]))
    home = torch.as_tensor(envs[0]._home_qpos, dtype=torch.float32).expand(2, -1)
    g = torch.Generator().manual_seed(3)
    controls = [torch.rand(fitted.field("ctrl").shape, generator=g) * 2 - 1 for _ in range(12)]
    contacts = []
    for sim in (fitted, compiled):
        sim.reset_worlds(torch.arange(2), home, torch.zeros((2, envs[0].template.model.nv)))
        contacts.append(0)
        for ctrl in controls:  # the quadrupeds stand on their feet, which lift and land
            sim.field("ctrl").copy_(ctrl)
            sim.step()
            contacts[-1] += int(sim.d.nacon.numpy()[0])
    # the prisms' heights differ by a rounding of their float32 products (~1e-7 m)
    torch.testing.assert_close(fitted.field("qpos"), compiled.field("qpos"), atol=1e-4, rtol=0)
    assert contacts[0] == contacts[1] > 12  # the feet's contacts with the field were stepped


def test_a_state_saved_before_the_tops_restores_at_the_compiled_top():
    env = many_worlds("terrain3d", 2, "cpu", body="big_quadru")
    env.tasks[:] = env.task_space.to_vector(TASK)
    env.reset(seed=1)
    sim, compiled = env.sim, _compiled_top(env)
    heights = sim.terrain("terrain") * sim.terrain_tops("terrain")[:, None, None]
    state = env.get_state()
    old = {k: v for k, v in state.items() if k != "sim/terrain_tops"}
    old["sim/terrain"] = (heights / compiled).numpy()  # what the simulation kept then
    env.set_state(old)
    assert torch.equal(sim.terrain_tops("terrain"), torch.full((2,), compiled))
    torch.testing.assert_close(sim.terrain("terrain") * compiled, heights)
    env.set_state(state)  # today's states: bit for bit
    assert torch.equal(sim.terrain("terrain"), torch.as_tensor(state["sim/terrain"]))
    assert torch.equal(sim.terrain_tops("terrain"), torch.as_tensor(state["sim/terrain_tops"]))
    with pytest.raises(ValueError, match=r"hfield='ceiling'; valid: \['terrain'\]"):
        sim.set_terrain("ceiling", None, heights)
