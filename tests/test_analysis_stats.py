"""The statistics against values computed by hand (and Welch's test against scipy's)."""

import math

import numpy as np
import pytest
from scipy import stats as sps

from acl3d.analysis import stats


def test_iqm_and_mean():
    assert stats.iqm([8, 1, 7, 2, 6, 3, 5, 4]) == pytest.approx(4.5)  # mean of 3, 4, 5, 6
    assert stats.iqm([0, 0, 10, 100]) == pytest.approx(5.0)  # mean of 0, 10
    assert stats.mean([1, 2, 6]) == pytest.approx(3.0)


def test_stratified_bootstrap_ci_bounds():
    # Task A always resamples to [0, 0]; task B's pair [1, 3] resamples to {1,1}, {1,3}, {3,1},
    # {3,3}: the pooled mean is 0.5, 1 or 1.5 with probabilities 1/4, 1/2, 1/4, so the 95% CI
    # is exactly [0.5, 1.5]. (Pooled resampling would also reach 0 and 2.25.)
    interval = stats.aggregate_interval([[0, 0], [1, 3]], stats.mean, reps=4000, seed=7)
    assert (interval.point, interval.low, interval.high) == (1.0, 0.5, 1.5)
    same = stats.aggregate_interval([[0, 0], [1, 3]], stats.mean, reps=4000, seed=7)
    assert same == interval  # a fixed seed gives the same bounds
    constant = stats.aggregate_interval([[5, 5, 5]], stats.iqm, reps=500, seed=0)
    assert (constant.point, constant.low, constant.high) == (5.0, 5.0, 5.0)


def test_probability_of_improvement():
    # x=1 beats 0 only (1/3); x=2 ties twice and beats 0 (2/3); x=3 beats all (3/3): 6/9.
    poi = stats.probability_of_improvement([[1, 2, 3]], [[2, 2, 0]], reps=2000, seed=0)
    assert poi.point == pytest.approx(6 / 9)
    assert 0 <= poi.low <= poi.point <= poi.high <= 1
    # averaged over tasks: 1 on the first (always better), 0.5 on the second (all ties)
    two = stats.probability_of_improvement([[5, 6], [1, 1]], [[0, 1], [1, 1]], reps=500, seed=0)
    assert (two.point, two.low, two.high) == (0.75, 0.75, 0.75)
    with pytest.raises(ValueError, match="tasks"):
        stats.probability_of_improvement([[1]], [[1], [2]])


def test_performance_profile():
    point, low, high = stats.performance_profile([[0, 50, 100]], [-1, 25, 75, 100], reps=300)
    np.testing.assert_allclose(point, [1, 2 / 3, 1 / 3, 0])
    assert np.all(low <= point) and np.all(point <= high)
    assert low[0] == high[0] == 1 and low[-1] == high[-1] == 0


def test_welch_matches_scipy_and_the_formula():
    x, y = np.array([12.0, 30, 25, 41, 18]), np.array([5.0, 9, 14, 3, 11, 8])
    vx, vy = x.var(ddof=1) / x.size, y.var(ddof=1) / y.size
    t = (x.mean() - y.mean()) / math.sqrt(vx + vy)
    df = (vx + vy) ** 2 / (vx**2 / (x.size - 1) + vy**2 / (y.size - 1))
    p = 2 * sps.t.sf(abs(t), df)
    result = stats.welch(x, y)
    assert result.t == pytest.approx(t) and result.p == pytest.approx(p)
    assert result.p == sps.ttest_ind(x, y, equal_var=False).pvalue
    assert result.significant and p < 0.05
    undefined = stats.welch([0, 0, 0], [0, 0])
    assert math.isnan(undefined.p) and not undefined.significant


def test_one_run_per_task_has_no_interval():
    """Resampling a single run gives it back: no CI rather than one of zero width."""
    alone = stats.aggregate_interval([[16.0], [4.0]], stats.mean, reps=100)
    assert alone.point == 10.0 and math.isnan(alone.low) and math.isnan(alone.high)
    assert str(alone) == "10 [no CI]" and alone.text(".1f") == "10.0 [no CI]"
    assert stats.aggregate_interval([[16.0, 4.0]], stats.mean, reps=100).text(".1f") != (
        "10.0 [no CI]"
    )


def test_mean_band():
    band = stats.mean_band([0, 1], reps=4000, seed=3)  # resampled means: 0, 0.5, 1
    assert (band.point, band.low, band.high) == (0.5, 0.0, 1.0)
    with pytest.raises(ValueError):
        stats.aggregate_interval([[1], []])


def test_holm_adjusts_in_input_order_and_skips_undefined_tests():
    adjusted = stats.holm([0.01, 0.04, 0.03, float("nan")])
    np.testing.assert_allclose(adjusted[:3], [0.03, 0.06, 0.06])  # 3 x 0.01, then monotone
    assert math.isnan(adjusted[3])
    assert stats.holm([0.5, 0.9]).max() == 1.0  # capped at 1


def test_mann_whitney_exact_floor_with_four_runs_a_side():
    """4 vs 4 fully separated: the exact two-sided p is 2/70, the smallest there is."""
    test = stats.mann_whitney([1, 2, 3, 4], [5, 6, 7, 8])
    assert test.p == pytest.approx(2 / 70)
    assert math.isnan(stats.mann_whitney([1, 1], [1, 1]).p)


def test_seeds_needed_matches_the_t_test_power():
    # d = 1 (pooled SD 1): the textbook 17 runs per side for 80% power at 0.05
    assert stats.seeds_needed([0, 1, 2], [1, 2, 3]) == 17
    assert stats.seeds_needed([0, 1, 2], [0, 1, 2]) == math.inf
    assert math.isnan(stats.seeds_needed([1], [1, 2]))
    assert stats.seeds_needed([0, 1, 2], [10, 11, 12]) == 2  # a huge effect: the minimum


def test_power_at_the_corrected_level_needs_more_seeds():
    """d = 1: 17 runs per side at 0.05, 30 at 0.05/11 (the normal approximation 2 (z_{1 - a/2}
    + z_0.8)^2 / d^2 gives 27.1, the t's heavier tails a few more); a p below 0.05/m passes
    Holm's correction over m tests."""
    alpha = stats.family_alpha([0.2, float("nan")] + [0.5] * 10)  # 11 defined tests
    assert alpha == pytest.approx(0.05 / 11)
    assert stats.seeds_needed([0, 1, 2], [1, 2, 3], alpha=alpha) == 30
    assert stats.family_alpha([float("nan")]) == 0.05  # no defined test: nothing to correct
    p = np.full(11, 0.9)
    p[3] = alpha * 0.99
    assert stats.holm(p)[3] < 0.05


def test_probability_of_improvement_needs_three_runs_a_side():
    assert not stats.enough_runs([1, 2], [1, 2, 3]) and stats.enough_runs([1, 2, 3], [4, 5, 6])
