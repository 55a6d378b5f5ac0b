"""ALP-GMM (Portelas et al., CoRL 2019): sample tasks from Gaussians fitted where progress is.

Every episode gets an absolute learning progress ALP = |r - r_nn|, where r_nn is the return of the
nearest earlier task. Every `fit_rate` episodes, Gaussian mixtures over [task, ALP] are fitted for
each k in `potential_ks` and the best one by AIC is kept; tasks are then drawn from a Gaussian
chosen in proportion to its mean ALP, plus a `random_task_ratio` of uniform tasks.

Differences from the originals (why): tasks are handled in [0, 1]-normalised coordinates over the
non-degenerate dimensions only, and the ALP coordinate is divided by the range of returns seen so
far, so the fit neither depends on the units of the task dimensions or of the returns (TeachMyAgent
feeds raw returns) nor breaks on constant dimensions. The mixtures are fitted by the small EM in
acl3d.teachers.gmm (same model, k-means initialisation and AIC as sklearn's GaussianMixture, about
10x less CPU); `gmm_backend="sklearn"` fits with scikit-learn in raw task units and raw ALPs, as
the originals (the nearest-neighbour ALP still uses normalised coordinates).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from acl3d.teachers import histories
from acl3d.teachers.gmm import GMMTeacherBase


# ---------------------------------------------------------------------- nearest-neighbour ALP
class NearestNeighbourALP:
    """ALP = |r - r_nn| against the nearest earlier task: a kd-tree plus a brute-force buffer.

    The tree is rebuilt only when the buffer holds `buffer_size` points, so each query costs one
    tree lookup and one small vectorised scan. With `max_size`, the oldest points are dropped when
    the tree is rebuilt (so up to `buffer_size` extra old points may be consulted in between).
    """

    def __init__(self, dim: int, buffer_size: int = 500, max_size: int | None = None):
        self.buffer_size, self.max_size = buffer_size, max_size
        self.tasks = np.zeros((max(1024, buffer_size), dim))
        self.rewards = np.zeros(len(self.tasks))
        self.n = 0
        self.tree_start = self.tree_end = 0
        self.tree: cKDTree | None = None

    def compute(self, task: np.ndarray, reward: float) -> float:
        """ALP of (task, reward) against the database, then add the pair to it."""
        alp = 0.0
        if self.n > 5:
            best_d, best_i = np.inf, -1
            if self.tree is not None:
                best_d, j = self.tree.query(task)
                best_i = self.tree_start + int(j)
            buf = self.tasks[self.tree_end : self.n]
            if len(buf):
                d = ((buf - task) ** 2).sum(axis=1)
                j = int(d.argmin())
                if math.sqrt(d[j]) < best_d:
                    best_i = self.tree_end + j
            alp = abs(reward - self.rewards[best_i])
        self._add(task, reward)
        return alp

    def compute_batch(self, tasks: np.ndarray, rewards: np.ndarray) -> np.ndarray:
        """`compute` of M pairs in order, in a few array operations per part of the batch that
        no tree rebuild interrupts (the pair whose storing rebuilds the tree ends a part, so a
        `max_size` drops old points exactly where M calls would drop them): each task's nearest
        earlier task is the tree's, or the buffer's (the stored points after the tree, then the
        part's earlier tasks) when strictly closer, with the squared distances and first-index
        ties `compute` uses."""
        alps, start = np.zeros(len(tasks)), 0
        while start < len(tasks):
            stop = min(len(tasks), start + max(1, self.tree_end + self.buffer_size - self.n))
            alps[start:stop] = self._compute_part(tasks[start:stop], rewards[start:stop])
            start = stop
        return alps

    def _compute_part(self, tasks: np.ndarray, rewards: np.ndarray) -> np.ndarray:
        m, alps = len(tasks), np.zeros(len(tasks))
        if m == 0:
            return alps
        order = np.arange(m)
        best_d, best_r = np.full(m, np.inf), np.zeros(m)
        if self.tree is not None:
            best_d, j = self.tree.query(tasks)
            best_r = self.rewards[self.tree_start + j]
        # the buffer's nearest: stored points first, then the part's earlier tasks (argmin's
        # first index wins a tie, as over `compute`'s one buffer array)
        buf_d2, buf_r = np.full(m, np.inf), np.zeros(m)
        stored = self.tasks[self.tree_end : self.n]
        if len(stored):
            d2 = ((tasks[:, None, :] - stored[None]) ** 2).sum(axis=2)
            j = d2.argmin(axis=1)
            buf_d2, buf_r = d2[order, j], self.rewards[self.tree_end + j]
        d2 = ((tasks[:, None, :] - tasks[None]) ** 2).sum(axis=2)
        d2[order[:, None] <= order] = np.inf  # only the part's earlier tasks
        j = d2.argmin(axis=1)
        nearer = d2[order, j] < buf_d2
        buf_d2, buf_r = np.where(nearer, d2[order, j], buf_d2), np.where(nearer, rewards[j], buf_r)
        best_r = np.where(np.sqrt(buf_d2) < best_d, buf_r, best_r)
        known = self.n + order > 5  # `compute` scores a pair once 6 are known
        alps[known] = np.abs(rewards - best_r)[known]
        self._add_many(tasks, rewards)
        return alps

    def _add_many(self, tasks: np.ndarray, rewards: np.ndarray) -> None:
        """`_add` of each pair of a part in order: the points stored at once, the tree rebuilt
        if the last one completes the buffer (no earlier one does: see `compute_batch`)."""
        end = self.n + len(tasks)
        if end > len(self.tasks):
            grown = max(end, 2 * len(self.tasks))
            self.tasks = np.concatenate(
                [self.tasks, np.zeros((grown - len(self.tasks), self.tasks.shape[1]))]
            )
            self.rewards = np.concatenate([self.rewards, np.zeros(grown - len(self.rewards))])
        self.tasks[self.n : end], self.rewards[self.n : end] = tasks, rewards
        self.n = end
        if self.n - self.tree_end >= self.buffer_size:
            self._rebuild()

    def _add(self, task, reward) -> None:
        if self.n == len(self.tasks):
            self.tasks = np.concatenate([self.tasks, np.zeros_like(self.tasks)])
            self.rewards = np.concatenate([self.rewards, np.zeros_like(self.rewards)])
        self.tasks[self.n], self.rewards[self.n] = task, reward
        self.n += 1
        if self.n - self.tree_end >= self.buffer_size:
            self._rebuild()

    def _rebuild(self) -> None:
        self.tree_end = self.n
        if self.max_size is not None:
            self.tree_start = max(self.tree_start, self.n - self.max_size)
        self.tree = (
            cKDTree(self.tasks[self.tree_start : self.tree_end])
            if self.tree_end > self.tree_start
            else None
        )

    def state(self) -> dict[str, Any]:
        return {
            "tasks": self.tasks[: self.n].copy(),
            "rewards": self.rewards[: self.n].copy(),
            "tree_start": self.tree_start,
            "tree_end": self.tree_end,
        }

    def load(self, s: dict[str, Any]) -> None:
        tasks = np.asarray(s["tasks"], dtype=np.float64).reshape(
            len(s["rewards"]), self.tasks.shape[1]
        )
        self.n = len(tasks)
        cap = max(1024, self.buffer_size, 2 * self.n)
        self.tasks = np.zeros((cap, tasks.shape[1]))
        self.rewards = np.zeros(cap)
        self.tasks[: self.n], self.rewards[: self.n] = (
            tasks,
            np.asarray(s["rewards"], dtype=np.float64),
        )
        self.tree_start, self.tree_end = int(s["tree_start"]), int(s["tree_end"])
        self.tree = (
            cKDTree(self.tasks[self.tree_start : self.tree_end])
            if self.tree_end > self.tree_start
            else None
        )


# ---------------------------------------------------------------------- the teacher
class ALPGMM(GMMTeacherBase):
    """Absolute-learning-progress Gaussian mixture teacher (defaults: TeachMyAgent benchmark)."""

    name = "alp-gmm"
    uses_initial_dist = True

    @classmethod
    def plot_history(cls, bk, low, high, steps):
        """The fitted mixtures, coloured by ALP (as it samples)."""
        return histories.mixtures(bk, len(low), by_alp=True)

    def __init__(
        self,
        task_space,
        seed: int | None = None,
        *,
        fit_rate: int = 150,
        nb_bootstrap: int | None = None,
        random_task_ratio: float = 0.05,
        potential_ks=tuple(range(2, 10)),
        gmm_fitness_func: str = "aic",
        nb_em_init: int = 1,
        alp_buffer_size: int = 500,
        alp_max_size: int | None = None,
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
        if not isinstance(alp_buffer_size, (int, np.integer)) or alp_buffer_size < 1:
            raise ValueError(f"alp_buffer_size must be an integer >= 1, got {alp_buffer_size!r}")
        if alp_max_size is not None and (
            not isinstance(alp_max_size, (int, np.integer)) or alp_max_size < 1
        ):
            raise ValueError(f"alp_max_size must be None or an integer >= 1, got {alp_max_size!r}")
        self.alp_computer = NearestNeighbourALP(self.d_act, int(alp_buffer_size), alp_max_size)
        self.tasks_unit: list[np.ndarray] = []  # the last fit_rate normalised tasks
        self.raw_alps: list[float] = []  # their ALPs in return units

    def _episodic_update(self, task: np.ndarray, reward: float, is_success: bool) -> None:
        unit = self._to_unit(task)
        self._book_episode(unit, reward, self.alp_computer.compute(unit, reward))

    def _book_episode(self, unit: np.ndarray, reward: float, alp: float) -> None:
        self.r_min, self.r_max = min(self.r_min, reward), max(self.r_max, reward)
        self.tasks_unit.append(unit)
        self.raw_alps.append(alp)
        del self.tasks_unit[: -self.fit_rate], self.raw_alps[: -self.fit_rate]
        self.bk["tasks_alps"].append(alp)
        self._episode_done(
            lambda: np.hstack(
                [
                    np.asarray(self.tasks_unit),
                    np.asarray(self.raw_alps)[:, None] * self._reward_scale(),
                ]
            )
        )

    def _update_batch(self, tasks: np.ndarray, returns: np.ndarray, successes: np.ndarray):
        """The episodes' ALPs in one batched neighbour search, then their book-keeping in bulk
        between refit events (a fit or a refit's application, done at its own episode); equal
        to the episodes one by one."""
        units = ((tasks - self.mins) / self.span)[:, self.active]
        alps = self.alp_computer.compute_batch(units, returns.astype(np.float64)).tolist()
        rewards, j = returns.tolist(), 0
        while j < len(units):
            quiet = self._episodes_before_refit_event(len(units) - j)
            if quiet:  # the episodes between refit events: book-keeping in bulk
                end = j + quiet
                self.r_min = min(self.r_min, min(rewards[j:end]))
                self.r_max = max(self.r_max, max(rewards[j:end]))
                self.tasks_unit.extend(units[j:end])
                self.raw_alps.extend(alps[j:end])
                del self.tasks_unit[: -self.fit_rate], self.raw_alps[: -self.fit_rate]
                self.bk["tasks_alps"].extend(alps[j:end])
                self.nb_episodes, j = self.nb_episodes + quiet, end
            if j < len(units):  # the episode of a refit event, as one
                self._book_episode(units[j], rewards[j], alps[j])
                self.nb_episodes, j = self.nb_episodes + 1, j + 1

    def _component_weights(self) -> np.ndarray:
        return np.maximum(self.gmm.means[:, -1], 0.0)

    def _original_units(self) -> tuple[np.ndarray, np.ndarray]:
        active = self.active
        scale = np.append(self.span[active], 1.0 / self._reward_scale())
        return scale, np.append(self.mins[active], 0.0)

    def _extra_state(self) -> dict[str, Any]:
        return {
            **self._gmm_state(),
            "alp": self.alp_computer.state(),
            "tasks_unit": np.asarray(self.tasks_unit).reshape(len(self.raw_alps), self.d_act),
            "raw_alps": list(self.raw_alps),
        }

    def _load_extra_state(self, extra: dict[str, Any]) -> None:
        self._load_gmm_state(extra)
        self.alp_computer.load(extra["alp"])
        self.tasks_unit = list(
            np.asarray(extra["tasks_unit"], dtype=np.float64).reshape(
                len(extra["raw_alps"]), self.d_act
            )
        )
        self.raw_alps = [float(a) for a in extra["raw_alps"]]
