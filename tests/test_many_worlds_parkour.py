"""Parkour on the many-world simulation (MuJoCo Warp on Warp's CPU device, no GPU needed).

As tests/test_many_worlds.py: the torch rules (water forces, survival, grasps, typed lidar) equal
the numpy rules on the same physics, Warp follows CPU MuJoCo over the first steps of a walker in
water, and a reset of some worlds leaves the others untouched. Two small worlds per check; the
kernels compile once per model (cached in ~/.cache/warp).
"""

from __future__ import annotations

import copy

import mujoco
import numpy as np
import pytest
import torch

pytest.importorskip("mujoco_warp", reason="the [gpu] extra: pip install 'acl3d[gpu]'")

from test_many_worlds import assert_world_1_steps_as  # noqa: E402

from acl3d.envs.climbing import Climbing, after_steps  # noqa: E402
from acl3d.envs.many_worlds import many_worlds  # noqa: E402
from acl3d.envs.parkour_env import ParkourEnv  # noqa: E402
from acl3d.envs.parkour_lidar import creeper_boxes  # noqa: E402

pytestmark = pytest.mark.xdist_group("warp")
WET = {
    "water_level": 0.95,
    "creepers_height": 4.0,
    "creepers_spacing": 0.5,
    "terrain_cppn_scale": 60.0,
}
# (a scale of 60: a low ceiling and creepers within the lidar's reach; a submerged start)
CLIMB = {"water_level": 0.0, "creepers_height": 0.0}


class WorldsAsNumpy:
    """The numpy rules' physics interface over the Warp worlds (float64 copies); static creepers
    stand where each world's record puts them (their bodies never move on the Warp side)."""

    def __init__(self, worlds):
        sim, rec = worlds.sim, worlds.rules.record
        names = ("qpos", "qvel", "xpos", "cvel", "sensordata", "geom_xpos", "subtree_com")
        names += ("xipos", "xaxis", "xanchor", "qfrc_actuator")
        self._fields = {name: sim.field(name).double().numpy().copy() for name in names}
        n = worlds.num_envs
        for name in ("xmat", "geom_xmat"):
            self._fields[name] = sim.field(name).double().numpy().reshape(n, -1, 9).copy()
        cx, cz, hx, _, used = (t.double().numpy() for t in rec.creepers(worlds.heights))
        pool = worlds.template.arena.creeper_geoms
        for i in range(n):
            k = int(used[i].sum())
            self._fields["geom_xpos"][i, pool[:k]] = np.column_stack(
                (cx[i, :k], np.zeros(k), cz[i, :k])
            )
            self._fields["geom_xmat"][i, pool[:k]] = np.eye(3).ravel()
        self.controls = sim.field("ctrl").double().numpy()

    def field(self, name):
        return self._fields[name]

    def data(self, model, i) -> mujoco.MjData:
        """World i's fields in an MjData (what `Water.apply` reads)."""
        data = mujoco.MjData(model)
        for name, value in self._fields.items():
            if name != "sensordata":
                getattr(data, name)[:] = value[i].reshape(getattr(data, name).shape)
        return data


def numpy_rows(worlds, physics):
    """The numpy rules' rows of the Warp worlds: terrain and survival from their records."""
    rules, rec, n = worlds.template.rules, worlds.rules.record, worlds.num_envs
    record = worlds.heights.double().numpy()
    rows = rules.new_rows(n)
    rows.ground[:], rows.ceiling[:] = rec(record, "ground"), rec(record, "ceiling")
    rows.water_level[:] = record[:, rec.slices["water"]][:, 0]
    _, _, hx, hz, used = rec.creepers(torch.as_tensor(record))
    rows.creeper_count[:] = used.sum(dim=1).numpy()
    half = (
        np.stack((hx.numpy(), np.full(hx.shape, 0.5), hz.numpy()), axis=-1)
        * used.numpy()[..., None]
    )
    rows.creeper_size[:], rows.creeper_rbound[:] = half, np.linalg.norm(half, axis=-1)
    rows.dead[:] = rec(record, "survival")[:, 2] > 0
    rows.under_water[:] = physics.field("xpos")[:, rules.bound.root_id, 2] <= rows.water_level
    return rows


def _actions(env, seed, grasp=None):
    g = torch.Generator().manual_seed(seed)
    a = torch.rand((env.num_envs, env.action_size), generator=g) * 2 - 1
    if grasp is not None:
        a[:, -len(grasp[0]) :] = torch.tensor(grasp, dtype=a.dtype)
    return a


@pytest.fixture(scope="module")
def walkers():
    env = many_worlds("parkour", 2, "cpu", body="classic_bipedal", lidars_type="full")
    env.tasks[:] = env.task_space.to_vector(WET)
    env.reset(seed=1)
    return env


def test_walkers_in_water_torch_rules_equal_numpy_rules(walkers):
    for k in range(3):
        walkers.step(_actions(walkers, k))
    rules, physics = walkers.template.rules, WorldsAsNumpy(walkers)
    rows = numpy_rows(walkers, physics)
    x_np, obs_np = rules.observe_rows(physics, rows)
    x_t, obs_t = walkers.rules.observe(walkers.sim, walkers.heights)
    assert obs_np[:, 4].all()  # under water
    assert (obs_np[:, -10:] == 1.0).any() and (obs_np[:, -10:] == 0.0).any()  # creepers, ceiling
    np.testing.assert_allclose(x_t.numpy(), x_np, atol=1e-6)
    np.testing.assert_allclose(obs_t.numpy(), obs_np, rtol=1e-5, atol=1e-5)
    # the water forces the next step applies: Water.apply on each world's fields
    water, rec = walkers.template.arena.water, walkers.rules.record
    forces = rec(walkers.heights, "forces").unflatten(1, (-1, 3)).double().numpy()
    for i in range(walkers.num_envs):
        data = physics.data(walkers.template.model, i)
        water.level = float(rows.water_level[i])
        assert water.apply(data) > 0.0
        expected = data.xfrc_applied[water.body_ids][:, [0, 2, 4]]
        np.testing.assert_allclose(forces[i], expected, rtol=1e-4, atol=1e-3)


def test_warp_follows_cpu_mujoco_in_water_over_the_first_steps(walkers):
    cpu = ParkourEnv(body="classic_bipedal", lidars_type="full")
    cpu.reset(seed=5, options={"task": WET})
    arena, rec, sim = cpu.arena, walkers.rules.record, walkers.sim
    row = rec.terrain_row(
        arena.heights, arena.ceiling_heights, arena.water.level, arena.terrain.creepers
    )
    walkers.heights[1] = torch.as_tensor(row)
    sim.terrain("terrain")[1] = torch.as_tensor(arena._hfield.reshape(2, -1))
    sim.reset_worlds(
        torch.tensor([1]),
        torch.as_tensor(cpu.data.qpos, dtype=torch.float32)[None],
        torch.as_tensor(cpu.data.qvel, dtype=torch.float32)[None],
    )
    wet, data = arena.water.wet, copy.copy(cpu.data)  # the forces of the CPU env's next step
    arena.water.apply(data)
    arena.water.wet = wet
    forces = data.xfrc_applied[arena.water.body_ids][:, [0, 2, 4]]
    rec(walkers.heights, "forces")[1] = torch.as_tensor(forces.ravel())
    walkers.prev_shaping[1] = float(cpu.rows.prev_shaping[0])
    walkers.elapsed[1] = 0
    # float32 against float64: the first step (the CPU env's forces) agrees to 1e-7; the water
    # forces Warp's worlds compute then part from the CPU's by ~0.01 N of ~20 N (what rounding
    # the state to float32 alone gives), so qpos parts by ~1e-4 a step (3e-4 after 5 steps)
    actions = [_actions(walkers, 100 + k) for k in range(5)]
    assert_world_1_steps_as(cpu, walkers, actions, qpos_atol=5e-4, obs_atol=2e-3)


def test_a_reset_touches_only_its_worlds(walkers):
    walkers.step(_actions(walkers, 9))
    sim = walkers.sim
    state = {name: sim.field(name)[1].clone() for name in ("qpos", "qvel", "xfrc_applied")}
    hfields = {name: sim.terrain(name)[1].clone() for name in ("terrain", "ceiling")}
    record, obs_before = walkers.heights[1].clone(), walkers.obs[1].clone()
    task = walkers.task_space.to_vector({"water_level": 0.1, "terrain_cppn_scale": 20.0})
    obs = walkers._reset_worlds(np.array([0]), task[None], walkers.obs)
    for name, value in state.items():
        assert torch.equal(sim.field(name)[1], value), name
    for name, value in hfields.items():
        assert torch.equal(sim.terrain(name)[1], value), name
    assert torch.equal(walkers.heights[1], record) and torch.equal(obs[1], obs_before)
    assert not torch.equal(walkers.heights[0], record)  # world 0: its new terrain and water
    assert float(sim.field("xfrc_applied")[0].abs().sum()) == 0.0  # cleared
    assert walkers.elapsed[0] == 0 and walkers.elapsed[1] > 0


def test_climbers_grasp_per_world_as_the_numpy_climbing_does():
    climbers = many_worlds("parkour", 2, "cpu", body="climbing_profile_chimpanzee")
    climbers.tasks[:] = climbers.task_space.to_vector(CLIMB)
    climbers.reset(seed=3)
    grasp = [[1.0, 1.0], [-1.0, -1.0]]  # world 0 holds on, world 1 lets go
    for k in range(4):
        climbers.step(_actions(climbers, 70 + k, grasp))
    rec, template = climbers.rules.record, climbers.template
    holding = rec(climbers.heights, "holding") > 0
    assert holding[0].any() and not holding[1].any()
    assert climbers.sim.field("eq_active").tolist() == holding.tolist()
    # the numpy touch test on the same poses, ceiling lines and creepers
    physics = WorldsAsNumpy(climbers)
    rows, arena = numpy_rows(climbers, physics), template.arena
    xpos, xmat = physics.field("geom_xpos"), physics.field("geom_xmat")
    boxes = creeper_boxes(
        xpos, xmat, arena.creeper_geoms, rows.creeper_size, rows.creeper_rbound,
        rows.creeper_count,
    )  # fmt: skip
    climbings = [
        Climbing(template.model, template.body.grasp_sensors, arena.creeper_geoms)
        for _ in range(climbers.num_envs)
    ]
    after_steps(climbings, None, xpos, xmat, rows.ceiling, arena.grid, boxes)
    touching = rec(climbers.heights, "touching").numpy() > 0
    assert touching.tolist() == [c.touching.tolist() for c in climbings]
    # a held hand stays where it grabbed; world 1's climber falls
    anchors = rec(climbers.heights, "anchors").unflatten(1, (-1, 3))[0][holding[0]]
    hands = climbers.rules.hand_geoms
    top = climbers.sim.field("geom_xpos")[1, hands, 2].clone()
    for k in range(5):
        climbers.step(_actions(climbers, 80 + k, grasp))
    held = climbers.sim.field("geom_xpos")[0, hands][holding[0]]
    assert float((held - anchors).norm(dim=1).max()) < 0.02
    assert (climbers.sim.field("geom_xpos")[1, hands, 2] < top - 0.05).all()


def test_a_restored_climber_continues_as_the_original():
    climbers = many_worlds("parkour", 2, "cpu", body="climbing_profile_chimpanzee")
    climbers.tasks[:] = climbers.task_space.to_vector(CLIMB)
    climbers.reset(seed=3)
    grasp = [[1.0, 1.0], [1.0, 1.0]]
    for k in range(6):  # hands on the ceiling: weld constraints active
        climbers.step(_actions(climbers, 70 + k, grasp))
    saved = climbers.get_state()
    runs = []
    for _ in range(2):
        climbers.set_state(saved)
        runs.append([climbers.step(_actions(climbers, 80 + k, grasp))[0].clone() for k in range(4)])
    assert bool((climbers.sim.field("eq_active")).any())
    assert all(torch.equal(a, b) for a, b in zip(*runs))
