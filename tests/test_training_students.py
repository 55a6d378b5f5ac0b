"""Students: presets, the value function given to teachers, forgetting resets, state files."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from gymnasium.wrappers import TimeLimit
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize
from test_training_curriculum import CountingEnv

from acl3d.teachers.state_files import load_state, save_state
from acl3d.training import checkpoint, students
from acl3d.training.curriculum import CurriculumEnv


def counting_venv(n_envs: int = 1):
    def make():
        env = CurriculumEnv(TimeLimit(CountingEnv(), max_episode_steps=9))
        for _ in range(1000):
            env.push_task([3.0, 0.5])
        return env

    return DummyVecEnv([make] * n_envs)


def test_benchmark_presets_follow_teachmyagent():
    sac = students.hyperparameters("sac", "benchmark", n_envs=2)
    assert sac["policy_kwargs"] == {"net_arch": [400, 300], "activation_fn": "relu"}
    assert (sac["learning_rate"], sac["batch_size"], sac["ent_coef"]) == (1e-3, 1000, 0.005)
    assert (sac["buffer_size"], sac["learning_starts"], sac["tau"]) == (2_000_000, 10_000, 0.005)
    assert sac["gradient_steps"] / (sac["train_freq"] * 2) == pytest.approx(0.1)  # 1 per 10 steps
    ppo = students.hyperparameters("ppo", "benchmark", n_envs=2)
    assert ppo["n_steps"] * 2 == 20_000 and ppo["batch_size"] == 1000 and ppo["n_epochs"] == 5
    assert ppo["policy_kwargs"]["activation_fn"] == "tanh" and ppo["ent_coef"] == 0.0
    assert students.uses_vecnormalize("ppo") and not students.uses_vecnormalize("sac")


def test_overrides_are_checked():
    assert students.hyperparameters("sac", "fast", 1, {"buffer_size": 5000})["buffer_size"] == 5000
    with pytest.raises(ValueError, match="unknown student parameter 'n_steps' for sac"):
        students.hyperparameters("sac", "fast", 1, {"n_steps": 5})
    with pytest.raises(ValueError, match="buffer_size .* must be >= batch_size"):
        students.hyperparameters("sac", "fast", 1, {"buffer_size": 10})


def test_ppo_value_estimator_uses_normalised_observations():
    venv = VecNormalize(counting_venv(), clip_obs=10.0)
    model = students.build(
        "ppo",
        students.hyperparameters("ppo", "fast", 1, {"n_steps": 64, "batch_size": 64}),
        venv,
        seed=0,
    )
    model.learn(64)  # moves the normalisation statistics away from identity
    states = np.array([[3.0, 0.5, 2.0], [3.0, 0.5, 7.0]], dtype=np.float32)
    values = students.value_estimator(model, venv.normalize_obs)(states)
    expected = model.policy.predict_values(torch.as_tensor(venv.normalize_obs(states))).flatten()
    np.testing.assert_allclose(values, expected.detach().numpy(), rtol=1e-6)
    raw = model.policy.predict_values(torch.as_tensor(states)).flatten().detach().numpy()
    assert not np.allclose(values, raw)


def test_sac_value_estimator_is_min_of_critics_and_follows_resets():
    model = students.build(
        "sac",
        students.hyperparameters("sac", "fast", 1, {"learning_starts": 10, "batch_size": 16}),
        counting_venv(),
        seed=0,
    )
    model.learn(40)
    estimate = students.value_estimator(model)
    states = np.array([[3.0, 0.5, 1.0]], dtype=np.float32)
    obs = torch.as_tensor(states)
    with torch.no_grad():
        q1, q2 = model.policy.critic(obs, model.policy.actor(obs, deterministic=True))
    np.testing.assert_allclose(estimate(states), torch.min(q1, q2).flatten().numpy(), rtol=1e-6)
    before = estimate(states)
    assert model.replay_buffer.pos > 0
    students.reinitialise(model)
    assert model.replay_buffer.pos == 0 and not model.replay_buffer.full
    assert model.actor is model.policy.actor
    assert not np.allclose(estimate(states), before)
    model.learn(40, reset_num_timesteps=False)  # trains again after the reset


def test_replay_buffer_and_normalisation_files_round_trip(tmp_path):
    model = students.build(
        "sac",
        students.hyperparameters("sac", "fast", 1, {"learning_starts": 10, "batch_size": 16}),
        counting_venv(),
        seed=0,
    )
    model.learn(30)
    checkpoint.save_replay_buffer(model.replay_buffer, tmp_path / "rb.npz")
    other = students.build(
        "sac", students.hyperparameters("sac", "fast", 1), counting_venv(), seed=1
    )
    checkpoint.load_replay_buffer(other.replay_buffer, tmp_path / "rb.npz")
    pos = model.replay_buffer.pos
    assert pos >= 30 and other.replay_buffer.pos == pos
    np.testing.assert_array_equal(
        other.replay_buffer.observations[:pos], model.replay_buffer.observations[:pos]
    )
    np.testing.assert_array_equal(
        other.replay_buffer.rewards[:pos], model.replay_buffer.rewards[:pos]
    )

    venv = VecNormalize(counting_venv())
    venv.reset()
    for _ in range(20):
        venv.step(np.zeros((1, 1), dtype=np.float32))
    checkpoint.save_normalization(venv, tmp_path / "m.zip")
    fresh = VecNormalize(counting_venv())
    checkpoint.load_normalization_into(fresh, tmp_path / "m.zip")
    obs = np.array([[3.0, 0.5, 4.0]], dtype=np.float32)
    np.testing.assert_allclose(fresh.normalize_obs(obs), venv.normalize_obs(obs))
    np.testing.assert_allclose(
        checkpoint.observation_normalizer(tmp_path / "m.zip")(obs),
        venv.normalize_obs(obs),
        rtol=1e-6,
    )


def test_rng_state_round_trip(tmp_path):
    np.random.seed(1)
    torch.manual_seed(2)
    save_state(tmp_path / "rng", checkpoint.rng_state())
    first = (np.random.rand(3), torch.rand(3))
    checkpoint.set_rng_state(load_state(tmp_path / "rng"))
    np.testing.assert_array_equal(np.random.rand(3), first[0])
    assert torch.equal(torch.rand(3), first[1])


def test_detect_student_from_zip(tmp_path):
    model = students.build(
        "ppo",
        students.hyperparameters("ppo", "fast", 1, {"n_steps": 64, "batch_size": 64}),
        counting_venv(),
        seed=0,
    )
    model.save(tmp_path / "p.zip")
    assert students.detect(tmp_path / "p.zip") == "ppo"
    (tmp_path / "bad.zip").write_text("not a zip")
    with pytest.raises(ValueError, match="not a Stable-Baselines3 model zip"):
        students.detect(tmp_path / "bad.zip")


def test_any_sb3_algorithm_takes_its_own_checked_hyperparameters():
    td3 = students.hyperparameters("sb3:TD3", "fast", 2, {"tau": 0.01, "action_noise_std": 0.2})
    assert td3 == {
        "policy_kwargs": {"net_arch": [64, 64], "activation_fn": "tanh"},
        "tau": 0.01,
        "action_noise_std": 0.2,
    }
    assert students.collection_steps("sb3:TD3", td3, 2) == 2  # TD3's train_freq: 1 step
    assert students.collection_steps("sb3:A2C", {"n_steps": 8}, 4) == 32
    assert students.uses_vecnormalize("sb3:A2C") and not students.uses_vecnormalize("sb3:TD3")
    assert students.spec(students.algorithm_class("sb3:TD3")) == "stable_baselines3.td3.td3:TD3"
    model = students.build("sb3:TD3", td3, counting_venv(2), seed=0)
    model.learn(40)
    values = students.value_estimator(model)(np.array([[3.0, 0.5, 2.0]], dtype=np.float32))
    assert values.shape == (1,) and np.isfinite(values).all()
    students.reinitialise(model)
    assert model.replay_buffer.size() == 0 and model.actor is model.policy.actor


@pytest.mark.parametrize(
    "student, overrides, match",
    [
        ("sb3:Nope", {}, "student"),
        ("acl3d.task_space:TaskSpace", {}, "Stable-Baselines3 algorithm class"),
        ("td3", {}, "student"),
        ("sb3:TD3", {"gae_lambda": 0.9}, "unknown student parameter 'gae_lambda' for sb3:TD3"),
        ("sb3:A2C", {"action_noise_std": 0.1}, "unknown student parameter"),
    ],
)
def test_bad_students_raise(student, overrides, match):
    with pytest.raises(ValueError, match=match):
        students.hyperparameters(student, "fast", 1, overrides)
