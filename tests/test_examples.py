"""The scripts in scripts/examples run end to end at a tiny budget (real physics, real training)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from acl3d.run_format.tables import read_csv
from acl3d.training import students

EXAMPLES = Path(__file__).resolve().parents[1] / "scripts" / "examples"


def example(name: str):
    """Import scripts/examples/NAME.py as a module."""
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_cleanrl_ppo_trains_on_the_batched_env_with_alp_gmm(tmp_path):
    cleanrl = example("cleanrl_ppo")
    args = cleanrl.parse_args(
        ["--total-steps", "512", "--num-envs", "4", "--num-steps", "64", "--minibatch-size", "64",
         "--epochs", "2", "--max-episode-steps", "30", "--out", str(tmp_path), "--quiet"]
    )  # fmt: skip
    result = cleanrl.train(args)
    assert result["steps"] == 512 and result["episodes"] >= 8
    episodes = read_csv(tmp_path / "episodes.csv")
    assert len(episodes["return"]) == result["episodes"]
    assert set(episodes["length"]) <= set(range(1, 31))
    assert (tmp_path / "agent.pt").stat().st_size > 0


def test_cleanrl_ppo_normalises_as_sb3_vecnormalize():
    """The example's normalisation on Gymnasium's NEXT_STEP autoreset gives what SB3's
    VecNormalize gives `acl3d train` on the same episodes: rewards, observation and return
    statistics, with falls (terminations) and time limits among the episodes."""
    from stable_baselines3.common.vec_env import VecNormalize

    from acl3d.envs.batched_vector import BatchedVectorEnv
    from acl3d.vec.batched_sb3 import BatchedVecEnv

    env_id = "acl3d/StumpTracks-v0"
    ours = example("cleanrl_ppo").VecNormalize(
        BatchedVectorEnv(env_id, 1, max_episode_steps=60), 0.99
    )
    sb3 = VecNormalize(
        BatchedVecEnv(env_id, 1, max_episode_steps=60), clip_obs=10.0, clip_reward=10.0, gamma=0.99
    )
    sb3.seed(0)
    assert np.allclose(ours.reset(seed=0)[0], sb3.reset(), atol=1e-6)
    rng = np.random.default_rng(0)
    ends = {"terminated": 0, "truncated": 0}
    for _ in range(400):
        action = rng.uniform(-1, 1, (1, 4))
        obs_sb3, reward_sb3, _, _ = sb3.step(action)
        _, reward, terminated, truncated, _ = ours.step(action)
        assert np.isclose(reward[0], reward_sb3[0], rtol=1e-5, atol=1e-7)
        if terminated[0] or truncated[0]:
            ends["terminated" if terminated[0] else "truncated"] += 1
            obs, reward, *_ = ours.step(action)  # NEXT_STEP's reset step: what SB3 returned
            assert reward[0] == 0.0 and np.allclose(obs, obs_sb3, atol=1e-5)
    assert min(ends.values()) >= 1, ends
    assert np.allclose(ours.obs_rms.mean, sb3.obs_rms.mean) and np.allclose(
        ours.obs_rms.var, sb3.obs_rms.var
    )
    assert ours.obs_rms.count == sb3.obs_rms.count and np.isclose(ours.ret_rms.var, sb3.ret_rms.var)


def test_syllabus_curriculum_drives_the_batched_env():
    pytest.importorskip("syllabus")
    out = example("syllabus_curriculum").main(
        ["--steps", "400", "--num-envs", "4", "--max-episode-steps", "30"]
    )
    tasks = out["tasks"]
    assert len(tasks) >= 8 and len(np.unique(tasks[:, 0])) == len(tasks)  # a new task each
    assert tasks.min() >= 0.0 and tasks[:, 0].max() <= 3.0 and tasks[:, 1].max() <= 6.0


def test_custom_teacher_trains_with_acl3d_train(tmp_path):
    result, rc = example("custom_teacher").main(
        ["--steps", "256", "--n-steps", "64", "--max-episode-steps", "30",
         "--out", str(tmp_path / "ef")]
    )  # fmt: skip
    assert rc == 0 and result.steps == 256
    for run in (tmp_path / "ef", tmp_path / "ef_cli"):
        tasks = read_csv(run / "episodes.csv")["stump_height"]
        assert len(tasks) >= 8 and max(tasks) <= 0.3 * 3.0 + 1e-6  # the easy part only


def test_any_sb3_algorithm_through_train_and_the_cli(tmp_path):
    td3, rc = example("sb3_any_algorithm").main(
        ["--steps", "200", "--learning-starts", "50", "--max-episode-steps", "30",
         "--out", str(tmp_path)]
    )  # fmt: skip
    assert rc == 0 and td3.steps == 200
    assert students.detect(tmp_path / "td3" / "final_model.zip") == "sb3:TD3"
    assert students.detect(tmp_path / "a2c" / "final_model.zip") == "sb3:A2C"
    assert students.load(None, tmp_path / "td3" / "final_model.zip").action_noise is not None
