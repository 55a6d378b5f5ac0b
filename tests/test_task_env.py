"""The declared env interfaces: every acl3d env is a TaskEnv and a SnapshotEnv; other envs are
refused by name before a curriculum starts."""

from __future__ import annotations

import gymnasium as gym
import pytest

from acl3d import envs
from acl3d.envs.task_env import SnapshotEnv, TaskEnv, task_env
from acl3d.training.curriculum import CurriculumEnv


@pytest.mark.parametrize("name", envs.ENV_NAMES)
def test_every_acl3d_env_is_a_task_env_with_snapshots(name):
    env = envs.make(name)
    try:
        inner = task_env(env)
        assert inner is env.unwrapped
        assert isinstance(inner, TaskEnv) and isinstance(inner, SnapshotEnv)
        # Gymnasium's solved-return convention is the env's own success return
        assert env.spec.reward_threshold == inner.curriculum_profile.success_return
    finally:
        env.close()


def test_an_env_without_tasks_is_refused_by_name():
    env = gym.make("CartPole-v1")
    try:
        assert not isinstance(env.unwrapped, SnapshotEnv)
        with pytest.raises(ValueError, match=r"'CartPole-v1' cannot run a curriculum.*task_space"):
            task_env(env)
        with pytest.raises(ValueError, match="'CartPole-v1' cannot run a curriculum"):
            CurriculumEnv(env)  # the worker refuses it before any episode
    finally:
        env.close()
