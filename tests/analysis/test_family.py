"""A claims file's family-wise verdicts, from the statistics up (issue 62): Holm's procedure against
a by-hand loop of its definition and a textbook example; each one-sided p-value against the interval
it must match (scipy's Student-t, Wilson and order-statistic intervals); and, simulated in numpy from
the test statistics' distributions — independently of the engine — the family-wise error of m null
claims (each exactly on its boundary) and the power of a claim 5 standard errors from its boundary,
decided as `mcjax check` decides them (:func:`mcjax.analysis.statistics.holm` over each claim's
smaller one-sided p-value, a ``below`` / ``above`` claim standing for two one-sided tests)."""

import math

import numpy as np
import pytest
from scipy import stats

from mcjax.analysis.statistics import holm, mean_tails, mean_ci, order_tails, wilson_interval, wilson_tails

ALPHA = 0.05
FAMILIES = 2000


# ------------------------------------------------------------------------------ Holm's procedure

def _holm_by_hand(p, w, tot, alpha):
    """Holm (1979), weighted, one hypothesis at a time: the smallest p/w first, while p/w <= alpha / (weight left)."""
    left, rejected, level = float(sum(tot)), [False] * len(p), [None] * len(p)
    for i in sorted(range(len(p)), key=lambda i: (p[i], i)):
        if p[i] > alpha / left:
            break
        rejected[i], level[i] = True, alpha / left
        left -= w[i]
    return rejected, [alpha / left if lv is None else lv for lv in level]


def test_holm_is_the_textbook_procedure():
    """Four p-values at 5 %: 0.005 <= 0.05/4 and 0.01 <= 0.05/3 are rejected, 0.03 > 0.05/2 stops; the
    adjusted p-values are max over earlier steps of (hypotheses left) x p."""
    h = holm([0.01, 0.04, 0.03, 0.005])
    assert h.rejected.tolist() == [True, False, False, True]
    assert h.level.tolist() == pytest.approx([0.05 / 3, 0.025, 0.025, 0.05 / 4])
    assert h.adjusted.tolist() == pytest.approx([0.03, 0.06, 0.06, 0.02])
    bonferroni = holm([0.01, 0.04, 0.03, 0.005], step_down=False)
    assert bonferroni.rejected.tolist() == [True, False, False, True]
    assert bonferroni.level.tolist() == pytest.approx([0.0125] * 4)
    assert bonferroni.adjusted.tolist() == pytest.approx([0.04, 0.16, 0.12, 0.02])


def test_weighted_holm_matches_its_definition_one_step_at_a_time():
    rng = np.random.default_rng(5)
    for _ in range(300):
        m = int(rng.integers(1, 12))
        p = rng.uniform(0, 0.02, m) * rng.choice([1.0, 10.0], m)
        w = rng.choice([1.0, 2.0], m)
        tot = w + rng.choice([0.0, 1.0, 2.0], m)
        h = holm(p, w, tot, ALPHA)
        rejected, level = _holm_by_hand(p.tolist(), w.tolist(), tot.tolist(), ALPHA)
        assert h.rejected.tolist() == rejected and h.level.tolist() == pytest.approx(level)
        assert ((h.adjusted <= ALPHA) == h.rejected).all()  # an adjusted p-value: the least error that rejects


# ------------------------------------------------------------------------------ each p-value matches its interval

def test_mean_tails_are_where_the_student_t_interval_reaches_the_value():
    x = np.random.default_rng(1).normal(0.3, 1.0, 25)
    below, above = mean_tails(x.mean(), x.std(ddof=1) / 5, 24, 0.8)
    low, high = stats.t.interval(1 - 2 * float(below), 24, loc=x.mean(), scale=stats.sem(x))
    assert high == pytest.approx(0.8, rel=1e-9) and float(above) == pytest.approx(1 - float(below), rel=1e-12)
    assert mean_ci(x, 1 - 2 * float(below) * 1.001).high < 0.8 < mean_ci(x, 1 - 2 * float(below) * 0.999).high
    assert [float(v) for v in mean_tails(2.0, 0.0, 9, [3.0, 2.0])[0]] == [0.0, 1.0]  # equal values: the point
    assert [float(v) for v in mean_tails(2.0, np.nan, 0, 3.0)] == [1.0, 1.0]  # one value: no interval


@pytest.mark.parametrize("k, n, value", [(7, 100, 0.15), (30, 50, 0.4), (0, 200, 0.01), (200, 200, 0.97)])
def test_wilson_tails_are_the_score_test_the_wilson_interval_inverts(k, n, value):
    below, above = (float(v) for v in wilson_tails(k, n, value))
    p = min(below, above)
    inside, outside = wilson_interval(k, n, 1 - 2 * p * 0.999), wilson_interval(k, n, 1 - 2 * p * 1.001)
    side = 1 if below < above else 0  # the end that reaches the value
    assert inside[side] == pytest.approx(value, rel=1e-3) and (outside.high < value if side else outside.low > value)
    assert (inside.high >= value if side else inside.low <= value)


def test_wilson_tails_at_the_ends_follow_the_interval():
    assert [float(v) for v in wilson_tails(3, 10, 1.0)] == [0.0, 1.0]   # below 1 at every level unless k = n
    assert [float(v) for v in wilson_tails(10, 10, 1.0)] == [1.0, 1.0]
    assert [float(v) for v in wilson_tails(0, 10, 0.0)] == [1.0, 1.0]   # never below 0; above 0 only if k > 0
    assert [float(v) for v in wilson_tails(1, 10, 0.0)] == [1.0, 0.0]


@pytest.mark.parametrize("level", [0.5, 0.9])
def test_order_tails_are_scipys_quantile_test_and_its_interval(level):
    x = np.sort(np.random.default_rng(2).exponential(1.0, 80))
    value = float(np.quantile(x, level)) * 0.7  # below the sample's quantile: 'above' is the small p-value
    below, above = (float(v) for v in order_tails(np.sum(x < value), np.sum(x <= value), len(x), level))
    assert above == pytest.approx(stats.quantile_test(x, q=value, p=level, alternative="greater").pvalue)
    assert below == pytest.approx(stats.quantile_test(x, q=value, p=level, alternative="less").pvalue)
    res = stats.quantile_test(x, p=level)
    assert res.confidence_interval(1 - 2 * above * 1.001).low > value  # past its level the interval lies above
    assert res.confidence_interval(1 - 2 * above * 0.999).low <= value
    # 3 runs: an order-statistic interval needs a >= 1/8 (its ends the smallest and largest value)
    assert [float(v) for v in order_tails(0, 0, 3, 0.5)] == [1.0, 1.0 / 8 * (1 + 1e-12)]


# ------------------------------------------------------------------------------ simulated families

def _decide(below, above, step_down=True):
    """`mcjax check`'s verdicts on families of `below` claims from their one-sided p-values: each claim
    two one-sided tests (holds: below; fails: above), its smaller p-value stepped through Holm."""
    h = holm(np.minimum(below, above), 1.0, 2.0, ALPHA, step_down=step_down)
    return h.rejected & (below < above), h.rejected & (above <= below)


def _null_statistics(kind, rng, shape):
    """(below, above) p-values of null claims, each exactly on its boundary, drawn from the statistic's own
    distribution: a Student-t mean of 20 runs, a Wilson rate of 400 runs at 0.2, a median of 101 continuous
    values (runs below it: binomial), equicorrelated (rho 0.6) normal means."""
    if kind == "mean":
        return mean_tails(rng.standard_t(19, shape), 1.0, 19, 0.0)
    if kind == "mixed":
        third = shape[1] // 3
        t = mean_tails(rng.standard_t(19, (shape[0], third)), 1.0, 19, 0.0)
        k = rng.binomial(400, 0.2, (shape[0], third))
        r = wilson_tails(k, 400, 0.2)
        less = rng.binomial(101, 0.5, (shape[0], shape[1] - 2 * third))
        q = order_tails(less, less, 101, 0.5)
        return tuple(np.concatenate([a, b, c], axis=1) for a, b, c in zip(t, r, q))
    z = math.sqrt(0.6) * rng.standard_normal((shape[0], 1)) + math.sqrt(0.4) * rng.standard_normal(shape)
    return mean_tails(z, 1.0, 10**9, 0.0)


@pytest.mark.parametrize("kind", ["mean", "mixed", "correlated"])
@pytest.mark.parametrize("m", [10, 30, 100])
def test_family_wise_error_of_null_claims_is_at_most_5_percent(m, kind):
    """Every claim on its boundary, so every holds or fails is wrong: the share of 2,000 families with at
    least one is <= 5 % (+ 2 Monte-Carlo standard errors), where each claim's own 95 % interval gives about
    1 − 0.95^m (independent claims: 40 %, 79 %, 99.4 %)."""
    rng = np.random.default_rng(62 + m)
    below, above = _null_statistics(kind, rng, (FAMILIES, m))
    holds, fails = _decide(below, above)
    wrong = np.mean((holds | fails).any(axis=1))
    assert wrong <= ALPHA + 2 * math.sqrt(ALPHA * (1 - ALPHA) / FAMILIES), wrong
    per_claim = np.mean((np.minimum(below, above) <= 0.025).any(axis=1))
    if kind == "mean":
        expected = 1 - 0.95 ** m
        assert abs(per_claim - expected) <= 4 * math.sqrt(expected * (1 - expected) / FAMILIES) + 1e-3, per_claim
    assert per_claim > 3 * ALPHA  # what the family level is for


def _effect(rng, shape, delta, dof=999):
    """A mean's t statistic when the truth is `delta` standard errors from the boundary (noncentral t)."""
    return (rng.standard_normal(shape) + delta) / np.sqrt(rng.chisquare(dof, shape) / dof)


def test_a_claim_5_standard_errors_from_its_boundary_holds_at_the_family_level():
    """Families of 100: claim 0 is 5 standard errors on its claimed side (below), the other 99 on their
    boundaries (nothing to step down on: the hardest case) — it holds in >= 90 % of 2,000 families
    (Bonferroni's first step alone: Φ(5 − z(1 − 0.05/200)) = 93.6 %); with all 100 that far out, Holm's
    steps make each hold more often still."""
    rng = np.random.default_rng(2062)
    t = rng.standard_t(999, (FAMILIES, 100))
    t[:, 0] = _effect(rng, FAMILIES, -5.0)
    holds, fails = _decide(*mean_tails(t, 1.0, 999, 0.0))
    alone = np.mean(holds[:, 0])
    bonferroni = stats.norm.cdf(5 - stats.norm.isf(ALPHA / 200))
    assert alone >= 0.90 and abs(alone - bonferroni) <= 4 * math.sqrt(bonferroni * (1 - bonferroni) / FAMILIES)
    every = _effect(rng, (FAMILIES, 100), -5.0)
    holds, fails = _decide(*mean_tails(every, 1.0, 999, 0.0))
    by_bonferroni = _decide(*mean_tails(every, 1.0, 999, 0.0), step_down=False)[0]
    assert holds.mean() >= 0.90 and holds.mean() > by_bonferroni.mean() + 0.01 and not fails.any()
