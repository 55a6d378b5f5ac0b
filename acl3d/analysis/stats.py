"""The statistics of a benchmark, with rliable's definitions and TeachMyAgent's test.

Scores of one condition are a list of 1-D arrays, one per task (a task: one environment /
criterion / expert-knowledge cell), each holding the score of every run of that cell; cells
may hold different numbers of runs.

* IQM: mean of the middle 50% of all scores pooled (`scipy.stats.trim_mean(x, 0.25)`).
* Mean: mean of all scores pooled.
* Stratified bootstrap (rliable's CIs): each replicate resamples, with replacement, the runs
  of every task separately; the 95% CI is the 2.5th and 97.5th percentiles of the replicates.
* Probability of improvement P(X > Y): per task, the Mann-Whitney U statistic over m·n (ties
  count one half), averaged over tasks; its CI resamples X and Y independently per task.
* Performance profile: for each threshold tau, the fraction of runs scoring above tau,
  averaged over tasks.
* Welch's t-test: `scipy.stats.ttest_ind(x, y, equal_var=False)`, p < 0.05 (TeachMyAgent).
* Holm's step-down correction of a family of p-values (the comparisons one table shows): a
  claim holds when its adjusted p < 0.05, whatever the number of teachers compared.
* Mann-Whitney U (two-sided; exact without ties): a rank test that assumes no normality. With
  4 runs against 4 its p cannot go below 2/70 = 0.029, so few seeds cannot carry many claims.
* Seeds needed: the smallest number of runs per side at which a two-sided t-test at 0.05 would
  reach 80% power for the observed effect (Cohen's d, pooled SD), from the noncentral t; and
  the same at `family_alpha`, 0.05 over the number of comparisons, where a p passes Holm's
  correction whatever the other p-values are (the level a claim in a table of many needs).
* P(improvement) needs `MIN_RUNS` runs on each side; with fewer it reads `INSUFFICIENT`.

Computed with numpy/scipy rather than by importing rliable, because rliable 1.2.0 only imports
with pandas<3 and arch<8; the definitions are rliable's and every function takes a seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats as sps

DEFAULT_REPS = 20_000
CONFIDENCE = 0.95


@dataclass(frozen=True)
class Interval:
    point: float
    low: float
    high: float

    def text(self, spec: str = ".3g") -> str:
        """'point [low, high]'; 'point [no CI]' where the bounds are undefined (one run)."""
        if not (np.isfinite(self.low) and np.isfinite(self.high)):
            return f"{self.point:{spec}} [no CI]"
        return f"{self.point:{spec}} [{self.low:{spec}}, {self.high:{spec}}]"

    def __str__(self) -> str:
        return self.text()


def _tasks(scores) -> list[np.ndarray]:
    tasks = [np.asarray(t, dtype=np.float64).ravel() for t in scores]
    if not tasks or any(t.size == 0 for t in tasks):
        raise ValueError("scores must hold at least one run for every task")
    return tasks


def iqm(values, axis=None):
    """Interquartile mean: the mean of the middle 50% (25% trimmed from each end)."""
    return sps.trim_mean(np.asarray(values, dtype=np.float64), 0.25, axis=axis)


def mean(values, axis=None):
    return np.mean(np.asarray(values, dtype=np.float64), axis=axis)


AGGREGATES = {"IQM": iqm, "mean": mean}


def _percentiles(replicates: np.ndarray) -> tuple[float, float]:
    alpha = 100 * (1 - CONFIDENCE) / 2
    low, high = np.percentile(replicates, [alpha, 100 - alpha])
    return float(low), float(high)


def _resample(tasks: list[np.ndarray], reps: int, rng: np.random.Generator) -> np.ndarray:
    """(reps, total runs): every replicate resamples each task's runs within that task."""
    parts = [t[rng.integers(0, t.size, size=(reps, t.size))] for t in tasks]
    return np.concatenate(parts, axis=1)


def aggregate_interval(scores, func=iqm, reps: int = DEFAULT_REPS, seed: int = 0) -> Interval:
    """`func` of the pooled scores with its stratified-bootstrap 95% CI; NaN bounds when every
    task holds a single run (each replicate would give that run back: a CI of zero width that
    reads as certainty)."""
    tasks = _tasks(scores)
    rng = np.random.default_rng(seed)
    point = float(func(np.concatenate(tasks)))
    if all(t.size == 1 for t in tasks):
        return Interval(point, float("nan"), float("nan"))
    replicates = func(_resample(tasks, reps, rng), axis=1)
    return Interval(point, *_percentiles(replicates))


def _poi_task(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """P(X > Y) + P(X = Y)/2 over the last axis pairs; x (..., m), y (..., n)."""
    diff = x[..., :, None] - y[..., None, :]
    return ((diff > 0) + 0.5 * (diff == 0)).mean(axis=(-2, -1))


def probability_of_improvement(
    scores_x, scores_y, reps: int = DEFAULT_REPS, seed: int = 0
) -> Interval:
    """P(a run of X beats a run of Y on the same task), averaged over tasks, with its CI."""
    xs, ys = _tasks(scores_x), _tasks(scores_y)
    if len(xs) != len(ys):
        raise ValueError(f"X has {len(xs)} tasks and Y {len(ys)}: they must match")
    rng = np.random.default_rng(seed)
    point = float(np.mean([_poi_task(x, y) for x, y in zip(xs, ys)]))
    replicates = np.zeros(reps)
    for x, y in zip(xs, ys):
        bx = x[rng.integers(0, x.size, size=(reps, x.size))]
        by = y[rng.integers(0, y.size, size=(reps, y.size))]
        replicates += _poi_task(bx, by)
    replicates /= len(xs)
    return Interval(point, *_percentiles(replicates))


def performance_profile(
    scores, taus, reps: int = 2_000, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fraction of runs above each tau (averaged over tasks), with 95% bootstrap bands."""
    tasks = _tasks(scores)
    taus = np.asarray(taus, dtype=np.float64)
    rng = np.random.default_rng(seed)

    def profile(task_arrays) -> np.ndarray:  # (..., n) arrays -> (..., len(taus))
        per_task = [(t[..., None] > taus).mean(axis=-2) for t in task_arrays]
        return np.mean(per_task, axis=0)

    point = profile(tasks)
    boot = profile([t[rng.integers(0, t.size, size=(reps, t.size))] for t in tasks])
    alpha = 100 * (1 - CONFIDENCE) / 2
    low, high = np.percentile(boot, [alpha, 100 - alpha], axis=0)
    return point, low, high


def mean_band(values, reps: int = DEFAULT_REPS, seed: int = 0) -> Interval:
    """Mean over runs with a 95% percentile-bootstrap CI (resampling runs)."""
    values = np.asarray(values, dtype=np.float64).ravel()
    if values.size == 0:
        raise ValueError("mean_band needs at least one value")
    rng = np.random.default_rng(seed)
    replicates = values[rng.integers(0, values.size, size=(reps, values.size))].mean(axis=1)
    return Interval(float(values.mean()), *_percentiles(replicates))


@dataclass(frozen=True)
class Welch:
    t: float
    p: float

    @property
    def significant(self) -> bool:
        return bool(np.isfinite(self.p) and self.p < 0.05)


def welch(x, y) -> Welch:
    """Welch's t-test of X against Y; NaN when undefined (fewer than 2 runs, zero variance)."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    if x.size < 2 or y.size < 2 or (np.ptp(x) == 0 and np.ptp(y) == 0):
        return Welch(float("nan"), float("nan"))
    result = sps.ttest_ind(x, y, equal_var=False)
    return Welch(float(result.statistic), float(result.pvalue))


MIN_RUNS = 3  # runs per side below which P(improvement) is not reported
INSUFFICIENT = "insufficient runs"
ALPHA = 0.05


def enough_runs(*samples) -> bool:
    """Whether every sample holds at least `MIN_RUNS` runs (P(improvement) is meaningful)."""
    return all(np.asarray(s).size >= MIN_RUNS for s in samples)


def holm(pvalues) -> np.ndarray:
    """Holm-adjusted p-values of a family, in the input order; NaN entries (undefined tests)
    stay NaN and do not count in the family."""
    p = np.asarray(pvalues, dtype=np.float64).ravel()
    out = np.full(p.shape, np.nan)
    defined = np.flatnonzero(np.isfinite(p))
    order = defined[np.argsort(p[defined], kind="stable")]
    m, running = order.size, 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p[i]))
        out[i] = running
    return out


@dataclass(frozen=True)
class RankTest:
    u: float
    p: float


def mann_whitney(x, y) -> RankTest:
    """Two-sided Mann-Whitney U test of X against Y (exact for small samples without ties);
    NaN when undefined (an empty side, or every value equal)."""
    x, y = np.asarray(x, dtype=np.float64).ravel(), np.asarray(y, dtype=np.float64).ravel()
    if x.size == 0 or y.size == 0 or np.ptp(np.concatenate([x, y])) == 0:
        return RankTest(float("nan"), float("nan"))
    result = sps.mannwhitneyu(x, y, alternative="two-sided", method="auto")
    return RankTest(float(result.statistic), float(result.pvalue))


def family_alpha(pvalues) -> float:
    """`ALPHA` over the number of defined tests of a family: a p below it passes Holm's
    correction whatever the family's other p-values (Holm asks exactly this of the smallest)."""
    defined = int(np.isfinite(np.asarray(pvalues, dtype=np.float64)).sum())
    return ALPHA / max(defined, 1)


def seeds_needed(x, y, power: float = 0.8, alpha: float = ALPHA, limit: int = 100_000) -> float:
    """Runs per side for a two-sided t-test at `alpha` to reach `power` for the effect observed
    between X and Y (Cohen's d with the pooled SD); inf for no effect or beyond `limit`, NaN when
    undefined (fewer than 2 runs on a side, or no spread at all)."""
    x, y = np.asarray(x, dtype=np.float64).ravel(), np.asarray(y, dtype=np.float64).ravel()
    if x.size < 2 or y.size < 2:
        return float("nan")
    pooled = np.sqrt(
        ((x.size - 1) * x.var(ddof=1) + (y.size - 1) * y.var(ddof=1)) / (x.size + y.size - 2)
    )
    if pooled == 0:
        return float("nan")
    d = abs(x.mean() - y.mean()) / pooled
    if d == 0:
        return float("inf")

    def reached(n: int) -> bool:
        df, shift = 2 * n - 2, d * np.sqrt(n / 2)
        crit = sps.t.ppf(1 - alpha / 2, df)
        achieved = sps.nct.sf(crit, df, shift) + sps.nct.cdf(-crit, df, shift)
        if not np.isfinite(achieved):  # scipy's noncentral t fails at large df: normal limit
            achieved = sps.norm.sf(crit - shift) + sps.norm.cdf(-crit - shift)
        return bool(achieved >= power)

    high = 2
    while not reached(high):  # doubling, then bisection: power grows with n
        if high >= limit:
            return float("inf")
        high = min(2 * high, limit)
    low = max(2, high // 2)
    while low < high:
        mid = (low + high) // 2
        low, high = (low, mid) if reached(mid) else (mid + 1, high)
    return float(low)
