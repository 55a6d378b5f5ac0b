"""Parkour: CPPN terrain, task space and errors, water physics, survival, API, test sets
(grasping and lidars: tests/test_parkour_grasps_and_lidars.py)."""

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import acl3d  # noqa: F401  (registers the environments)
from acl3d.envs.parkour_rules import SURVIVAL_STEPS
from acl3d.envs.profiles import PARKOUR
from acl3d.envs.water import Water
from acl3d.teachers import test_sets
from acl3d.terrain import parkour_test_sets
from acl3d.terrain.parkour import (
    CPPN_LAYERS,
    ParkourGenerator,
    cppn,
    cppn_weights,
    parkour_task_space,
)
from acl3d.terrain.tracks import TERRAIN_STEP

CLIMBER = "climbing_profile_chimpanzee"


def make(body="classic_bipedal", **kw):
    return gym.make("acl3d/Parkour-v0", body=body, **kw).unwrapped


def run(env, actions):
    out = []
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        out.append((obs, reward, terminated))
        if terminated:
            break
    return out


# ---------------------------------------------------------------------------- terrain (numpy)
def test_cppn_has_the_original_architecture_and_frozen_seeded_weights():
    weights = cppn_weights()
    assert [w.shape for w in weights] == list(CPPN_LAYERS)
    assert all(np.abs(w).max() <= 4.0 for w in weights)  # truncated at 2 std (std 2)
    assert 1.6 < np.std(np.concatenate([w.ravel() for w in weights])) < 2.0
    assert all(np.array_equal(a, b) for a, b in zip(weights, cppn_weights.__wrapped__(26)))
    assert not np.array_equal(cppn_weights(26)[0], cppn_weights(27)[0])
    out = cppn([-0.15, 0.8, 0.1])
    assert out.shape == (200, 2) and np.array_equal(out, cppn([-0.15, 0.8, 0.1]))
    assert not np.allclose(out, cppn([-0.15, 0.8, 0.2]))


def test_height_lines_follow_the_original_offsets_and_scale():
    gen = ParkourGenerator(start_pad=20)
    ground, ceiling = gen.height_lines([-0.15, 0.8, 0.1], 10.0)
    assert len(ground) == 220 and np.all(ground[:21] == 0.0)  # pad, then the first CPPN point
    assert np.all(ceiling[:21] == pytest.approx(20.0))  # 200 / scale above the start pad
    assert np.all(ceiling >= ground)
    g20, c20 = gen.height_lines([-0.15, 0.8, 0.1], 20.0)
    assert np.allclose(g20, ground / 2) and c20[0] == pytest.approx(10.0)
    assert gen.end_x == pytest.approx(215 * TERRAIN_STEP)


def test_water_level_maps_between_the_bottom_and_the_highest_ceiling():
    gen, rng = ParkourGenerator(), np.random.default_rng(0)
    task = parkour_task_space().to_dict(parkour_task_space().to_vector({}))
    low = gen.generate({**task, "water_level": 0.0}, rng)
    high = gen.generate({**task, "water_level": 1.0}, rng)
    assert low.water_z == pytest.approx(-100 - 10 / 3 + 0.01 * (high.water_z + 100 + 10 / 3))
    assert high.water_z == pytest.approx(high.ceiling.max())


def test_creepers_spacing_height_and_width_as_the_original():
    gen = ParkourGenerator()
    space = parkour_task_space()
    task = space.to_dict(space.to_vector({"creepers_height": 2.0, "creepers_spacing": 2.0}))
    creepers = gen.generate(task, np.random.default_rng(0)).creepers
    assert creepers[0, 0] == 0.0  # the first one inside the start pad
    assert np.allclose(np.diff(creepers[:, 0]), 2.8)  # (ceil(2 / TS) + 1) TS
    assert np.allclose(creepers[:, 1] - creepers[:, 0], 0.25)
    lengths = creepers[:, 2] - creepers[:, 3]
    assert np.all(lengths >= 0.2 - 1e-9) and abs(lengths.mean() - 2.0) < 0.05
    tiny = gen.generate(
        {**task, "creepers_width": 0.0, "creepers_height": 0.01}, np.random.default_rng(0)
    )
    assert np.allclose(tiny.creepers[:, 1] - tiny.creepers[:, 0], 0.2)
    assert np.all(tiny.creepers[:, 2] - tiny.creepers[:, 3] >= 0.2 - 1e-9)
    assert (
        len(gen.generate({**task, "creepers_height": 0.0}, np.random.default_rng(0)).creepers) == 0
    )


# ---------------------------------------------------------------------------- task space, errors
def test_task_space_is_the_benchmark_8d_space_with_degenerate_dims():
    space = make().task_space
    assert space.flat_names() == [
        "input_vector[0]",
        "input_vector[1]",
        "input_vector[2]",
        "water_level",
        "creepers_width",
        "creepers_height",
        "creepers_spacing",
        "terrain_cppn_scale",
    ]
    assert np.allclose(space.low, [-0.35, 0.6, -0.1, 0, 0.25, 0, 0, 10])
    assert np.allclose(space.high, [0.05, 1.0, 0.3, 1, 0.25, 4, 5, 10])
    easy = make(input_space="easy").task_space
    assert np.allclose(easy.low[:3], [-0.25, 0.8, 0.0])
    assert np.allclose(make(input_space="full").task_space.high[:3], 1.0)


@pytest.mark.parametrize(
    "task, match",
    [
        ({"water_level": 1.5}, r"water_level=1\.5; valid: .*\[0, 1\]"),
        ({"terrain_cppn_scale": 1.0}, r"terrain_cppn_scale=1\.0; valid: .*\[5, 100\]"),
        (
            {"input_vector": [0.0, 3.0, 0.0]},
            r"input_vector=\[0\.0, 3\.0, 0\.0\]; valid: .*\[-1, 1\]",
        ),
        ({"creepers_spacing": -1.0}, r"creepers_spacing=-1\.0"),
        ({"stump_height": 1.0}, "unknown task parameter"),
    ],
)
def test_bad_task_values_raise_naming_parameter_value_and_range(task, match):
    env = make()
    with pytest.raises(ValueError, match=match):
        env.reset(seed=0, options={"task": task})


def test_bad_options_raise():
    with pytest.raises(ValueError, match="input_space='hard'"):
        make(input_space="hard")
    with pytest.raises(ValueError, match="lidars_type='side'"):
        make(lidars_type="side")
    with pytest.raises(ValueError, match="end_on_death='False'; valid: True or False"):
        make(end_on_death="False")
    with pytest.raises(ValueError, match="movable_creepers=1"):
        make(movable_creepers=1)
    with pytest.raises(ValueError, match=r"water_clip=inf; valid: a finite number >= 0"):
        make(water_clip=float("inf"))


# ---------------------------------------------------------------------------- environment API
@pytest.mark.parametrize(
    "body, size, options",
    [
        ("classic_bipedal", 36, {}),
        (CLIMBER, 54, {}),
        (CLIMBER, 54, {"movable_creepers": True}),
        ("fish", 43, {}),
        ("amphibious_bipedal", 36, {}),
    ],
)
def test_check_env_and_observation_sizes(body, size, options):
    env = make(body, **options)
    assert env.observation_space.shape == (size,)
    check_env(env, skip_render_check=True)
    sb3_check_env(env, warn=False)


def test_planar_fish_has_the_original_38_values():
    assert make("fish", planar=True).observation_space.shape == (38,)


def test_same_seed_task_and_actions_give_identical_episodes_in_two_instances():
    task = {"input_vector": [-0.3, 0.9, 0.2], "water_level": 0.8, "creepers_height": 1.0}
    a, b = make(CLIMBER), make(CLIMBER)
    actions = np.random.default_rng(0).uniform(-1, 1, (150, a.body.action_size))
    oa, _ = a.reset(seed=3, options={"task": task})
    ob, _ = b.reset(seed=3, options={"task": task})
    assert np.array_equal(oa, ob)
    assert np.array_equal(a.model.hfield_data, b.model.hfield_data)
    assert np.array_equal(a.terrain.creepers, b.terrain.creepers)
    for (o1, r1, t1), (o2, r2, t2) in zip(run(a, actions), run(b, actions)):
        assert np.array_equal(o1, o2) and r1 == r2 and t1 == t2


def test_new_task_rewrites_terrain_in_place_and_the_ceiling_collides_from_below():
    env = make()
    model = env.model
    env.reset(seed=0, options={"task": {"input_vector": [-0.3, 0.7, 0.0]}})
    first = model.hfield_data.copy()
    env.reset(seed=0, options={"task": {"input_vector": [0.0, 1.0, 0.3]}})
    assert env.model is model and not np.array_equal(model.hfield_data, first)
    hit = np.zeros(1, np.int32)
    x = 30.0
    origin = np.array([x, 0.0, env.terrain.ground_at(x) + 0.5])
    up = mujoco.mj_ray(model, env.data, origin, np.array([0, 0, 1.0]), None, 1, -1, hit)
    assert hit[0] == env.arena.ceiling_geom
    assert up == pytest.approx(env.terrain.ceiling_at(x) - origin[2], abs=1e-3)
    down = mujoco.mj_ray(model, env.data, origin, np.array([0, 0, -1.0]), None, 1, -1, hit)
    assert hit[0] == model.geom("terrain").id and down == pytest.approx(0.5, abs=1e-3)


def test_a_body_thrown_up_hits_the_ceiling_and_stays_below_it():
    env = make()
    env.reset(seed=0, options={"task": {"terrain_cppn_scale": 40.0}})  # ceiling 5 m up
    assert env.terrain.ceiling[0] == pytest.approx(5.0)
    env.data.qvel[env.bound.root_dof + 1] = 15.0
    hit, top = False, 0.0
    for _ in range(60):
        env.step(np.zeros(4))
        hit |= bool((env.data.contact.geom[: env.data.ncon] == env.arena.ceiling_geom).any())
        top = max(top, env.data.xpos[env.bound.root_id, 2] + 0.3)  # hull top
    assert hit and top < 5.0 + 0.15


def test_walker_hull_contact_is_not_terminal():
    env = make()
    env.reset(seed=0)
    hull = env.model.geom("walker/hull").id
    for _ in range(300):  # knees bent backwards: the biped collapses onto its hull
        _, reward, terminated, _, _ = env.step(np.array([1.0, 1.0, 1.0, 1.0]))
        assert not terminated
    assert reward != -100.0
    assert hull in env.bound.critical_geom_ids  # critical on the tracks, not in Parkour


# ---------------------------------------------------------------------------- water physics
def _box_in_water(mass: float, velocity=(0.0, 0.0), level: float = 10.0):
    """A planar 1 m^2 (x-z silhouette) box at z = 5 and the Water acting on it."""
    xml = f"""<mujoco><option timestep="0.01" gravity="0 0 -10"/><worldbody>
      <body name="box" pos="0 0 5">
        <joint name="x" type="slide" axis="1 0 0"/><joint name="z" type="slide" axis="0 0 1"/>
        <joint name="pitch" type="hinge" axis="0 -1 0"/>
        <geom type="box" size="0.5 0.2 0.5" mass="{mass}" contype="0" conaffinity="1"/>
      </body></worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    data.qvel[:2] = velocity
    water = Water(model, [0])
    water.level = level
    return model, data, water


def _simulate(model, data, water, steps=100):
    for _ in range(steps):
        water.apply(data)
        mujoco.mj_step(model, data)
    return data.qpos.copy(), data.qvel.copy()


def test_buoyancy_floats_lighter_bodies_and_sinks_denser_ones():
    assert Water(_box_in_water(1.0)[0], [0]).area[0] == pytest.approx(1.0)
    light, _ = _simulate(*_box_in_water(0.5))
    heavy, _ = _simulate(*_box_in_water(2.0))
    neutral, _ = _simulate(*_box_in_water(1.0))
    assert light[1] > 0.5 and heavy[1] < -0.5 and abs(neutral[1]) < 1e-6
    dry, _ = _simulate(*_box_in_water(0.5, level=-10.0))
    assert dry[1] == pytest.approx(-0.5 * 10 * 1.0**2, rel=0.02)  # free fall, no water force


def test_drag_slows_a_moving_body_only_under_water():
    _, wet = _simulate(*_box_in_water(1.0, velocity=(3.0, 0.0)), steps=50)
    model, data, water = _box_in_water(1.0, velocity=(3.0, 0.0), level=-10.0)
    model.opt.gravity[:] = 0.0
    _, dry = _simulate(model, data, water, steps=50)
    assert dry[0] == pytest.approx(3.0)
    assert 0.0 < wet[0] < 0.8 * dry[0]  # 0.25 * width * v^2 of drag on 1 kg


def test_fish_swims_with_its_tail_and_drifts_little_at_rest():
    env = make("fish", planar=True)
    task = {"water_level": 1.0}

    def travel(gait):
        env.reset(seed=0, options={"task": task})
        x0 = env.data.xpos[env.bound.root_id, 0]
        for i in range(300):
            env.step(gait(i))
        return env.data.xpos[env.bound.root_id, 0] - x0

    wave = travel(lambda i: np.sign(np.sin([0.3 * i, 0.3 * i - 1, 0.3 * i - 2, 0.0])))
    rest = travel(lambda i: np.zeros(4))
    assert abs(wave) > 2.0 and abs(rest) < 1.0  # the tail's thrust moves it along the track


# ---------------------------------------------------------------------------- survival
@pytest.mark.parametrize(
    "body, level, dies",
    [("classic_bipedal", 1.0, True), ("fish", 0.0, True), ("amphibious_bipedal", 1.0, False)],
)
def test_drowning_and_suffocation_after_600_steps(body, level, dies):
    env = make(body)
    obs, _ = env.reset(seed=0, options={"task": {"water_level": level}})
    flags = env.body.planar and 4 or 9
    zeros = np.zeros(env.body.action_size)
    for _ in range(SURVIVAL_STEPS):
        obs, *_ = env.step(zeros)
    assert obs[flags + 1] == 0.0 and not env.get_state()["survival/dead"]
    for _ in range(2):
        obs, reward, terminated, *_ = env.step(np.ones(env.body.action_size))
    assert env.get_state()["survival/dead"] == dies
    assert obs[flags + 1] == float(dies) and not terminated
    if dies:  # dead bodies play zero actions, which cost nothing
        assert env.data.ctrl[env.bound.actuator_ids] == pytest.approx(0.0)


def test_end_on_death_ends_the_episode():
    env = make(end_on_death=True)
    env.reset(seed=0, options={"task": {"water_level": 1.0}})
    steps = run(env, np.zeros((SURVIVAL_STEPS + 5, 4)))
    assert len(steps) == SURVIVAL_STEPS + 1 and steps[-1][2]


# ---------------------------------------------------------------------------- test sets
@pytest.mark.parametrize("name", ["walking", "climbing", "swimming"])
def test_test_sets_are_seeded_and_inside_the_training_space(name, tmp_path):
    space = parkour_task_space()
    tasks = parkour_test_sets.build(name)
    assert tasks.shape == (100, 8) and all(space.contains(t) for t in tasks)
    named = test_sets.resolve(f"{name}_test_set_v1", space, profile=PARKOUR)
    assert np.array_equal(tasks, named)
    path = tmp_path / f"{name}.csv"
    test_sets.save(path, tasks, space)
    assert np.allclose(test_sets.resolve(str(path), space, profile=PARKOUR), tasks)
    water = tasks[:, space.slice("water_level")]
    if name == "swimming":
        assert np.all(water == 1.0)
    if name == "walking":
        assert np.sum(water > 0) == 2
    with pytest.raises(ValueError, match="unknown Parkour test set"):
        parkour_test_sets.build("running")
