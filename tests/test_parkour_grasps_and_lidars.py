"""Parkour: climbers hanging and grasping (per-env weld anchors, movable creepers), and the
lidars that see creepers and water."""

import mujoco
import numpy as np
import pytest

import acl3d  # noqa: F401  (registers the environments)
from acl3d.envs.parkour_lidar import CREEPER_FLAG, WATER_FLAG
from tests.test_parkour import CLIMBER, make


def test_climber_hangs_from_the_ceiling_holds_and_falls_when_released():
    env = make(CLIMBER)
    obs, _ = env.reset(seed=0)
    head = env.bound.root_id
    assert env.climbing.holding.all()
    grasp = obs[6 + env.bound.motor_state_size : 6 + env.bound.motor_state_size + 4]
    assert np.array_equal(grasp, [1, 1, 1, 1])  # touching, holding for each hand
    z0 = env.data.xpos[head, 2]
    assert 17.0 < z0 < 19.5  # ~18 m above the start pad, as the original
    hold = np.zeros(env.body.action_size)
    hold[-2:] = 1.0
    for _ in range(100):
        env.step(hold)
    assert env.data.xpos[head, 2] == pytest.approx(z0, abs=0.3)
    assert env.data.eq_active[env.climbing.eq_ids].all()
    for _ in range(30):
        env.step(-hold)
    assert not env.data.eq_active[env.climbing.eq_ids].any()
    assert env.data.xpos[head, 2] < z0 - 1.0  # free fall: 1.8 m in 0.6 s


def test_weld_anchors_are_per_env():
    a, b = make(CLIMBER), make(CLIMBER)
    a.reset(seed=0)
    b.reset(seed=1)
    before = b.model.eq_data.copy()
    grasp = np.zeros(a.body.action_size)
    grasp[0] = 1.0  # swing a leg while holding, release, grab again where the hands are now
    grasp[-2:] = 1.0
    for _ in range(10):
        a.step(grasp)
    anchors = a.model.eq_data.copy()
    a.step(-grasp)
    a.step(grasp)
    assert a.climbing.holding.all()
    assert not np.array_equal(a.model.eq_data, anchors)
    assert np.array_equal(b.model.eq_data, before)


def test_climber_grabs_a_movable_creeper_and_hangs_from_it():
    env = make(CLIMBER, movable_creepers=True)
    env.reset(seed=0, options={"task": {"creepers_height": 4.0, "creepers_spacing": 0.0}})
    grasp = np.zeros(env.body.action_size)
    grasp[-2:] = 1.0
    env.step(-grasp)  # let go of the ceiling
    hand = env.data.geom_xpos[env.climbing.geom_ids[0]]
    segments = env.arena.creeper_geoms[: env.arena.nb_creeper_geoms]
    centres = env.data.geom_xpos[segments]
    below = centres[centres[:, 2] < hand[2] - 1.0]
    target = below[np.argmin(np.abs(below[:, 0] - hand[0]))]  # a lower segment nearby
    env.data.qpos[env.bound.root_qpos : env.bound.root_qpos + 2] += (target - hand)[[0, 2]]
    env.data.qvel[:] = 0.0
    mujoco.mj_forward(env.model, env.data)
    env.step(grasp)
    held = env.model.eq_obj2id[env.climbing.eq_ids[0]]
    assert env.climbing.holding[0] and env.model.body(held).name.startswith("creeper")
    z0 = env.data.xpos[env.bound.root_id, 2]
    for _ in range(50):
        env.step(grasp)
    assert env.data.xpos[env.bound.root_id, 2] > z0 - 1.0  # held up by the chain, not falling


def test_creepers_never_collide_but_lidars_see_them():
    env = make(CLIMBER)
    task = {"creepers_height": 10.0, "creepers_spacing": 0.0}
    env.reset(seed=0, options={"task": task})
    creepers = set(env.arena.creeper_geoms.tolist())
    rng = np.random.default_rng(0)
    seen = False
    for _ in range(100):
        obs, *_ = env.step(rng.uniform(-1, 1, env.body.action_size))
        pairs = env.data.contact.geom[: env.data.ncon].ravel().tolist()
        assert not creepers.intersection(pairs)
        seen |= bool((obs[-10:] == CREEPER_FLAG).any())
    assert seen


def test_lidar_sees_water_from_above_only_and_flags_reset_on_misses():
    env = make("fish", planar=True)
    space = env.task_space
    task = space.to_dict(space.to_vector({}))
    terrain = env.generator.generate({**task, "water_level": 0.0}, np.random.default_rng(0))
    bottom = terrain.water_z - 0.01 * (terrain.ceiling.max() - terrain.water_z) / 0.99
    level = (0.5 - bottom) / (terrain.ceiling.max() - bottom)  # surface 0.5 m above the pad
    obs, _ = env.reset(seed=0, options={"task": {"water_level": level}})
    assert env.water.level == pytest.approx(0.5)
    lidar, flags = obs[-20:-10], obs[-10:]
    head_z = env.data.xpos[env.bound.root_id, 2]
    assert flags[0] == WATER_FLAG
    assert lidar[0] == pytest.approx((head_z - 0.5) / (160 / 30), abs=1e-4)
    assert np.all(flags[lidar == 1.0] == 0.0)  # misses carry no stale flag
    env.reset(seed=0, options={"task": {"water_level": 1.0}})  # under water: no surface seen
    obs, *_ = env.step(np.zeros(4))
    assert not (obs[-10:] == WATER_FLAG).any()


def mujoco_lidar(env, lidar, origin):
    """The same rays cast by MuJoCo on the compiled geoms of group 0 (terrain and creepers)."""
    ids, dist = np.zeros(lidar.nb_rays, np.int32), np.zeros(lidar.nb_rays)
    groups = np.array([1, 0, 0, 0, 0, 0], np.uint8)
    vec = lidar.directions.ravel()
    n, r = lidar.nb_rays, lidar.range
    mujoco.mj_multiRay(env.model, env.data, origin, vec, groups, 1, -1, ids, dist, None, n, r)
    return np.where((ids >= 0) & (dist <= r), dist / r, 1.0)


@pytest.mark.parametrize("movable", [False, True])
def test_analytic_lidar_matches_mujoco_ray_casting(movable):
    env = make(CLIMBER, movable_creepers=movable, lidars_type="full")
    task = {"creepers_height": 3.0, "creepers_spacing": 0.5, "input_vector": [-0.3, 1.0, 0.3]}
    env.reset(seed=0, options={"task": task})
    lidar, rng = env.rules.lidar, np.random.default_rng(0)
    checked = 0
    for x in np.linspace(2.0, 60.0, 40):
        z = rng.uniform(env.terrain.ground_at(x) + 0.3, env.terrain.ceiling_at(x) - 0.3)
        c = env.terrain.creepers  # mj_ray also reports the box a ray starts in; the original not
        if np.any((c[:, 0] - 0.05 <= x) & (x <= c[:, 1] + 0.05) & (c[:, 3] - 0.05 <= z)):
            continue
        origin = np.array([x, 0.0, z])
        analytic = lidar.read(env.model, env.data, origin)
        reference = mujoco_lidar(env, lidar, origin)
        assert analytic == pytest.approx(reference, abs=1e-4)
        checked += int((analytic < 1).sum())
    assert checked > 50
