"""Training Stable-Baselines3 students on a teacher's curriculum: `train(config)` and friends."""

from acl3d.training.trainer import TrainConfig, TrainResult, train

__all__ = ["TrainConfig", "TrainResult", "train"]
