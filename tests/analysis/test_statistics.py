"""Tests of mcjax.analysis.statistics against textbook values computed by hand and against scipy's
own interval functions (stats.t.interval, stats.binomtest(...).proportion_ci)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from mcjax.analysis.statistics import mean_ci, t_critical, wilson_interval

Z975 = 1.959964  # normal quantile, textbook table


# --------------------------------------------------------------------------------------
# t-interval
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("dof,table", [(1, 12.706), (2, 4.303), (4, 2.776), (10, 2.228), (30, 2.042),
                                       (120, 1.980), (math.inf, 1.960)])
def test_t_critical_textbook_table(dof, table):
    assert t_critical(dof) == pytest.approx(table, abs=5e-4)


def test_t_critical_other_levels_and_edges():
    assert t_critical(5, confidence=0.99) == pytest.approx(4.032, abs=5e-4)   # textbook
    assert t_critical(5, confidence=0.90) == pytest.approx(2.015, abs=5e-4)
    assert math.isnan(t_critical(0)) and math.isnan(t_critical(float("nan")))
    with pytest.raises(ValueError, match="confidence"):
        t_critical(3, confidence=1.0)


def test_mean_ci_hand_computed():
    # x = 1..5: mean 3, sd = sqrt(2.5), se = sqrt(2.5/5) = 0.7071068, t(0.975, 4) = 2.776445
    # half width 2.776445 * 0.7071068 = 1.963243
    mean, lo, hi = mean_ci([1.0, 2.0, 3.0, 4.0, 5.0])
    assert mean == 3.0
    assert lo == pytest.approx(3 - 1.963243, abs=2e-6)
    assert hi == pytest.approx(3 + 1.963243, abs=2e-6)
    # two values 10, 20: mean 15, se = 5, t(0.975, 1) = 12.706205 -> 15 ± 63.531
    assert mean_ci([10.0, 20.0]) == pytest.approx((15.0, 15 - 63.531025, 15 + 63.531025), abs=1e-5)


@pytest.mark.parametrize("n", [2, 3, 10, 30, 31, 57, 400])
def test_mean_ci_matches_scipy_t_interval(n):
    x = np.random.default_rng(n).gamma(2.0, 10.0, size=n)
    mean, lo, hi = mean_ci(x)
    ref = stats.t.interval(0.95, n - 1, loc=x.mean(), scale=stats.sem(x))
    assert mean == pytest.approx(x.mean(), rel=1e-12)
    assert (lo, hi) == pytest.approx(ref, rel=1e-10)
    ref90 = stats.t.interval(0.90, n - 1, loc=x.mean(), scale=stats.sem(x))
    assert mean_ci(x, confidence=0.9)[1:] == pytest.approx(ref90, rel=1e-10)


def test_mean_ci_ignores_nonfinite_and_small_samples():
    mean, lo, hi = mean_ci([1.0, np.nan, 3.0, np.inf])
    ref = stats.t.interval(0.95, 1, loc=2.0, scale=stats.sem([1.0, 3.0]))
    assert mean == 2.0 and (lo, hi) == pytest.approx(ref, rel=1e-10)
    mean, lo, hi = mean_ci([4.0])
    assert mean == 4.0 and math.isnan(lo) and math.isnan(hi)
    assert all(math.isnan(v) for v in mean_ci([]))
    assert mean_ci(v for v in (2.0, 2.0, 2.0)) == (2.0, 2.0, 2.0)  # generators; zero width


# --------------------------------------------------------------------------------------
# Wilson interval
# --------------------------------------------------------------------------------------


def test_wilson_hand_computed():
    # k=5, n=10: z^2/n = 0.3841459, centre (0.5 + 0.19207)/1.3841459 = 0.5,
    # half = z/1.3841459 * sqrt(0.5*0.5/10 + z^2/(4*10^2)) = 1.416013 * 0.186021 = 0.263407
    lo, hi = wilson_interval(5, 10)
    assert lo == pytest.approx(0.236593, abs=2e-6)
    assert hi == pytest.approx(0.763407, abs=2e-6)


@pytest.mark.parametrize("n", [1, 10, 50])
def test_wilson_at_k_zero_and_k_n(n):
    # k=0: (0, z^2/(n + z^2)); k=n: (n/(n + z^2), 1) -- from the closed form with p = 0 or 1
    z2 = Z975**2
    assert wilson_interval(0, n) == pytest.approx((0.0, z2 / (n + z2)), abs=1e-6)
    assert wilson_interval(0, n).low == 0.0
    assert wilson_interval(n, n) == pytest.approx((n / (n + z2), 1.0), abs=1e-6)
    assert wilson_interval(n, n).high == 1.0


@pytest.mark.parametrize("k,n", [(0, 1), (1, 1), (0, 7), (3, 10), (10, 10), (1, 200), (57, 200), (999, 1000)])
def test_wilson_matches_scipy(k, n):
    ci = stats.binomtest(k, n).proportion_ci(method="wilson")
    assert wilson_interval(k, n) == pytest.approx((ci.low, ci.high), abs=1e-12)
    ci90 = stats.binomtest(k, n).proportion_ci(confidence_level=0.9, method="wilson")
    assert wilson_interval(k, n, confidence=0.9) == pytest.approx((ci90.low, ci90.high), abs=1e-12)


def test_wilson_edge_cases():
    assert all(math.isnan(v) for v in wilson_interval(0, 0))
    with pytest.raises(ValueError, match="k <= n"):
        wilson_interval(3, 2)
    with pytest.raises(ValueError, match="k <= n"):
        wilson_interval(-1, 2)
    with pytest.raises(ValueError, match="confidence"):
        wilson_interval(1, 2, confidence=1.5)
