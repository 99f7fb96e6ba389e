"""The league's ranking on hand-made tables whose paired intervals are computed here, independently,
with scipy: ties where the paired intervals contain 0, a clear order where they do not."""

import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from mcjax.league.rank import paired_difference, paired_ranks


def t_interval(d):
    """The 95 % Student-t interval of the mean of ``d``, by scipy alone."""
    d = np.asarray(d, float)
    return stats.t.interval(0.95, d.size - 1, loc=d.mean(), scale=stats.sem(d))


SEEDS = np.arange(12)
RNG = np.random.default_rng(7)
BASE = 10 + RNG.normal(0, 2, SEEDS.size)          # what every filter shares on a seed


def series(values):
    return pd.Series(np.asarray(values, float), index=SEEDS)


def test_paired_difference_is_scipys_t_interval():
    a, b = series(BASE + RNG.normal(1, 0.3, 12)), series(BASE)
    mean, low, high = paired_difference(a, b)
    lo, hi = t_interval(a.to_numpy() - b.to_numpy())
    assert mean == pytest.approx((a - b).mean()) and low == pytest.approx(lo) and high == pytest.approx(hi)


def test_a_clear_order_where_the_paired_intervals_lie_apart():
    a = series(BASE)
    b = series(BASE + 1.0 + RNG.normal(0, 0.1, 12))     # clearly worse than a, run by run
    c = series(BASE + 2.5 + RNG.normal(0, 0.1, 12))     # clearly worse than b
    for x, y in ((b, a), (c, b)):
        assert t_interval(x - y)[0] > 0                 # scipy: the interval lies above 0
    assert paired_ranks({"c": c, "a": a, "b": b}) == {"c": 3, "a": 1, "b": 2}


def test_a_tie_where_the_paired_interval_contains_zero():
    a = series(BASE)
    noise = np.tile([0.5, -0.5], 6) + RNG.normal(0, 0.05, 12)
    b = series(BASE + 0.02 + noise)                       # about the same as a, run by run
    c = series(BASE + 3.0 + RNG.normal(0, 0.1, 12))       # clearly worse than both
    lo, hi = t_interval(b - a)
    assert lo < 0 < hi                                    # scipy: b - a straddles 0
    assert t_interval(c - b)[0] > 0
    ranks = paired_ranks({"a": a, "b": b, "c": c})
    assert ranks == {"a": 1, "b": 1, "c": 2}


def test_pairing_matters_the_unpaired_intervals_would_overlap():
    # seeds vary a lot (BASE * 5), the difference is small but the same on every seed: paired, clearly apart
    a = series(5 * BASE)
    b = series(5 * BASE + 0.3 + RNG.normal(0, 0.01, 12))
    ia = stats.t.interval(0.95, 11, loc=a.mean(), scale=stats.sem(a))
    ib = stats.t.interval(0.95, 11, loc=b.mean(), scale=stats.sem(b))
    assert ia[1] > ib[0]                                  # the per-filter intervals overlap
    assert t_interval(b - a)[0] > 0                       # the paired one does not contain 0
    assert paired_ranks({"a": a, "b": b}) == {"a": 1, "b": 2}


def test_ties_are_judged_against_each_ranks_leader():
    # b ties with a (rank 1); c is clearly worse than a, so it leads rank 2, and d ties with c
    a = series(BASE)
    b = series(BASE + 0.05 + np.tile([0.6, -0.6], 6))
    c = series(BASE + 2.0 + RNG.normal(0, 0.05, 12))
    d = series(BASE + 2.02 + np.tile([-0.7, 0.7], 6))
    assert t_interval(c - a)[0] > 0 and t_interval(d - a)[0] > 0
    lo, hi = t_interval(d - c)
    assert lo < 0 < hi
    assert paired_ranks({"a": a, "b": b, "c": c, "d": d}) == {"a": 1, "b": 1, "c": 2, "d": 2}


def test_non_finite_runs_are_left_out_and_a_filter_without_any_has_no_rank():
    a = series(BASE)
    b = series(np.where(SEEDS == 3, np.nan, BASE + 1.0 + RNG.normal(0, 0.1, 12)))
    none = series(np.full(12, np.nan))
    ranks = paired_ranks({"a": a, "b": b, "none": none})
    assert ranks == {"a": 1, "b": 2, "none": None}
    d = (b - a).dropna()
    assert paired_difference(b, a).low == pytest.approx(t_interval(d)[0])
    assert math.isnan(paired_difference(none, a).mean)
