"""Full-covariance Gaussian mixtures fitted by a small EM, for the GMM teachers.

Same model, initialisation and AIC/BIC as sklearn's GaussianMixture (full covariances, k-means
init over every column, reg_covar 1e-6, tol 1e-3), about 10x less CPU: every EM iteration is two
matrix products over expanded Mahalanobis terms. `backend="sklearn"` fits with scikit-learn
itself, to compare with TeachMyAgent (the `sklearn` extra). Pure functions of their inputs and
seed, so a fit may run in another thread and still give the same mixture.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from acl3d.extras import optional_dependency

FITNESS = ("aic", "bic", "aicc")
GMM_BACKENDS = ("acl3d", "sklearn")
_LOG_2PI = math.log(2.0 * math.pi)
_EPS10 = 10.0 * np.finfo(np.float64).eps


class GaussianMixture:
    """A fitted full-covariance Gaussian mixture (plain arrays, so it saves as JSON + npz)."""

    def __init__(self, weights, means, covariances):
        self.weights = np.asarray(weights, dtype=np.float64)
        self.means = np.asarray(means, dtype=np.float64)
        self.covariances = np.asarray(covariances, dtype=np.float64)
        self.chol = np.linalg.cholesky(self.covariances)

    @property
    def k(self) -> int:
        return len(self.weights)

    def sample_component(self, rng: np.random.Generator, index: int) -> np.ndarray:
        z = rng.standard_normal(self.means.shape[1])
        return self.means[index] + self.chol[index] @ z

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


def sklearn_mixture_class():
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
        fit = sklearn_mixture_class()(
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


def fit_mixture(
    data: np.ndarray,
    ks,
    em_seed: int,
    fitness: str,
    n_init: int,
    *,
    backend: str = "acl3d",
    sklearn_seed: int = 0,
    units: tuple[np.ndarray, np.ndarray] | None = None,
) -> GaussianMixture:
    """The fittest mixture of `data` over `ks`, from an EM seeded with `em_seed`; the sklearn
    backend fits in `units` ((scale, offset) per column: the originals' units) with
    random_state `sklearn_seed` and maps the result back. A pure function of its arguments."""
    em_rng = np.random.default_rng(em_seed)
    if backend != "sklearn":
        return fit_best_gmm(data, ks, em_rng, fitness, n_init)
    scale, offset = units
    raw = fit_best_gmm(
        data * scale + offset, ks, em_rng, fitness, n_init, backend="sklearn", seed=sklearn_seed
    )
    return raw.affine(1.0 / scale, -offset / scale)
