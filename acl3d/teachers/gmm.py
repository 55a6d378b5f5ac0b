"""The machinery ALP-GMM and Covar-GMM share (`GMMTeacherBase`).

Bootstrap, random-task ratio, fitting every `fit_rate` episodes over [normalised task, progress
columns] (the EM is in `acl3d.teachers.mixture_fit`), sampling a Gaussian in proportion to its
progress weight. With `fit_lag` K > 0 a refit runs in a worker process (a thread's EM, small
numpy calls holding the GIL, would slow the step loop as much as fitting inline) and its mixture
is applied exactly K episodes after the fit point, so the step loop never waits for EM and a run
stays reproducible bit for bit (the fit is a pure function of its data and seed). K may exceed
`fit_rate`: thousands of worlds finish 150 episodes faster than one EM runs, so several refits
are then in flight, on several workers, each applied at its own point in fit order.
"""

from __future__ import annotations

import functools
import multiprocessing
import multiprocessing.util
import os
from concurrent.futures import Future, ProcessPoolExecutor
from typing import Any

import numpy as np

from acl3d import validation
from acl3d.teachers.base import Teacher
from acl3d.teachers.mixture_fit import (
    FITNESS,
    GMM_BACKENDS,
    GaussianMixture,
    fit_mixture,
    sklearn_mixture_class,
)

_REFITS: ProcessPoolExecutor | None = None  # the worker processes of every teacher's refits
MAX_FIT_LAG = 10**6  # episodes
REFIT_WORKERS = max(1, min(4, (os.cpu_count() or 2) - 1))


def _refits() -> ProcessPoolExecutor:
    """The refit workers, started on first use: each imports this module while the run goes on
    setting up (a worker's start, about a second, would otherwise stall the first refits)."""
    global _REFITS
    if _REFITS is None:
        context = multiprocessing.get_context("forkserver")
        _REFITS = ProcessPoolExecutor(max_workers=REFIT_WORKERS, mp_context=context)
        for _ in range(REFIT_WORKERS):
            _REFITS.submit(_ready)
        # a process that multiprocessing started (a campaign's attempt) joins its children at
        # exit before the executor's own exit hook would stop them, and hung: stop them first
        multiprocessing.util.Finalize(None, _stop_refits, exitpriority=100)
    return _REFITS


def _ready() -> None:
    """A worker's first task: importing this module is the start-up to get done early."""


def _stop_refits() -> None:
    global _REFITS
    if _REFITS is not None:
        _REFITS.shutdown(wait=True, cancel_futures=True)
        _REFITS = None


def pick_proportional(rng: np.random.Generator, weights: np.ndarray) -> int:
    """Index drawn with probability proportional to non-negative `weights` (uniform if all 0)."""
    cum = np.cumsum(weights)
    if not cum[-1] > 0:
        return int(rng.integers(len(weights)))
    return int(min(np.searchsorted(cum, rng.random() * cum[-1], side="right"), len(cum) - 1))


def pick_many(rng: np.random.Generator, weights: np.ndarray, n: int) -> np.ndarray:
    """`n` indices drawn as `pick_proportional` draws one (one uniform each, vectorised)."""
    cum = np.cumsum(weights)
    if not cum[-1] > 0:
        return rng.integers(len(weights), size=n)
    return np.minimum(np.searchsorted(cum, rng.random(n) * cum[-1], side="right"), len(cum) - 1)


# ---------------------------------------------------------------------- shared GMM-teacher machinery
def check_common_params(
    fit_rate, nb_bootstrap, random_task_ratio, potential_ks, gmm_fitness_func, nb_em_init
):
    """Validate the parameters ALP-GMM and Covar-GMM share; returns (nb_bootstrap, ks)."""
    fit_rate = validation.count("fit_rate", fit_rate, minimum=2)
    nb_bootstrap = fit_rate if nb_bootstrap is None else nb_bootstrap
    nb_bootstrap = validation.count("nb_bootstrap", nb_bootstrap, minimum=0)
    validation.real("random_task_ratio", random_task_ratio, 0.0, 1.0)
    ks_list = (
        list(potential_ks) if isinstance(potential_ks, (list, tuple, range, np.ndarray)) else []
    )
    if not ks_list:
        raise validation.fail("potential_ks", potential_ks, "a non-empty list of integers >= 1")
    ks = [validation.count("potential_ks", k) for k in ks_list]
    if min(ks) > fit_rate:
        raise ValueError(f"potential_ks {ks} all exceed fit_rate {fit_rate} (points per fit)")
    if gmm_fitness_func not in FITNESS:
        raise ValueError(f"gmm_fitness_func must be one of {FITNESS}, got {gmm_fitness_func!r}")
    validation.count("nb_em_init", nb_em_init)
    return int(nb_bootstrap), ks


def check_initial_dist(initial_dist, dim: int):
    """`{"mean": (d,), "variance": (d, d) covariance}` -> (mean, covariance) arrays, or None."""
    if initial_dist is None:
        return None
    try:
        mean = np.asarray(initial_dist["mean"], dtype=np.float64).reshape(dim)
        cov = np.asarray(initial_dist["variance"], dtype=np.float64)
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(
            f"initial_dist must be {{'mean': ({dim},), 'variance': ({dim}, {dim})}}, got {initial_dist!r} ({exc})"
        ) from None
    if cov.ndim == 1 and cov.shape == (dim,):
        cov = np.diag(cov)
    if cov.shape != (dim, dim) or not np.all(np.isfinite(cov)) or not np.all(np.isfinite(mean)):
        raise ValueError(
            f"initial_dist variance must be a finite ({dim}, {dim}) covariance, got shape {cov.shape}"
        )
    eig = np.linalg.eigvalsh((cov + cov.T) / 2)
    if eig.min() < -1e-9 * max(1.0, eig.max()):
        raise ValueError(
            f"initial_dist variance must be positive semi-definite (min eigenvalue {eig.min():g})"
        )
    return mean, cov


class GMMTeacherBase(Teacher):
    """Bootstrap / random / mixture sampling shared by ALP-GMM and Covar-GMM.

    Subclasses fill `self.gmm` (fitted over [normalised active task dims, extra columns]) and define
    `_component_weights()`; the extra columns are dropped when sampling.
    """

    def _init_gmm(
        self,
        fit_rate,
        nb_bootstrap,
        random_task_ratio,
        potential_ks,
        gmm_fitness_func,
        nb_em_init,
        initial_dist,
        gmm_backend,
        fit_lag,
    ):
        if gmm_backend not in GMM_BACKENDS:
            raise ValueError(f"gmm_backend must be one of {GMM_BACKENDS}, got {gmm_backend!r}")
        if gmm_backend == "sklearn":
            sklearn_mixture_class()  # a missing extra fails here, not at the first fit
        self.gmm_backend = gmm_backend
        self.nb_bootstrap, self.potential_ks = check_common_params(
            fit_rate, nb_bootstrap, random_task_ratio, potential_ks, gmm_fitness_func, nb_em_init
        )
        self.fit_rate = int(fit_rate)
        self.fit_lag = validation.integer("fit_lag", fit_lag, 0, MAX_FIT_LAG)
        if self.fit_lag:
            _refits()
        self._in_flight: list[tuple[dict[str, Any], Future]] = []  # (job, its fit), fit order
        self.random_task_ratio = float(random_task_ratio)
        self.gmm_fitness_func = gmm_fitness_func
        self.nb_em_init = int(nb_em_init)
        self.initial_dist = check_initial_dist(initial_dist, self.dim)
        if self.initial_dist is not None:
            self._init_chol = np.linalg.cholesky(self.initial_dist[1] + 1e-12 * np.eye(self.dim))
        self.active = self.maxs > self.mins
        self.span = np.where(self.active, self.maxs - self.mins, 1.0)
        self.d_act = int(self.active.sum())
        self.gmm: GaussianMixture | None = None
        self.r_min, self.r_max = np.inf, -np.inf

    # ------------------------------------------------------------------ coordinates
    def _to_unit(self, task: np.ndarray) -> np.ndarray:
        return ((task - self.mins) / self.span)[self.active]

    def _from_unit(self, unit: np.ndarray) -> np.ndarray:
        task = self.mins.copy()
        task[self.active] = (
            self.mins[self.active] + np.clip(unit, 0.0, 1.0) * self.span[self.active]
        )
        return task

    def _reward_scale(self) -> float:
        span = self.r_max - self.r_min
        return 1.0 / span if span > 0 else 1.0

    # ------------------------------------------------------------------ sampling
    def _sample(self) -> np.ndarray:
        if (
            self.nb_episodes < self.nb_bootstrap
            or self.gmm is None
            or self.rng.random() < self.random_task_ratio
        ):
            if self.nb_episodes < self.nb_bootstrap and self.initial_dist is not None:
                self.bk["tasks_origin"].append(-2)
                mean, _ = self.initial_dist
                return self.clip(mean + self._init_chol @ self.rng.standard_normal(self.dim))
            self.bk["tasks_origin"].append(-1)
            return self.uniform_task()
        index = pick_proportional(self.rng, self._component_weights())
        self.bk["tasks_origin"].append(index)
        return self._from_unit(self.gmm.sample_component(self.rng, index)[: self.d_act])

    def _sample_batch(self, n: int) -> np.ndarray:
        """`_sample` for n tasks with each random quantity drawn for the whole batch."""
        bootstrap = self.nb_episodes < self.nb_bootstrap
        if bootstrap and self.initial_dist is not None:
            self.bk["tasks_origin"].extend([-2] * n)
            z = self.rng.standard_normal((n, self.dim))
            return self.clip(self.initial_dist[0] + z @ self._init_chol.T)
        if bootstrap or self.gmm is None:
            self.bk["tasks_origin"].extend([-1] * n)
            return self.rng.uniform(self.mins, self.maxs, size=(n, self.dim))
        uniform = self.rng.random(n) < self.random_task_ratio
        tasks = np.empty((n, self.dim))
        tasks[uniform] = self.rng.uniform(self.mins, self.maxs, size=(int(uniform.sum()), self.dim))
        picks = pick_many(self.rng, self._component_weights(), n - int(uniform.sum()))
        tasks[~uniform] = self._components_to_tasks(picks)
        origins = np.full(n, -1)
        origins[~uniform] = picks
        self.bk["tasks_origin"].extend(origins.tolist())
        return tasks

    def _components_to_tasks(self, picks: np.ndarray) -> np.ndarray:
        """One draw from each picked component, extra columns dropped, in task units."""
        z = self.rng.standard_normal((len(picks), self.gmm.means.shape[1]))
        units = self.gmm.means[picks] + np.matmul(self.gmm.chol[picks], z[:, :, None])[:, :, 0]
        tasks = np.tile(self.mins, (len(picks), 1))
        act = self.active
        tasks[:, act] = self.mins[act] + np.clip(units[:, : self.d_act], 0.0, 1.0) * self.span[act]
        return tasks

    def _non_exploratory_sample(self) -> np.ndarray:
        if self.gmm is None:
            return self.uniform_task()
        index = pick_proportional(self.rng, self._component_weights())
        return self._from_unit(self.gmm.sample_component(self.rng, index)[: self.d_act])

    def is_non_exploratory_task_sampling_available(self) -> bool:
        return self.gmm is not None

    def _component_weights(self) -> np.ndarray:
        raise NotImplementedError

    def _original_units(self) -> tuple[np.ndarray, np.ndarray]:
        """(scale, offset) per fitted column from the fit's units to the originals' (raw task
        units, raw returns): the sklearn backend fits there, as TeachMyAgent does."""
        raise NotImplementedError

    def _episodes_before_refit_event(self, limit: int) -> int:
        """How many of the next `limit` episodes `_episode_done` would do nothing for (no refit
        to apply, no fit to start)."""
        count = self.nb_episodes + 1  # the next episode's
        first_fit = max(-(-count // self.fit_rate), -(-self.nb_bootstrap // self.fit_rate))
        event = first_fit * self.fit_rate
        if self._in_flight:
            event = min(event, self._in_flight[0][0]["apply_at"])
        return max(0, min(limit, event - count))

    def _episode_done(self, fit_data) -> None:
        """After an episode's book-keeping: apply a refit whose point has come, then start
        one if this episode completes a `fit_rate` batch (`fit_data()`: the points to fit)."""
        count = self.nb_episodes + 1
        while self._in_flight and count >= self._in_flight[0][0]["apply_at"]:
            job, running = self._in_flight.pop(0)
            self._apply(running.result())  # waits only if the worker is not done yet
        if count >= self.nb_bootstrap and count % self.fit_rate == 0:
            self._fit(fit_data())

    def _fit(self, data: np.ndarray) -> None:
        """Fit now (`fit_lag` 0) or in the background, applied `fit_lag` episodes later."""
        job = {
            "data": np.array(data, dtype=np.float64),
            "em_seed": int(self.rng.integers(2**63)),
            "units": self._original_units() if self.gmm_backend == "sklearn" else None,
            "apply_at": self.nb_episodes + 1 + self.fit_lag,
        }
        if self.fit_lag == 0:
            self._apply(self._fit_of(job)())
        else:
            self._in_flight.append((job, _refits().submit(self._fit_of(job))))

    def _fit_of(self, job: dict[str, Any]):
        """The fit of `job` as a picklable call (settings fixed at construction only)."""
        return functools.partial(
            fit_mixture,
            job["data"],
            self.potential_ks,
            job["em_seed"],
            self.gmm_fitness_func,
            self.nb_em_init,
            backend=self.gmm_backend,
            sklearn_seed=self.seed,
            units=job["units"],
        )

    def _apply(self, gmm: GaussianMixture) -> None:
        self.gmm = gmm
        means, covs = self._in_task_units()
        self.bk["weights"].append(self.gmm.weights.copy())
        self.bk["means"].append(means)
        self.bk["covariances"].append(covs)
        self.bk["episodes"].append(self.nb_episodes + 1)

    def _in_task_units(self) -> tuple[np.ndarray, np.ndarray]:
        """The mixture over [task (all d dims, task units), extra columns] (TeachMyAgent's layout)."""
        idx = np.flatnonzero(self.active)
        k, n_extra = self.gmm.k, self.gmm.means.shape[1] - self.d_act
        full = np.concatenate(
            [idx, self.dim + np.arange(n_extra)]
        )  # fitted column -> output column
        scale = np.concatenate([self.span[idx], np.ones(n_extra)])
        means = np.zeros((k, self.dim + n_extra))
        means[:, : self.dim] = self.mins
        means[:, full] = self.gmm.means * scale
        means[:, idx] += self.mins[idx]
        covs = np.zeros((k, self.dim + n_extra, self.dim + n_extra))
        covs[np.ix_(np.arange(k), full, full)] = self.gmm.covariances * np.outer(scale, scale)
        return means, covs

    # ------------------------------------------------------------------ plots
    def plot_state(self) -> dict[str, Any] | None:
        """The mixture over the task dimensions, in task units."""
        if self.gmm is None:
            return None
        means, covs = self._in_task_units()
        return {
            "kind": "gmm",
            "means": means[:, : self.dim],
            "covariances": covs[:, : self.dim, : self.dim],
            "weights": self._component_weights(),
        }

    # ------------------------------------------------------------------ state
    def _gmm_state(self) -> dict[str, Any]:
        return {
            "gmm": None if self.gmm is None else self.gmm.state(),
            "r_min": None if not np.isfinite(self.r_min) else self.r_min,
            "r_max": None if not np.isfinite(self.r_max) else self.r_max,
            "refits": [self._job_state(job) for job, _ in self._in_flight],
        }

    @staticmethod
    def _job_state(job: dict[str, Any]) -> dict[str, Any]:
        units = job["units"]
        return {**job, "units": None if units is None else list(units)}

    def _load_gmm_state(self, extra: dict[str, Any]) -> None:
        g = extra["gmm"]
        self.gmm = (
            None if g is None else GaussianMixture(g["weights"], g["means"], g["covariances"])
        )
        self.r_min = np.inf if extra["r_min"] is None else float(extra["r_min"])
        self.r_max = -np.inf if extra["r_max"] is None else float(extra["r_max"])
        # refits in flight are fitted again from their saved inputs (same results); states of
        # earlier versions hold at most one, as "refit"
        jobs = extra.get("refits", [extra["refit"]] if extra.get("refit") else [])
        self._in_flight = []
        for job in jobs:
            units = None if job["units"] is None else tuple(np.asarray(u) for u in job["units"])
            job = {
                **job,
                "units": units,
                "em_seed": int(job["em_seed"]),
                "apply_at": int(job["apply_at"]),
            }
            self._in_flight.append((job, _refits().submit(self._fit_of(job))))
