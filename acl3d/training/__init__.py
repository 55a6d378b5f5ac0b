"""Training Stable-Baselines3 students on a teacher's curriculum: `train(config)` and friends.

`config` (TrainConfig and its validation) < `session` (envs, student, controller, checkpoints)
< `callbacks` (logging, evaluation, checkpoints, student resets) < `trainer` (`train()`).
"""

from acl3d.training.config import TrainConfig
from acl3d.training.trainer import TrainResult, train

__all__ = ["TrainConfig", "TrainResult", "train"]
