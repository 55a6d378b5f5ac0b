"""The many-world simulation on MuJoCo Warp, run on Warp's CPU device (no GPU needed).

Warp compiles its CPU kernels once per machine (about a minute; cached in ~/.cache/warp), so the
checks share one small simulation and stay few: the torch rules equal the numpy rules on the same
physics, Warp steps as CPU MuJoCo does over the first steps, and a reset of some worlds leaves the
others untouched. All tests of this module run on one test worker (`xdist_group`).
"""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
import torch
import yaml

pytest.importorskip("mujoco_warp", reason="the [gpu] extra: pip install 'acl3d[gpu]'")

from acl3d.envs.many_worlds import ManyWorldTracks, many_worlds  # noqa: E402
from acl3d.envs.track_env import TrackEnv  # noqa: E402

pytestmark = pytest.mark.xdist_group("warp")
FLAT = {"stump_height": 0.0, "obstacle_spacing": 6.0}  # stumps of ~0 m: contacts stay smooth


class WorldsAsNumpy:
    """The numpy rules' physics interface over the Warp worlds' fields (float64 copies)."""

    def __init__(self, sim):
        fields = ("qpos", "qvel", "xpos", "xmat", "cvel", "sensordata")
        self._fields = {name: sim.field(name).double().numpy() for name in fields}
        n = self._fields["xmat"].shape[0]
        self._fields["xmat"] = self._fields["xmat"].reshape(n, -1, 9)
        self.controls = sim.field("ctrl").double().numpy()

    def field(self, name):
        return self._fields[name]


@pytest.fixture(scope="module")
def worlds():
    env = ManyWorldTracks(2, device="cpu", body="classic_bipedal")
    env.tasks[:] = env.task_space.to_vector(FLAT)
    env.reset(seed=1)
    return env


def _actions(env, seed):
    g = torch.Generator().manual_seed(seed)
    return torch.rand((env.num_envs, env.action_size), generator=g) * 2 - 1


def _assert_rules_agree(worlds) -> None:
    """The torch rules' observation, head x and shaping equal the numpy rules' on the worlds'
    current physics (float32 tolerance)."""
    rules, physics = worlds.template.rules, WorldsAsNumpy(worlds.sim)
    rows = rules.new_rows(worlds.num_envs)
    rows.heights[:, ..., : worlds.heights.shape[-1]] = worlds.heights.double().numpy()
    x_np, obs_np = rules.observe_rows(physics, rows)
    x_t, obs_t = worlds.rules.observe(worlds.sim, worlds.heights)
    assert obs_np.shape == (worlds.num_envs, worlds.observation_size)
    np.testing.assert_allclose(x_t.numpy(), x_np, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(obs_t.numpy(), obs_np, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(
        worlds.rules.potential(worlds.sim, x_t, obs_t).numpy(),
        rules.potential(physics, x_np, obs_np),
        atol=1e-4,
    )


def test_torch_rules_equal_numpy_rules_on_the_same_physics(worlds):
    for k in range(3):
        worlds.step(_actions(worlds, k))
    _assert_rules_agree(worlds)


def test_torch_rules_of_a_free_3d_body_equal_numpy_rules():
    spider = ManyWorldTracks(2, device="cpu", body="spider", planar=False)
    spider.reset(seed=4)
    for k in range(3):
        spider.step(_actions(spider, 30 + k))
    _assert_rules_agree(spider)
    assert not spider.template.rules.body.planar


@pytest.mark.parametrize("spacing, grid", [((0.1, 0.5), (13, 328)), ((0.5, 0.5), (13, 67))])
def test_3d_terrain_runs_as_many_worlds_with_the_height_scan(spacing, grid):
    field = many_worlds("terrain3d", 2, "cpu", body="big_quadru", grid_spacing=spacing)
    assert tuple(field.sim.terrain("terrain").shape) == (2, *grid)  # each world's own field
    task = field.task_space.to_vector({"hill_slope": 0.2, "cross_slope": 0.15, "roughness": 0.1})
    field.tasks[:] = task
    field.reset(seed=2)
    assert float(field.heights.std()) > 0  # a field that varies, read by the height scan
    for k in range(3):
        obs, reward, terminated, truncated, infos = field.step(_actions(field, 40 + k))
        assert torch.isfinite(obs).all() and torch.isfinite(reward).all()
    _assert_rules_agree(field)


def test_warp_steps_as_cpu_mujoco_over_the_first_steps(worlds):
    cpu = TrackEnv(body="classic_bipedal")
    obs_cpu, _ = cpu.reset(seed=5, options={"task": FLAT})
    # world 1 takes the CPU env's terrain and state
    sim = worlds.sim
    heights = torch.as_tensor(cpu.arena.heights, dtype=torch.float32)
    worlds.heights[1, : len(heights)] = heights
    sim.terrain("terrain")[1] = torch.as_tensor(
        cpu.model.hfield_data.reshape(2, -1), dtype=torch.float32
    )
    qpos = torch.as_tensor(cpu.data.qpos, dtype=torch.float32)[None]
    qvel = torch.as_tensor(cpu.data.qvel, dtype=torch.float32)[None]
    sim.reset_worlds(torch.tensor([1]), qpos, qvel)
    worlds.prev_shaping[1] = float(cpu.rows.prev_shaping[0])
    worlds.elapsed[1] = 0
    # float32 against float64: ~1e-6 until a foot's contact starts (the 6th step of this seed,
    # where the two part by ~3e-3, as contact onsets do; docs/architecture.md)
    assert_world_1_steps_as(cpu, worlds, [_actions(worlds, 100 + k) for k in range(5)], 1e-5, 1e-4)


def assert_world_1_steps_as(cpu, worlds, actions, qpos_atol: float, obs_atol: float) -> None:
    """World 1 of `worlds` and the CPU env `cpu` (in the same state) take the same actions and
    stay within the tolerances (rewards within 1e-4), neither ending its episode."""
    for a in actions:
        obs_cpu, reward_cpu, terminated, _, _ = cpu.step(a[1].numpy())
        obs, reward, terminated_w, _, _ = worlds.step(a)
        assert not terminated and not terminated_w[1]
        np.testing.assert_allclose(
            worlds.sim.field("qpos")[1].numpy(), cpu.data.qpos, atol=qpos_atol
        )
        np.testing.assert_allclose(obs[1].numpy(), obs_cpu, atol=obs_atol)
        assert abs(float(reward[1]) - reward_cpu) < 1e-4


def _thirty_steps(**reserved):
    """(simulation, last observations) of two Stump Tracks worlds after 30 steps."""
    env = many_worlds("stump-tracks", 2, "cpu", **reserved)
    env.reset(seed=1)
    for k in range(30):
        obs, *_ = env.step(_actions(env, 70 + k))
    env.close()
    return env.sim, obs


def test_fewer_contact_slots_step_the_same_and_a_full_pool_is_flagged():
    """The contact slots reserved per world (MuJoCo Warp's nconmax: one pool of N x slots for
    the broadphase's candidate pairs and the contacts) set the collision kernels' cost, not
    their result, while the pool holds a step's pairs and contacts; a full pool is flagged."""
    default, obs = _thirty_steps()
    tight, tight_obs = _thirty_steps(contact_slots=8)  # 5 candidate pairs a world, ~1 contact
    short, _ = _thirty_steps(contact_slots=2)
    assert tight.contact_slots == 8 < default.contact_slots
    assert torch.equal(tight_obs, obs)
    assert not default.contact_overflows() and not tight.contact_overflows()
    assert short.contact_overflows()
    with pytest.raises(ValueError, match=r"contact_slots=0"):
        many_worlds("stump-tracks", 2, "cpu", contact_slots=0)


def test_fewer_constraint_rows_step_the_same_and_a_world_needing_more_is_flagged():
    """The constraint rows reserved per world (MuJoCo Warp's njmax) set the solver's cost, not
    its result, while every world's rows fit; a world that needs more is flagged."""
    runs = {}
    for rows in (None, 72, 8):
        sim, obs = _thirty_steps(constraint_rows=rows)
        runs[rows] = (sim.constraint_rows, obs, sim.constraint_overflows())
    (default_rows, obs, overflows), (rows, tight_obs, tight_overflows) = runs[None], runs[72]
    assert rows == 72 < default_rows
    assert torch.equal(tight_obs, obs) and not overflows.any() and not tight_overflows.any()
    assert runs[8][2].all()  # a walker's feet on the ground need more than 8 rows
    with pytest.raises(ValueError, match=r"constraint_rows=0"):
        many_worlds("stump-tracks", 2, "cpu", constraint_rows=0)


def test_resetting_some_worlds_leaves_the_others_untouched(worlds):
    worlds.step(_actions(worlds, 7))
    sim = worlds.sim
    before = {name: sim.field(name)[1].clone() for name in ("qpos", "qvel")}
    terrain_before = sim.terrain("terrain")[1].clone()
    heights_before = worlds.heights[1].clone()
    obs_before = worlds.obs.clone()
    task = worlds.task_space.to_vector({"stump_height": 2.0, "obstacle_spacing": 1.0})
    obs = worlds._reset_worlds(np.array([0]), task[None], worlds.obs)
    for name, value in before.items():
        assert torch.equal(sim.field(name)[1], value), name
    assert torch.equal(sim.terrain("terrain")[1], terrain_before)
    assert torch.equal(worlds.heights[1], heights_before)
    assert torch.equal(obs[1], obs_before[1])
    assert not torch.equal(sim.terrain("terrain")[0], terrain_before)  # world 0's new stumps
    assert worlds.stats.returns[0] == 0 and worlds.elapsed[0] == 0


def test_a_reset_worlds_first_observation_is_that_of_its_reset_state(worlds):
    """The start worlds compute what a `forward` of the worlds themselves gives."""
    worlds.step(_actions(worlds, 13))
    task = worlds.task_space.to_vector({"stump_height": 1.0, "obstacle_spacing": 2.0})
    obs = worlds._reset_worlds(np.array([1]), task[None], worlds.obs)
    worlds.sim.forward()
    x, again = worlds.rules.observe(worlds.sim, worlds.heights)
    assert torch.equal(obs[1], again[1])
    assert worlds.prev_shaping[1] == worlds.rules.potential(worlds.sim, x, again)[1]


def test_more_resets_than_start_worlds_are_done_in_parts():
    envs = [ManyWorldTracks(3, device="cpu", start_worlds=k) for k in (1, 3)]
    assert [env.starts.nworld for env in envs] == [1, 3]
    runs = []
    for env in envs:
        env.tasks[:] = env.task_space.to_vector({"stump_height": 1.5, "obstacle_spacing": 1.0})
        first = env.reset(seed=6)
        runs.append([first, *(env.step(_actions(env, 50 + k))[0] for k in range(2))])
    assert all(torch.equal(a, b) for a, b in zip(*runs))
    with pytest.raises(ValueError, match="start_worlds"):
        ManyWorldTracks(3, device="cpu", start_worlds=4)


def test_a_reset_with_a_period_repeats_the_first_worlds_draws():
    """Copies of one set of episodes (several policies evaluated side by side): worlds i and
    i + period get what worlds 0..period-1 of a period-world simulation get from the seed."""
    copies, alone = ManyWorldTracks(4, device="cpu"), ManyWorldTracks(2, device="cpu")
    for env in (copies, alone):
        env.tasks[:] = np.tile(env.task_space.to_vector({"stump_height": 1.0}), (env.num_envs, 1))
        env.tasks[:, 1] = np.resize([1.0, 4.0], env.num_envs)  # two spacings per block
    first, single = copies.reset(seed=3, period=2), alone.reset(seed=3)
    assert torch.equal(first[:2], single) and torch.equal(first[2:], single)
    terrain = copies.sim.terrain("terrain")
    assert torch.equal(terrain[:2], terrain[2:]) and not torch.equal(terrain[0], terrain[1])
    with pytest.raises(ValueError, match=r"period=5; valid: an integer in \[1, 4\]"):
        copies.reset(seed=3, period=5)
    with pytest.raises(ValueError, match="period=0; valid"):
        copies.reset(seed=3, period=0)


def test_without_autoreset_finished_worlds_play_on_until_reset():
    env = ManyWorldTracks(2, device="cpu", max_episode_steps=3, autoreset=False)
    env.reset(seed=8)
    ends = [env.step(_actions(env, 60 + k))[3] for k in range(4)]
    assert [bool(t.all()) for t in ends] == [False, False, True, True]
    assert env.elapsed.tolist() == [4, 4]  # no new episode began
    env.reset(seed=8)
    assert env.elapsed.tolist() == [0, 0]


def test_a_restored_state_continues_as_the_original(worlds):
    worlds.step(_actions(worlds, 11))
    saved = worlds.get_state()
    fresh = ManyWorldTracks(2, device="cpu", body="classic_bipedal")
    with pytest.raises(gym.error.ResetNeeded, match="reset"):  # no episode to step or save yet
        fresh.step(_actions(fresh, 20))
    with pytest.raises(gym.error.ResetNeeded, match="reset"):
        fresh.get_state()
    runs = []
    for env in (worlds, worlds, fresh):  # restored twice, and into new worlds (no reset needed)
        env.set_state(saved)
        out = [env.step(_actions(env, 20 + k)) for k in range(3)]
        runs.append((out[-1][0].clone(), torch.stack([o[1] for o in out])))
    for obs, rewards in runs[1:]:
        assert torch.equal(runs[0][0], obs) and torch.equal(runs[0][1], rewards)


def test_rsl_ppo_trains_on_the_warp_worlds_and_resumes_exactly(tmp_path):
    pytest.importorskip("rsl_rl")
    from acl3d.cli import main

    common = [
        "--student", "rsl-ppo", "--env", "stump-tracks", "--teacher", "alp-gmm", "--seed", "2",
        "--teacher-param", "fit_rate=10", "--teacher-param", "nb_bootstrap=5",
        "--env-kwarg", "max_episode_steps=60", "--n-envs", "4", "--nb-test-episodes", "4",
        "--student-param", "num_steps_per_env=32", "--student-param", "hidden_dims=[32, 32]",
        "--eval-every", "256", "--checkpoint-every", "256", "--no-progress", "--quiet",
        "--vec-env", "warp",
    ]  # fmt: skip
    whole, parts = tmp_path / "whole", tmp_path / "parts"
    # whole: its evaluations played side by side at the end (the default here); parts: each
    # when it falls due, as 4 worlds
    assert main(["train", *common, "--steps", "512", "--out", str(whole)]) == 0
    parted = [*common, "--eval-together", "1", "--steps", "256", "--out", str(parts)]
    assert main(["train", *parted]) == 0
    assert main(["train", "--resume", str(parts), "--steps", "512", "--quiet"]) == 0
    episodes = (whole / "episodes.csv").read_text()
    assert len(episodes.splitlines()) > 8
    seconds = json.loads((whole / "status.json").read_text())["seconds_by_phase"]
    assert set(seconds) == {"collect", "teacher", "update", "evaluate", "records"}
    assert all(value > 0 for value in seconds.values())
    assert episodes == (parts / "episodes.csv").read_text()  # with tasks drawn ahead (rounds)
    resolved = yaml.safe_load((whole / "config.yaml").read_text())["resolved"]
    assert resolved["teacher_reserve"] == 1
    evals = [line.split(",")[:6] for line in (whole / "evals.csv").read_text().splitlines()]
    assert evals == [line.split(",")[:6] for line in (parts / "evals.csv").read_text().splitlines()]
    # `acl3d evaluate` plays the final policy on the worlds the run evaluated on
    played = tmp_path / "played.csv"
    assert main(["evaluate", str(whole), "--out", str(played)]) == 0
    own = [row.split(",") for row in (whole / "evals_tasks.csv").read_text().splitlines()[1:]]
    again = [row.split(",")[1:3] for row in played.read_text().splitlines()[1:]]
    assert again == [row[2:4] for row in own if row[0] == "512"]


@pytest.mark.parametrize("teacher", ["robust-plr", "self-paced"])
def test_teachers_learning_from_steps_train_on_the_warp_worlds_and_resume_exactly(
    teacher, tmp_path, monkeypatch
):
    """Every world's steps reach the teacher in one call per step: each Robust PLR episode is
    scored from its own steps (their rewards sum to its return), SPDL gets each episode's first
    observation, and a run stopped halfway and resumed is the uninterrupted one."""
    pytest.importorskip("rsl_rl")
    from acl3d.cli import main
    from acl3d.teachers.plr import RobustPLR
    from acl3d.teachers.self_paced import SelfPaced

    seen = []
    score, learn = RobustPLR._episode_score, SelfPaced._episodic_update

    def scored(self, index, reward):
        steps = self._finished[0] if self._finished else None
        seen.append(steps is not None and abs(float(np.sum(steps[1])) - reward) < 1e-3)
        return score(self, index, reward)

    def learnt(self, task, reward, is_success):
        seen.append(self._pending_state is not None and len(self._finished_returns) > 0)
        return learn(self, task, reward, is_success)

    monkeypatch.setattr(RobustPLR, "_episode_score", scored)
    monkeypatch.setattr(SelfPaced, "_episodic_update", learnt)
    params = {"robust-plr": "buffer_size=8", "self-paced": "update_frequency=64"}[teacher]
    common = [
        "--student", "rsl-ppo", "--env", "stump-tracks", "--teacher", teacher, "--seed", "2",
        "--teacher-param", params, "--env-kwarg", "max_episode_steps=60", "--n-envs", "4",
        "--nb-test-episodes", "4", "--student-param", "num_steps_per_env=32",
        "--student-param", "hidden_dims=[32, 32]", "--eval-every", "512",
        "--checkpoint-every", "256", "--periodical-samples-every", "256", "--no-progress",
        "--quiet", "--vec-env", "warp",
    ]  # fmt: skip
    whole, parts = tmp_path / "whole", tmp_path / "parts"
    assert main(["train", *common, "--steps", "512", "--out", str(whole)]) == 0
    assert len(seen) >= 8 and all(seen)
    assert main(["train", *common, "--steps", "256", "--out", str(parts)]) == 0
    assert main(["train", "--resume", str(parts), "--steps", "512", "--quiet"]) == 0
    assert (whole / "episodes.csv").read_text() == (parts / "episodes.csv").read_text()
    final = [
        (run / "evals.csv").read_text().splitlines()[-1].split(",")[:6] for run in (whole, parts)
    ]
    assert final[0] == final[1]


def test_policies_evaluated_side_by_side_score_as_each_alone():
    """Two policies, sampled actions, a test set in two chunks, and a spare third block: each
    scores what it scores alone, though one block's episodes outlast the other's."""
    pytest.importorskip("rsl_rl")
    from acl3d.training.torch_student import rsl_ppo
    from acl3d.training.torch_student.evaluation import ManyWorldEvaluator

    tasks = np.array([[0.0, 4.0], [1.0, 3.0], [2.0, 5.0], [0.5, 2.0]])
    where = ("stump-tracks", "classic_bipedal", {"max_episode_steps": 300}, tasks, 7, 2, "cpu")
    together, alone = ManyWorldEvaluator(*where, copies=3), ManyWorldEvaluator(*where, copies=1)
    spec = {"student": "rsl-ppo", "observation_size": alone.observation_shape[0],
            "action_size": 4, "hidden_dims": [16], "activation": "elu", "init_noise_std": 1.0}  # fmt: skip
    torch.manual_seed(0)
    actors = [rsl_ppo._models(spec, 1, "cpu")[0] for _ in range(2)]
    with torch.no_grad():
        for weight in actors[1].mlp.parameters():
            weight.zero_()  # its episodes last other lengths than the first one's
    policies = [rsl_ppo.PolicySnapshot(spec, actor, -1.0, 1.0) for actor in actors]
    side_by_side = together.run(policies, stochastic=True)
    for policy, result in zip(policies, side_by_side):
        (own,) = alone.run([policy], stochastic=True)
        np.testing.assert_array_equal(result.returns, own.returns)
        np.testing.assert_array_equal(result.lengths, own.lengths)
