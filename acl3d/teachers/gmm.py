"""Gaussian mixtures for the GMM teachers (ALP-GMM, Covar-GMM): a small EM and the shared base.

Same model, initialisation and AIC/BIC as sklearn's GaussianMixture (full covariances, k-means
init over every column, reg_covar 1e-6, tol 1e-3), about 10x less CPU: every EM iteration is two
matrix products over expanded Mahalanobis terms. `gmm_backend="sklearn"` fits with scikit-learn
itself, in the originals' units, to compare with TeachMyAgent (the `sklearn` extra).
`GMMTeacherBase` holds what both teachers share: bootstrap, random-task ratio, fitting every
`fit_rate` episodes over [normalised task, progress columns], sampling a Gaussian in proportion
to its progress weight.
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np

from acl3d import validation
from acl3d.extras import optional_dependency
from acl3d.teachers.base import Teacher

_FITNESS = ("aic", "bic", "aicc")
GMM_BACKENDS = ("acl3d", "sklearn")
_LOG_2PI = math.log(2.0 * math.pi)
_EPS10 = 10.0 * np.finfo(np.float64).eps


# ---------------------------------------------------------------------- Gaussian mixtures
class GaussianMixture:
    """A fitted full-covariance Gaussian mixture (plain arrays, so it saves as JSON + npz)."""

    def __init__(self, weights, means, covariances):
        self.weights = np.asarray(weights, dtype=np.float64)
        self.means = np.asarray(means, dtype=np.float64)
        self.covariances = np.asarray(covariances, dtype=np.float64)
        self._chol = np.linalg.cholesky(self.covariances)

    @property
    def k(self) -> int:
        return len(self.weights)

    def sample_component(self, rng: np.random.Generator, index: int) -> np.ndarray:
        z = rng.standard_normal(self.means.shape[1])
        return self.means[index] + self._chol[index] @ z

    def state(self) -> dict[str, np.ndarray]:
        return {"weights": self.weights, "means": self.means, "covariances": self.covariances}

    def affine(self, scale: np.ndarray, offset: np.ndarray) -> GaussianMixture:
        """The mixture of `x * scale + offset` (per column) for x drawn from this one."""
        return GaussianMixture(
            self.weights,
            self.means * scale + offset,
            self.covariances * np.outer(scale, scale),
        )


def _log_gauss(x2t: np.ndarray, xt: np.ndarray, means: np.ndarray, covs: np.ndarray) -> np.ndarray:
    """log N(x_n | mean_k, cov_k) as a (k, n) array, from x^T (d, n) and its outer products (d*d, n).

    The Mahalanobis terms are expanded (x'Px - 2x'Pm + m'Pm) so the whole E-step is two matrix
    products instead of one small product per component (EM on a few hundred points is call-bound).
    """
    k, d = means.shape
    log_det = 2.0 * np.log(np.diagonal(np.linalg.cholesky(covs), axis1=1, axis2=2)).sum(axis=1)
    prec = np.linalg.inv(covs)
    prec_mean = (prec @ means[:, :, None])[:, :, 0]
    const = (prec_mean * means).sum(axis=1) + log_det + d * _LOG_2PI
    maha = prec.reshape(k, d * d) @ x2t - 2.0 * (prec_mean @ xt)
    return -0.5 * (maha + const[:, None])


def _m_step(x: np.ndarray, x2: np.ndarray, resp: np.ndarray, reg: np.ndarray):
    """Weights, means and regularised covariances from (k, n) responsibilities."""
    nk = resp.sum(axis=1) + _EPS10
    d = x.shape[1]
    means = (resp @ x) / nk[:, None]
    covs = (resp @ x2).reshape(-1, d, d) / nk[:, None, None] - means[:, :, None] * means[:, None, :]
    return nk / x.shape[0], means, covs + reg


def _kmeans_labels(x: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """Cluster labels of k-means as sklearn's GaussianMixture initialises it (init "kmeans").

    Greedy k-means++ seeding (2 + ln k candidates per centre, the one that lowers the total
    squared distance most is kept), then Lloyd iterations until the centres move less than
    1e-4 x the mean column variance (at most 300), over every fitted column. Seeding alone, or
    seeding on the task columns only, leaves clusters that EM shrinks onto a few aligned points
    (e.g. tasks clipped onto a bound): degenerate, line-shaped components.
    """
    n = len(x)
    trials = 2 + int(math.log(k))
    centres = np.empty((k, x.shape[1]))
    centres[0] = x[rng.integers(n)]
    d2 = ((x - centres[0]) ** 2).sum(axis=1)
    for c in range(1, k):
        total = d2.sum()
        if total > 0:
            candidates = np.searchsorted(np.cumsum(d2), rng.random(trials) * total)
            candidates = np.minimum(candidates, n - 1)
        else:
            candidates = rng.integers(n, size=trials)
        to_candidates = ((x[None, :, :] - x[candidates][:, None, :]) ** 2).sum(axis=2)
        closest = np.minimum(d2[None, :], to_candidates)
        best = int(closest.sum(axis=1).argmin())
        centres[c], d2 = x[candidates[best]], closest[best]
    tol = 1e-4 * float(x.var(axis=0).mean())
    ids = np.arange(k)[:, None]
    for _ in range(300):
        labels = ((centres**2).sum(axis=1)[None, :] - 2.0 * x @ centres.T).argmin(axis=1)
        members = (labels[None, :] == ids).astype(np.float64)  # (k, n) one-hot
        counts = members.sum(axis=1, keepdims=True)
        moved = np.where(counts > 0, (members @ x) / np.maximum(counts, 1.0), centres)
        shift = float(((moved - centres) ** 2).sum())
        centres = moved
        if shift <= tol:
            break
    return ((centres**2).sum(axis=1)[None, :] - 2.0 * x @ centres.T).argmin(axis=1)


def fit_gmm(
    x: np.ndarray,
    k: int,
    rng: np.random.Generator,
    *,
    n_init: int = 1,
    max_iter: int = 100,
    tol: float = 1e-3,
    reg_covar: float = 1e-6,
) -> tuple[GaussianMixture, float]:
    """EM for a full-covariance mixture; returns the best of `n_init` runs and its total log-lik.

    Initialised from k-means labels over all columns, as sklearn's GaussianMixture.
    """
    best, best_ll = None, -np.inf
    n = len(x)
    x2 = (x[:, :, None] * x[:, None, :]).reshape(n, -1)
    xt, x2t = np.ascontiguousarray(x.T), np.ascontiguousarray(x2.T)
    reg = reg_covar * np.eye(x.shape[1])
    for _ in range(n_init):
        resp = np.zeros((k, n))
        resp[_kmeans_labels(x, k, rng), np.arange(n)] = 1.0
        weights, means, covs = _m_step(x, x2, resp, reg)
        prev = -np.inf
        for _ in range(max_iter):
            log_p = _log_gauss(x2t, xt, means, covs) + np.log(weights)[:, None]
            top = log_p.max(axis=0)
            log_norm = top + np.log(np.exp(log_p - top).sum(axis=0))
            ll = float(log_norm.mean())
            if abs(ll - prev) < tol:
                break
            prev = ll
            weights, means, covs = _m_step(x, x2, np.exp(log_p - log_norm), reg)
        if ll > best_ll:
            best, best_ll = (weights, means, covs), ll
    return GaussianMixture(*best), best_ll * n


def gmm_fitness(name: str, log_lik: float, k: int, n: int, d: int) -> float:
    """AIC / BIC / AICc of a k-component full-covariance mixture in d dims (lower is better)."""
    n_params = k * (d * (d + 1) / 2 + d + 1) - 1
    if name == "aic":
        return -2.0 * log_lik + 2.0 * n_params
    if name == "bic":
        return -2.0 * log_lik + n_params * math.log(n)
    penalty = (
        2.0 * n_params * (n_params + 1) / (n - n_params - 1) if n - n_params - 1 > 0 else np.inf
    )
    return -2.0 * log_lik + 2.0 * n_params + penalty


def _sklearn_mixture_class():
    """sklearn's GaussianMixture, imported only when the sklearn backend is chosen."""
    with optional_dependency('gmm_backend="sklearn"'):
        from sklearn.mixture import GaussianMixture as SklearnMixture
    return SklearnMixture


def fit_sklearn_gmm(x: np.ndarray, k: int, seed: int, n_init: int = 1):
    """sklearn's fit as the originals call it: full covariances, random_state = the seed."""
    from sklearn.exceptions import ConvergenceWarning
    from threadpoolctl import threadpool_limits

    # one thread: on a few hundred points, OpenMP k-means threads only add overhead (~100x
    # slower on a loaded 2-core machine)
    with warnings.catch_warnings(), threadpool_limits(1):
        warnings.simplefilter("ignore", ConvergenceWarning)
        fit = _sklearn_mixture_class()(
            k, covariance_type="full", random_state=seed, n_init=n_init
        ).fit(x)
    return GaussianMixture(fit.weights_, fit.means_, fit.covariances_), fit.score(x) * len(x)


def fit_best_gmm(
    x, ks, rng, fitness: str, n_init: int, backend: str = "acl3d", seed: int = 0
) -> GaussianMixture:
    """Fit one mixture per k and keep the fittest (k larger than the data size is skipped).

    `backend="sklearn"` fits with scikit-learn's GaussianMixture(random_state=seed) instead of
    the EM above (`rng` is then unused).
    """
    best, best_score = None, np.inf
    for k in ks:
        if k > len(x):
            continue
        if backend == "sklearn":
            gmm, ll = fit_sklearn_gmm(x, int(k), seed, n_init)
        else:
            gmm, ll = fit_gmm(x, int(k), rng, n_init=n_init)
        score = gmm_fitness(fitness, ll, int(k), len(x), x.shape[1])
        if score < best_score:
            best, best_score = gmm, score
    return best


def pick_proportional(rng: np.random.Generator, weights: np.ndarray) -> int:
    """Index drawn with probability proportional to non-negative `weights` (uniform if all 0)."""
    cum = np.cumsum(weights)
    if not cum[-1] > 0:
        return int(rng.integers(len(weights)))
    return int(min(np.searchsorted(cum, rng.random() * cum[-1], side="right"), len(cum) - 1))


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
    if gmm_fitness_func not in _FITNESS:
        raise ValueError(f"gmm_fitness_func must be one of {_FITNESS}, got {gmm_fitness_func!r}")
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
    ):
        if gmm_backend not in GMM_BACKENDS:
            raise ValueError(f"gmm_backend must be one of {GMM_BACKENDS}, got {gmm_backend!r}")
        if gmm_backend == "sklearn":
            _sklearn_mixture_class()  # a missing extra fails here, not at the first fit
        self.gmm_backend = gmm_backend
        self.nb_bootstrap, self.potential_ks = check_common_params(
            fit_rate, nb_bootstrap, random_task_ratio, potential_ks, gmm_fitness_func, nb_em_init
        )
        self.fit_rate = int(fit_rate)
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

    def _fit(self, data: np.ndarray) -> None:
        em_rng = np.random.default_rng(int(self.rng.integers(2**63)))
        if self.gmm_backend == "sklearn":
            scale, offset = self._original_units()
            raw = fit_best_gmm(
                data * scale + offset,
                self.potential_ks,
                em_rng,
                self.gmm_fitness_func,
                self.nb_em_init,
                backend="sklearn",
                seed=self.seed,
            )
            self.gmm = raw.affine(1.0 / scale, -offset / scale)
        else:
            self.gmm = fit_best_gmm(
                data, self.potential_ks, em_rng, self.gmm_fitness_func, self.nb_em_init
            )
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
        }

    def _load_gmm_state(self, extra: dict[str, Any]) -> None:
        g = extra["gmm"]
        self.gmm = (
            None if g is None else GaussianMixture(g["weights"], g["means"], g["covariances"])
        )
        self.r_min = np.inf if extra["r_min"] is None else float(extra["r_min"])
        self.r_max = -np.inf if extra["r_max"] is None else float(extra["r_max"])
