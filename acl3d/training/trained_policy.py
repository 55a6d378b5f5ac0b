"""A saved SB3 model as a one-observation policy, with its VecNormalize statistics applied.

It uses the evaluation's own `make_predict`, so a played episode takes the actions that
`acl3d evaluate` takes on the same observations.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


class TrainedPolicy:
    """obs (d,) -> action: the model's deterministic (or sampled) action."""

    def __init__(self, model_path, deterministic: bool = True):
        from acl3d.training import checkpoint, students
        from acl3d.training.evaluation import make_predict
        from acl3d.training.torch_student.policy_file import is_policy_file

        path = Path(model_path)
        if path.suffix != ".zip" or not path.is_file():
            raise ValueError(f"model={str(model_path)!r}: not an existing SB3 model .zip")
        self.path = path
        if is_policy_file(path):  # a torch-native student's policy (normaliser inside)
            from acl3d.training.torch_student.rsl_ppo import SavedPolicy

            saved = SavedPolicy(path)
            self.shapes = ((saved.observation_size,), (saved.action_size,))
            self.normalized = True
            self._predict = lambda obs: saved(obs, deterministic)
            return
        self.model = students.load(None, path)
        self.shapes = (self.model.observation_space.shape, self.model.action_space.shape)
        normalize = checkpoint.observation_normalizer(path)
        self.normalized = normalize is not None
        self._predict = make_predict(self.model, deterministic, normalize)

    def check_env(self, env) -> None:
        """ValueError when `env`'s observations or actions do not fit the model."""
        for what, shape, env_space in (
            ("observations", self.shapes[0], env.observation_space),
            ("actions", self.shapes[1], env.action_space),
        ):
            if tuple(shape) != env_space.shape:
                raise ValueError(
                    f"model {str(self.path)!r} expects {what} of shape {tuple(shape)}; "
                    f"the environment has {env_space.shape} (another env or body?)"
                )

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return self._predict(np.asarray(obs, dtype=np.float32)[None])[0]
