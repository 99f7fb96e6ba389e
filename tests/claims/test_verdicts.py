"""mcjax.claims.verdicts against independent references: scipy's intervals (Student-t, paired t,
Wilson, the binomial coverage of an order-statistic interval) and hand-made datasets on which each
relation must hold, fail or stay undecided."""

import math

import numpy as np
import pytest
from scipy import stats

from mcjax.claims import verdicts
from mcjax.claims.verdicts import Estimate, compare, estimate, ordered, paired

RNG = np.random.default_rng(7)


def test_mean_is_scipys_t_interval_over_the_finite_values():
    x = RNG.normal(3.0, 2.0, 40)
    est = estimate(np.concatenate([x, [np.nan, np.inf]]), "mean")
    low, high = stats.t.interval(0.95, len(x) - 1, loc=x.mean(), scale=stats.sem(x))
    assert est.n == 40 and est.value == pytest.approx(x.mean(), rel=1e-12)
    assert (est.low, est.high) == pytest.approx((low, high), rel=1e-12)


def test_rate_is_scipys_wilson_interval_over_every_run():
    flags = np.array([True] * 7 + [False] * 93)
    est = estimate(flags, "rate")
    ci = stats.binomtest(7, 100).proportion_ci(0.95, method="wilson")
    assert est.n == 100 and est.value == 0.07
    assert (est.low, est.high) == pytest.approx((ci.low, ci.high), rel=1e-12)


@pytest.mark.parametrize("statistic, q", [("median", None), ("quantile", 0.9)])
def test_quantile_interval_is_two_order_statistics_covering_the_quantile(statistic, q):
    """The interval's ends are order statistics X(l) <= X(u) of the sample, and the chance that
    [X(l), X(u)] holds the true quantile, P(l <= B < u) with B ~ Binomial(n, p), is at least 95 %."""
    x = np.sort(RNG.exponential(1.0, 200))
    est = estimate(x, statistic, q=q)
    p = 0.5 if q is None else q
    l, u = int(np.searchsorted(x, est.low)) + 1, int(np.searchsorted(x, est.high)) + 1  # 1-based ranks
    assert x[l - 1] == est.low and x[u - 1] == est.high and l < u
    coverage = stats.binom.cdf(u - 1, len(x), p) - stats.binom.cdf(l - 1, len(x), p)
    assert coverage >= 0.95
    assert est.low <= np.quantile(x, p) <= est.high


def test_paired_is_scipys_paired_t_interval_matched_by_seed():
    seeds = np.arange(30)
    a = RNG.normal(10.0, 1.0, 30)
    b = a - 0.3 + RNG.normal(0.0, 0.2, 30)
    order = RNG.permutation(30)  # the second side's rows come in another order
    est = paired(a, b[order], seeds, seeds[order])
    ref = stats.ttest_rel(a, b).confidence_interval(0.95)
    assert est.value == pytest.approx(np.mean(a - b), rel=1e-12)
    assert (est.low, est.high) == pytest.approx((ref.low, ref.high), rel=1e-12)


@pytest.mark.parametrize("seeds_b, words", [(np.arange(1, 31), "same seeds"), (np.r_[np.arange(29), 0], "twice")])
def test_a_pairing_whose_seeds_differ_is_refused_in_one_line(seeds_b, words):
    with pytest.raises(verdicts.PairingError, match=words) as exc:
        paired(np.zeros(30), np.zeros(30), np.arange(30), seeds_b)
    assert "\n" not in str(exc.value)


def _mean_of(center: float, half: float, n: int = 100) -> Estimate:
    return Estimate("mean", center, center - half, center + half, n)


@pytest.mark.parametrize("relation, kwargs, est, expected", [
    ("below", dict(value=10.0), _mean_of(8.0, 1.0), "holds"),
    ("below", dict(value=10.0), _mean_of(12.0, 1.0), "fails"),
    ("below", dict(value=10.0), _mean_of(9.5, 1.0), "undecided"),
    ("above", dict(value=10.0), _mean_of(12.0, 1.0), "holds"),
    ("above", dict(value=10.0), _mean_of(8.0, 1.0), "fails"),
    ("above", dict(value=10.0), _mean_of(10.5, 1.0), "undecided"),
    ("within", dict(band=(9.0, 11.0)), _mean_of(10.0, 0.5), "holds"),
    ("within", dict(band=(9.0, 11.0)), _mean_of(13.0, 0.5), "fails"),
    ("within", dict(band=(9.0, 11.0)), _mean_of(10.8, 0.5), "undecided"),
])
def test_each_relation_holds_fails_or_is_undecided_where_it_should(relation, kwargs, est, expected):
    assert compare(est, relation, **kwargs).verdict == expected


def test_a_statistic_from_real_runs_gets_each_verdict():
    """Hand-made runs: a mean of 5.0 with noise 1.0 over 400 runs is below 6, not below 4, and
    undecided against 5.05; a 2 % divergence rate over 1,000 runs is below 5 %."""
    x = 5.0 + RNG.normal(0.0, 1.0, 400)
    x = x - x.mean() + 5.0
    est = estimate(x, "mean")
    assert compare(est, "below", 6.0).verdict == "holds"
    assert compare(est, "below", 4.0).verdict == "fails"
    close = compare(est, "below", 5.05)
    assert close.verdict == "undecided"
    # the runs that would decide it: the interval's half-width at that many runs is the distance
    half = (est.high - est.low) / 2
    assert close.runs_to_decide == math.ceil(400 * (half / 0.05) ** 2)
    assert half * math.sqrt(400 / close.runs_to_decide) <= 0.05 + 1e-12
    rate = estimate(np.r_[np.ones(20, bool), np.zeros(980, bool)], "rate")
    assert compare(rate, "below", 0.05).verdict == "holds"


def test_an_estimate_without_an_interval_is_undecided_and_sitting_on_the_boundary_names_no_run_count():
    assert compare(estimate([1.0], "mean"), "below", 2.0) == ("undecided", None)
    assert compare(_mean_of(10.0, 1.0), "below", 10.0) == ("undecided", None)


def test_an_order_holds_fails_or_is_undecided():
    a, b, c = _mean_of(1.0, 0.2), _mean_of(2.0, 0.2), _mean_of(3.0, 0.2)
    assert ordered([a, b, c]).verdict == "holds"
    assert ordered([c, b, a], decreasing=True).verdict == "holds"
    assert ordered([a, c, b]).verdict == "fails"
    assert ordered([a, _mean_of(1.1, 0.2), c]).verdict == "undecided"


@pytest.mark.parametrize("call, message", [
    (lambda: estimate([1.0, 2.0], "mode"), "statistic must be one of mean, median, quantile, rate"),
    (lambda: estimate([1.0, 2.0], "quantile"), r"q \(the quantile's level\) must be a number in \(0, 1\)"),
    (lambda: compare(_mean_of(1.0, 0.1), "beside", 2.0), "relation must be one of below, above, within"),
    (lambda: compare(_mean_of(1.0, 0.1), "within", band=(2.0, 1.0)), "within needs a band"),
    (lambda: ordered([_mean_of(1.0, 0.1)]), "at least two"),
])
def test_bad_arguments_are_one_line_errors(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_runs_to_decide_a_rate_near_zero_follow_the_wilson_interval_not_one_over_root_n():
    """0 of 200 runs against a bound of 1 %: the Wilson interval's upper end is about z²/n, so the
    runs that decide it are the fewest whose interval (scipy's) at 0 of n lies below 0.01."""
    from scipy.stats import binomtest

    v = compare(estimate(np.zeros(200, bool), "rate"), "below", 0.01)
    assert v.verdict == "undecided"
    n = next(n for n in range(201, 2000) if binomtest(0, n).proportion_ci(0.95, method="wilson").high < 0.01)
    assert v.runs_to_decide == n
