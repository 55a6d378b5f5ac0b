"""Covar-GMM (Moulin-Frier et al. 2014): favour Gaussians where return grows with time.

Every `fit_rate` episodes, mixtures over [task, t, r] (t = position of the episode inside the batch,
in [0, 1)) are fitted for each k in `potential_ks` and the best by AIC is kept. A Gaussian's learning
progress is its time/return covariance, max(0, Cov(t, r)) (or |Cov(t, r)| with `absolute_lp`), and
tasks are drawn from Gaussians chosen in proportion to it, plus `random_task_ratio` uniform tasks.

As in `alp_gmm`, tasks are fitted in [0, 1]-normalised coordinates over non-degenerate dimensions and
returns are mapped to [0, 1] with the range of returns seen so far (TeachMyAgent feeds raw returns,
which would let the return axis dominate the fit); `gmm_backend="sklearn"` fits with scikit-learn
in raw task units and raw returns, as the originals.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from acl3d.teachers import histories
from acl3d.teachers.gmm import GMMTeacherBase


class CovarGMM(GMMTeacherBase):
    """Covariance-based learning-progress mixture teacher (defaults: TeachMyAgent benchmark)."""

    name = "covar-gmm"
    uses_initial_dist = True

    @classmethod
    def plot_history(cls, bk, low, high, steps):
        """The fitted mixtures, coloured by weight."""
        return histories.mixtures(bk, len(low), by_alp=False)

    def __init__(
        self,
        task_space,
        seed: int | None = None,
        *,
        fit_rate: int = 150,
        nb_bootstrap: int | None = None,
        random_task_ratio: float = 0.10,
        potential_ks=tuple(range(2, 15)),
        gmm_fitness_func: str = "aic",
        nb_em_init: int = 1,
        absolute_lp: bool = False,
        initial_dist: dict | None = None,
        gmm_backend: str = "acl3d",
        fit_lag: int = 0,
    ):
        super().__init__(task_space, seed)
        self._init_gmm(
            fit_rate,
            nb_bootstrap,
            random_task_ratio,
            potential_ks,
            gmm_fitness_func,
            nb_em_init,
            initial_dist,
            gmm_backend,
            fit_lag,
        )
        self.absolute_lp = bool(absolute_lp)
        self.tasks_unit: list[np.ndarray] = []  # the last fit_rate normalised tasks
        self.times: list[float] = []
        self.rewards: list[float] = []

    def _episodic_update(self, task: np.ndarray, reward: float, is_success: bool) -> None:
        self.r_min, self.r_max = min(self.r_min, reward), max(self.r_max, reward)
        self.tasks_unit.append(self._to_unit(task))
        self.times.append((self.nb_episodes % self.fit_rate) / self.fit_rate)
        self.rewards.append(reward)
        del (
            self.tasks_unit[: -self.fit_rate],
            self.times[: -self.fit_rate],
            self.rewards[: -self.fit_rate],
        )
        self._episode_done(
            lambda: np.column_stack(
                [
                    np.asarray(self.tasks_unit),
                    self.times,
                    (np.asarray(self.rewards) - self.r_min) * self._reward_scale(),
                ]
            )
        )

    def _component_weights(self) -> np.ndarray:
        cov_tr = self.gmm.covariances[:, -2, -1]
        return np.abs(cov_tr) if self.absolute_lp else np.maximum(cov_tr, 0.0)

    def _original_units(self) -> tuple[np.ndarray, np.ndarray]:
        active = self.active
        scale = np.append(self.span[active], [1.0, 1.0 / self._reward_scale()])
        return scale, np.append(self.mins[active], [0.0, self.r_min])

    def _extra_state(self) -> dict[str, Any]:
        return {
            **self._gmm_state(),
            "tasks_unit": np.asarray(self.tasks_unit).reshape(len(self.rewards), self.d_act),
            "times": list(self.times),
            "rewards": list(self.rewards),
        }

    def _load_extra_state(self, extra: dict[str, Any]) -> None:
        self._load_gmm_state(extra)
        self.tasks_unit = list(
            np.asarray(extra["tasks_unit"], dtype=np.float64).reshape(
                len(extra["rewards"]), self.d_act
            )
        )
        self.times = [float(t) for t in extra["times"]]
        self.rewards = [float(r) for r in extra["rewards"]]
