"""Every embodiment on the tracks: sizes as in TeachMyAgent, masses from the 2D shapes, stability,
critical contacts, determinism, options, climbers' grasp interface and a moving open-loop gait."""

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from acl3d.bodies import ALIASES, BODIES, body_class, make_body
from acl3d.envs.track_rules import FAIL_REWARD, TrackRules

# (actions, planar observation size): TeachMyAgent's Stump Tracks sizes for its bodies
SIZES = {
    "classic_bipedal": (4, 24),
    "small_bipedal": (4, 24),
    "amphibious_bipedal": (4, 24),
    "big_quadru": (8, 34),
    "spider": (12, 42),
    "millipede": (16, 54),
    "wheel": (8, 34),
    "profile_chimpanzee": (14, 50),
    "climbing_profile_chimpanzee": (12, 42),
    "climbing_chest_profile_chimpanzee": (8, 32),
    "fish": (4, 26),
    "dmc:ant": (8, 4 + 16 + 4 + 10),
    "dmc:cmu_humanoid": (56, 4 + 112 + 10),
}
FREE_EXTRA_OBS = 5  # roll, yaw, lateral velocity, roll and yaw rates
NO_CRITICAL_PARTS = {"fish", "millipede", "amphibious_bipedal"}
FLAT = {"stump_height": 0.0, "obstacle_spacing": 6.0}

PX2 = 1 / 900  # m^2 per px^2
LEG = (8 * 34 + 6.4 * 34) * PX2  # classic upper + lower leg areas
CHIMP_CORE = (200 + 900) * PX2 * 5 + 2 * (8 * 28 + 6.4 * 28) * PX2  # head, trunk, two legs
SENSOR = np.pi * 0.05**2  # grasp sensor disc, density 1
# total masses from the original 2D areas x densities (hull/trunk 5, limbs 1, fish 0.99)
MASSES = {
    "classic_bipedal": 976 * PX2 * 5 + 2 * LEG,
    "small_bipedal": 976 * PX2 * 5 + LEG,
    "amphibious_bipedal": 976 * PX2 * 1.25 + 2 * LEG * 0.25,
    "big_quadru": 2224 * PX2 * 5 + 4 * (10 * 51 + 8 * 51) * PX2,
    "spider": 400 * PX2 * 5 + 4 * (2 * 6 * 20 + 4.8 * 20) * PX2,
    "millipede": 4 * (400 * PX2 * 5 + 2 * (4 * 10 + 3.2 * 10) * PX2),
    "wheel": 400 * PX2 * 5 + 4 * (4 * 10 + 3.2 * 10) * PX2,
    "profile_chimpanzee": CHIMP_CORE + 2 * (8 * 28 + 6.4 * 28 + 3 * 4 * 8) * PX2,
    "climbing_profile_chimpanzee": CHIMP_CORE + 2 * ((8 * 28 + 6.4 * 28 + 4 * 8) * PX2 + SENSOR),
    "climbing_chest_profile_chimpanzee": (200 + 900) * PX2 * 5
    + 2 * ((8 * 28 + 6.4 * 28 + 4 * 8) * PX2 + SENSOR),
    "fish": (768 + 336 + 208 + 48 + 40) * PX2 * 0.99,
}
MODES = [pytest.param(True, id="planar"), pytest.param(False, id="3d")]


def make(body, planar, **kw):
    return gym.make("acl3d/StumpTracks-v0", body=body, planar=planar, **kw).unwrapped


def random_rollout(env, steps, seed=0):
    """Random actions with resets on termination; returns MuJoCo's warning counts summed."""
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    warnings = np.zeros_like(env.data.warning.number)
    for _ in range(steps):
        obs, reward, terminated, _, _ = env.step(rng.uniform(-1, 1, env.action_space.shape))
        assert np.all(np.isfinite(obs)) and np.isfinite(reward)
        if terminated:
            warnings += env.data.warning.number  # reset clears MuJoCo's counters
            env.reset()
    return warnings + env.data.warning.number


def test_registry_lists_every_teachmyagent_body():
    assert set(SIZES) == set(BODIES)
    assert body_class("old_big_quadru") is body_class("big_quadru")
    assert all(target in BODIES for target in ALIASES.values())
    kinds = {name: body_class(name).kind for name in BODIES}
    assert kinds["fish"] == "swimmer" and kinds["amphibious_bipedal"] == "amphibian"
    assert kinds["climbing_profile_chimpanzee"] == kinds["climbing_chest_profile_chimpanzee"]
    assert kinds["climbing_profile_chimpanzee"] == "climber"
    assert {k for k in kinds.values()} == {"walker", "climber", "swimmer", "amphibian"}


@pytest.mark.filterwarnings("ignore:.*Box observation space (minimum|maximum)")  # unbounded obs
@pytest.mark.parametrize("planar", MODES)
@pytest.mark.parametrize("name", BODIES)
def test_builds_passes_check_env_and_has_the_original_sizes(name, planar):
    env = make(name, planar)
    actions, obs = SIZES[name]
    assert env.action_space.shape == (actions,)
    assert env.observation_space.shape == (obs + (0 if planar else FREE_EXTRA_OBS),)
    check_env(env, skip_render_check=True)


@pytest.mark.parametrize("name", BODIES)
def test_body_never_collides_with_itself_and_is_invisible_to_lidars(name):
    env = make(name, None)
    m = env.model
    geoms = env.bound.body_geom_ids
    assert np.all(m.geom_contype[geoms] == 0)  # only the terrain (contype 1) can touch a body
    assert np.all(m.geom_group[geoms] != 0)  # lidars see group 0 only


@pytest.mark.parametrize("name", sorted(MASSES))
def test_masses_come_from_the_2d_areas(name):
    env = make(name, True)
    assert env.bound.total_mass == pytest.approx(MASSES[name], rel=2e-3)


@pytest.mark.parametrize("planar", MODES)
@pytest.mark.parametrize("name", BODIES)
def test_random_actions_stay_finite_without_warnings(name, planar):
    steps = 100 if name == "dmc:cmu_humanoid" else 300
    assert not random_rollout(make(name, planar), steps).any()


@pytest.mark.slow
@pytest.mark.parametrize("planar", MODES)
@pytest.mark.parametrize("name", BODIES)
def test_2000_random_steps_stay_finite_without_warnings(name, planar):
    assert not random_rollout(make(name, planar), 2000, seed=1).any()


def flip(env, angle=np.pi):
    """Pitch the body over where it spawned, so that its hull/head/trunk falls onto the ground."""
    q, data = env.bound.root_qpos, env.data
    if env.body.planar:
        data.qpos[q + 2] = angle
    else:
        data.qpos[q + 3 : q + 7] = (np.cos(angle / 2), 0.0, -np.sin(angle / 2), 0.0)
    data.qvel[:] = 0.0


@pytest.mark.parametrize("planar", MODES)
@pytest.mark.parametrize("name", BODIES)
def test_landing_upside_down_ends_the_episode_iff_the_body_has_critical_parts(name, planar):
    env = make(name, planar)
    env.reset(seed=0, options={"task": FLAT})
    flip(env, 0.75 * np.pi if name == "wheel" else np.pi)  # upside down, limp legs hold the cube
    for _ in range(150):
        _, reward, terminated, _, _ = env.step(np.zeros(env.action_space.shape))
        if terminated:
            break
    if name in NO_CRITICAL_PARTS:
        assert not terminated and not env.rows.critical_contact[0]
    else:
        assert terminated and env.rows.critical_contact[0] and reward == FAIL_REWARD


@pytest.mark.parametrize("planar", MODES)
@pytest.mark.parametrize("name", BODIES)
def test_same_seed_and_actions_give_identical_observations(name, planar):
    actions = np.random.default_rng(3).uniform(-1, 1, (60, SIZES[name][0]))
    runs = []
    for _ in range(2):
        env = make(name, planar)
        obs = [env.reset(seed=5, options={"task": {"stump_height": 1.0}})[0]]
        obs += [env.step(a)[0] for a in actions]
        runs.append(np.array(obs))
    assert np.array_equal(runs[0], runs[1])


@pytest.mark.parametrize("planar", MODES)
@pytest.mark.parametrize("name", BODIES)
def test_settles_at_rest_and_moves_under_a_periodic_gait(name, planar):
    env = make(name, planar)
    env.reset(seed=0, options={"task": FLAT})
    for _ in range(150):
        env.step(np.zeros(env.action_space.shape))
    assert np.abs(env.data.qvel).max() < 10.0  # limp but not exploding
    assert not env.data.warning.number.any()
    env.reset(seed=0, options={"task": FLAT})
    x0 = env.data.xpos[env.bound.root_id, 0]
    n = env.action_space.shape[0]
    phases = np.pi / 2 * np.arange(n)
    moved = 0.0
    for t in range(150):  # 1 Hz sine per action entry, a quarter period apart
        env.step(np.sin(2 * np.pi * t / 50 + phases))  # physics goes on after a fall
        moved = max(moved, abs(env.data.xpos[env.bound.root_id, 0] - x0))
    assert moved > 0.05
    assert not env.data.warning.number.any()


def test_body_options_are_validated_with_clear_errors():
    with pytest.raises(ValueError, match=r"nb_pairs_of_legs=0; valid: an integer in \[1, 8\]"):
        make_body("spider", nb_pairs_of_legs=0)
    with pytest.raises(ValueError, match=r"nb_of_bodies=2.5; valid: an integer in \[1, 12\]"):
        make_body("millipede", nb_of_bodies=2.5)
    with pytest.raises(
        ValueError, match=r"motors_torque=-1; valid: a finite number in \[1, 10000\]"
    ):
        make_body("wheel", motors_torque=-1)
    with pytest.raises(ValueError, match="motors_torque='90'"):
        make_body("wheel", motors_torque="90")
    with pytest.raises(ValueError, match="planar='False'; valid: True or False"):
        make_body("classic_bipedal", planar="False")
    with pytest.raises(ValueError, match="nb_of_bodies=True"):
        make_body("millipede", nb_of_bodies=True)
    with pytest.raises(ValueError, match="unknown option"):
        make_body("fish", nb_of_bodies=3)
    with pytest.raises(ValueError, match="unknown option"):
        make_body("dmc:ant", motors_torque=10)  # its joints keep dm_control's own limits


@pytest.mark.parametrize(
    "name, options, actions, obs, divisor",
    [
        ("spider", {"nb_pairs_of_legs": 1}, 6, 4 + 12 + 2 + 10, 1),
        ("spider", {"nb_pairs_of_legs": 3}, 18, 4 + 36 + 6 + 10, 3),
        ("millipede", {"nb_of_bodies": 1}, 4, 4 + 8 + 2 + 10, 1),
        ("millipede", {"nb_of_bodies": 6}, 24, 4 + 48 + 12 + 10, 6),
    ],
)
def test_parametric_bodies_scale_motors_observation_and_penalty(
    name, options, actions, obs, divisor
):
    env = make(name, True, body_options=options)
    assert env.action_space.shape == (actions,) and env.observation_space.shape == (obs,)
    assert env.body.penalty_divisor == divisor
    assert not random_rollout(env, 100).any()


def test_motors_torque_option_caps_the_servos():
    env = make("big_quadru", True, body_options={"motors_torque": 150})
    env.reset(seed=0)
    env.step(np.full(8, 0.5))
    assert np.allclose(env.model.actuator_forcerange[env.bound.actuator_ids], [-75.0, 75.0])


def test_millipede_head_is_the_front_segment_and_segments_are_passively_jointed():
    env = make("millipede", False)
    m = env.model
    xs = [m.body(f"walker/seg{j}_segment").id for j in range(4)]
    env.reset(seed=0)
    assert env.bound.root_id == xs[-1]
    assert np.all(np.diff(env.data.xpos[xs, 0]) > 0)  # rear (seg0) to head
    spines = [m.joint(f"walker/seg{j}_spine") for j in range(3)]
    assert all(m.jnt_range[j.id][1] == pytest.approx(0.05 * np.pi, abs=1e-4) for j in spines)
    assert not set(j.id for j in spines) & set(m.actuator_trnid[:, 0])  # passive


@pytest.mark.parametrize(
    "name", ["climbing_profile_chimpanzee", "climbing_chest_profile_chimpanzee"]
)
def test_climbers_declare_non_colliding_hand_sensors_and_observe_grasp_state(name):
    env = make(name, True)
    m, body = env.model, env.body
    assert env.action_space.shape == (len(body.motors) + 2,)
    for sensor in body.grasp_sensors:
        geom = m.geom("walker/" + sensor.geom)
        assert geom.bodyid[0] == m.body("walker/" + sensor.body).id
        assert geom.contype[0] == 0 and geom.conaffinity[0] == 0
        assert geom.size[0] == pytest.approx(0.05)

    class Grasping(TrackRules):  # what Parkour does: report [contact, grasp] per hand
        def grasp_state(self):
            return np.array([1.0, 0.0, 1.0, 1.0])

    env.rules = Grasping(env.bound, env.rules.lidar)
    obs, _ = env.reset(seed=0)
    start = 4 + env.bound.motor_state_size
    assert np.array_equal(obs[start : start + 4], [1.0, 0.0, 1.0, 1.0])
    assert env.observation_space.shape == (start + 4 + 10,)


def test_fish_is_not_pushed_at_spawn_and_has_no_critical_parts():
    body = make_body("fish")
    assert body.initial_push is False and body.critical_geoms == ()
    assert all(m.contact_geom for m in body.motors)  # every joint reports contact


def test_dm_control_walkers_use_acl3d_servos_and_collision_scheme():
    env = make("dmc:cmu_humanoid", True)
    m = env.model
    geoms = env.bound.body_geom_ids
    assert np.all(m.geom_contype[geoms] == 0) and np.all(m.geom_group[geoms] == 1)
    gears = m.actuator_gear[env.bound.actuator_ids, 0]
    assert gears.min() == pytest.approx(20.0) and gears.max() > gears.min()  # per-joint limits
    env.reset(seed=0)
    env.step(np.ones(56))
    torque_caps = m.actuator_forcerange[env.bound.actuator_ids, 1] * gears
    assert np.allclose(torque_caps, gears)  # |a| = 1: each joint's own limit
    body_z = env.data.xpos[env.bound.root_id, 2]
    assert body_z > 0.5  # spawned standing: the base is at the pelvis, above the feet
    assert mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "walker/cmu/head") in geoms


@pytest.mark.parametrize(
    "env_id", ["acl3d/StumpTracks-v0", "acl3d/HexagonTracks-v0", "acl3d/Parkour-v0"]
)
@pytest.mark.parametrize(
    "body, options",
    [("millipede", {"nb_of_bodies": 12}), ("spider", {"nb_pairs_of_legs": 8})],
)
def test_the_largest_documented_bodies_build_on_every_track(env_id, body, options):
    env = gym.make(env_id, body=body, body_options=options)
    obs, _ = env.reset(seed=0)
    obs, *_ = env.step(np.full(env.action_space.shape, 0.5))
    assert np.all(np.isfinite(obs))


def test_an_odd_start_pad_builds_on_parkour():
    """11 segments widen the start pad to 21 TS: the heightfields get 241 columns."""
    env = gym.make("acl3d/Parkour-v0", body="millipede", body_options={"nb_of_bodies": 11})
    env.reset(seed=0)
    assert env.unwrapped.model.hfield_ncol.tolist() == [241, 241]
