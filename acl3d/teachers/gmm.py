"""Gaussian mixtures for the GMM teachers (ALP-GMM, Covar-GMM): a small EM and the shared base.

Same model and AIC/BIC as sklearn's GaussianMixture (full covariances, k-means++ init, reg_covar),
about 10x less CPU: every EM iteration is two matrix products over expanded Mahalanobis terms.
`GMMTeacherBase` holds what both teachers share: bootstrap, random-task ratio, fitting every
`fit_rate` episodes over [normalised task, progress columns], sampling a Gaussian in proportion
to its progress weight.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from acl3d import validation
from acl3d.teachers.base import Teacher

_FITNESS = ("aic", "bic", "aicc")
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


def _kmeanspp_resp(x: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """Hard responsibilities from k-means++ seeding (sklearn's "k-means++" initialisation)."""
    n = x.shape[0]
    centres = [x[rng.integers(n)]]
    d2 = ((x - centres[0]) ** 2).sum(axis=1)
    for _ in range(1, k):
        total = d2.sum()
        i = (
            int(np.searchsorted(np.cumsum(d2), rng.random() * total))
            if total > 0
            else rng.integers(n)
        )
        centres.append(x[min(i, n - 1)])
        d2 = np.minimum(d2, ((x - centres[-1]) ** 2).sum(axis=1))
    dist = ((x[:, None, :] - np.asarray(centres)[None, :, :]) ** 2).sum(axis=2)
    resp = np.zeros((n, k))
    resp[np.arange(n), dist.argmin(axis=1)] = 1.0
    return resp


def fit_gmm(
    x: np.ndarray,
    k: int,
    rng: np.random.Generator,
    *,
    n_init: int = 1,
    max_iter: int = 100,
    tol: float = 1e-3,
    reg_covar: float = 1e-6,
    seed_columns=None,
) -> tuple[GaussianMixture, float]:
    """EM for a full-covariance mixture; returns the best of `n_init` runs and its total log-lik.

    `seed_columns` (indices, default all) are the columns the k-means++ seeding looks at: EM
    itself is invariant to each column's scale, the Euclidean seeding is not.
    """
    best, best_ll = None, -np.inf
    x2 = (x[:, :, None] * x[:, None, :]).reshape(len(x), -1)
    xt, x2t = np.ascontiguousarray(x.T), np.ascontiguousarray(x2.T)
    reg = reg_covar * np.eye(x.shape[1])
    x_seed = x if seed_columns is None else x[:, seed_columns]
    for _ in range(n_init):
        weights, means, covs = _m_step(x, x2, _kmeanspp_resp(x_seed, k, rng).T, reg)
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
    return GaussianMixture(*best), best_ll * x.shape[0]


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


def fit_best_gmm(x, ks, rng, fitness: str, n_init: int, seed_columns=None) -> GaussianMixture:
    """Fit one mixture per k and keep the fittest (k larger than the data size is skipped)."""
    best, best_score = None, np.inf
    for k in ks:
        if k > len(x):
            continue
        gmm, ll = fit_gmm(x, int(k), rng, n_init=n_init, seed_columns=seed_columns)
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
    ):
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

    def _seed_columns(self, n_columns: int) -> np.ndarray:
        """Columns the k-means++ seeding of each fit uses (see the subclasses for why)."""
        return np.arange(n_columns)

    def _fit(self, data: np.ndarray) -> None:
        em_rng = np.random.default_rng(int(self.rng.integers(2**63)))
        self.gmm = fit_best_gmm(
            data,
            self.potential_ks,
            em_rng,
            self.gmm_fitness_func,
            self.nb_em_init,
            self._seed_columns(data.shape[1]),
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
