"""Training Stable-Baselines3 students on a teacher's curriculum: `train(config)` and friends.

`config` (TrainConfig and its validation) < `session` (envs, student, controller, checkpoints)
< `callbacks` (logging, evaluation, checkpoints, student resets) < `trainer` (`train()`).
The names below load on first use, so `acl3d.training.config` alone stays light (the CLI's
parser imports it without torch and SB3).
"""

import importlib

from acl3d.extras import optional_dependency

_EXPORTS = {"TrainConfig": "config", "TrainResult": "trainer", "train": "trainer"}
__all__ = list(_EXPORTS)


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'acl3d.training' has no attribute {name!r}")
    with optional_dependency(f"acl3d.training.{name}"):
        return getattr(importlib.import_module(f"acl3d.training.{_EXPORTS[name]}"), name)
