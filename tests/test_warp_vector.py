"""The many-world simulation's front: Gymnasium's vector API with `device=` (spaces, Gymnasium's
info masks, a teacher or a curriculum_sync, refused devices, actions and tasks), the training
options that select it, and the sensors it refuses by name. On Warp's CPU device (no GPU
needed), on the test worker of the other Warp tests (`xdist_group`)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

pytest.importorskip("mujoco_warp", reason="the [gpu] extra: pip install 'acl3d[gpu]'")

from acl3d.envs.many_worlds import many_worlds  # noqa: E402

pytestmark = pytest.mark.xdist_group("warp")


def test_make_vec_with_a_device_gives_the_warp_worlds_behind_gymnasiums_api():

    from acl3d.teachers import make

    envs = gym.make_vec(
        "acl3d/StumpTracks-v0", num_envs=2, vectorization_mode="vector_entry_point", device="cpu"
    )
    teacher = make("random", envs.unwrapped.task_space, seed=0)
    taught = gym.make_vec(
        "acl3d/StumpTracks-v0", num_envs=2, vectorization_mode="vector_entry_point",
        device="cpu", teacher=teacher, max_episode_steps=5,
    )  # fmt: skip
    obs, info = envs.reset(seed=0, options={"task": {"stump_height": 0.5}})
    assert isinstance(obs, torch.Tensor) and obs.shape == (2, *envs.single_observation_space.shape)
    assert envs.observation_space.shape == (2, *envs.single_observation_space.shape)
    obs, reward, terminated, truncated, infos = envs.step(envs.action_space.sample())
    assert reward.shape == (2,) and "final_obs" in infos
    taught.reset(seed=1)
    for _ in range(5):
        *_, truncated, infos = taught.step(np.zeros((2, 4), np.float32))
        for key in ("final_obs", "success", "episode_return"):  # Gymnasium's info layout
            assert torch.equal(infos["_" + key], truncated)
    assert bool(truncated.all()) and teacher.nb_episodes == 2  # the teacher saw both episodes

    class Tasks:  # a curriculum of one fixed reply
        def __init__(self, reply):
            self.reply = reply

        def sync(self, finished, ids):
            return np.tile(self.reply, (len(ids), 1))

    for reply, match in (([np.nan, 1.0], "the curriculum's tasks"), ([99.0, 1.0], "stump_height")):
        with pytest.raises(ValueError, match=match):  # refused before any world resets
            gym.make_vec(
                "acl3d/StumpTracks-v0", num_envs=2, vectorization_mode="vector_entry_point",
                device="cpu", curriculum_sync=Tasks(reply),
            ).reset(seed=0)  # fmt: skip
    with pytest.raises(ValueError, match="movable_creepers=True on the many-world"):
        gym.make_vec(
            "acl3d/Parkour-v0", num_envs=2, vectorization_mode="vector_entry_point",
            device="cpu", movable_creepers=True,
        )  # fmt: skip
    with pytest.raises(ValueError, match="actions: non-finite"):
        envs.step(np.full((2, 4), np.nan, np.float32))
    for bad in ([["0.1"] * 4] * 2, torch.ones((2, 4), dtype=torch.bool), np.full((2, 4), 1j)):
        with pytest.raises(ValueError, match="actions: expected real numbers"):
            envs.step(bad)
    for device in ("tpu", "cuda:x", "meta") + (() if torch.cuda.is_available() else ("cuda",)):
        with pytest.raises(ValueError, match=rf"device='{device}'; valid: cpu"):
            gym.make_vec(
                "acl3d/StumpTracks-v0", num_envs=2, vectorization_mode="vector_entry_point",
                device=device,
            )  # fmt: skip


def test_the_many_world_simulation_takes_more_worlds_than_the_cpu_batched_env():
    from acl3d.training.config import TrainConfig, uses_many_worlds, validate

    warp = TrainConfig(student="rsl-ppo", vec_env="warp", n_envs=16_384)
    assert uses_many_worlds(warp)
    validate(warp, on_this_machine=False)
    with pytest.raises(ValueError, match=r"n_envs.*4096"):
        validate(TrainConfig(student="ppo", n_envs=16_384), on_this_machine=False)


def test_runs_on_the_many_world_simulation_evaluate_ten_times_by_default():
    from acl3d.training.config import TrainConfig

    gpu = TrainConfig(student="rsl-ppo", device="cuda", steps=20_000_000)
    assert gpu.effective_eval_every == 2_000_000
    assert TrainConfig(student="rsl-ppo", vec_env="warp", steps=1_000_000).effective_eval_every == (
        500_000
    )
    assert TrainConfig(student="ppo", steps=20_000_000).effective_eval_every == 500_000


def test_warp_loads_its_kernel_modules_without_a_line_each():
    from acl3d.sim.warp_backend import import_warp

    warp, _ = import_warp()
    assert warp.config.log_level >= warp.LOG_WARNING  # 1.19 dropped config.quiet


@pytest.mark.parametrize(
    "name, observation, valid",
    [("stump-tracks", "height_scan", "'lidar'"), ("terrain3d", "lidar", "'height_scan'")],
)
def test_a_sensor_the_worlds_do_not_fill_is_refused_by_name(name, observation, valid):
    with pytest.raises(ValueError, match=f"observation='{observation}'; valid: {valid}"):
        many_worlds(name, 2, "cpu", observation=observation)
