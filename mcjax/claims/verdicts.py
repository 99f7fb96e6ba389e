"""Verdicts on a claim from runs: a statistic with its 95 % interval and a relation it should
meet, judged by where the interval lies.

* :func:`estimate` -- a statistic of one design point's runs: the ``mean`` (Student-t interval,
  :func:`mcjax.analysis.statistics.mean_ci`), a ``rate`` of flagged runs (Wilson interval,
  :func:`mcjax.analysis.statistics.wilson_interval`), the ``median`` or a ``quantile`` (the
  distribution-free interval between two order statistics, ``scipy.stats.quantile_test``).
* :func:`paired` -- the mean difference of two sides run on the same seeds (common random
  numbers), with the Student-t interval of the per-seed differences; a pairing whose seeds
  differ is refused (:class:`PairingError`).
* :func:`compare` -- the verdict of ``below`` / ``above`` a value or ``within`` a band:
  **holds** when the interval lies on the claimed side, **fails** when it lies on the other,
  **undecided** when it straddles — then, roughly, how many runs would decide it: the interval's
  half-width shrinks as 1/√n, so ``n (half-width / distance)²`` runs bring it to the distance
  between the estimate and the boundary (a rate: the fewest runs whose Wilson interval at the same
  observed rate excludes the boundary; None when the estimate sits on it).
* :func:`consistent` -- whether a paper's number, from its own ``runs``, is one those runs could
  give if our estimate were the truth: it holds when the paper's value lies within our estimate ±
  √(h² + h_paper²), ``h`` our interval's half-width and ``h_paper`` the half-width an interval of
  the paper's run count would have with our spread (mean: t·s/√runs, s from our interval; rate:
  z·√(p(1 − p)/runs)), and fails otherwise — a two-sample comparison in which the paper's sampling
  error, usually the larger, is estimated from ours since papers seldom print their spread.
* :func:`ordered` -- an order of several estimates (each of its own runs): holds when every
  neighbouring pair's intervals are apart in the claimed direction, fails when one pair's are apart
  the other way, undecided otherwise (apart intervals: a conservative test, as in the report's
  findings). An order of paired sides is judged by :func:`paired` differences instead.
* :func:`tails` -- the one-sided p-values of a statistic against a value, from the test its
  interval inverts (:mod:`mcjax.analysis.statistics`): the smallest one-sided level ``a`` at which
  its interval of confidence ``1 − 2a`` lies below / above the value; :func:`first_level` -- that
  level for any verdict, found by bisection (an order, a paper's number). The family-wise verdict
  of a claims file (:mod:`mcjax.claims.evaluate`) judges each claim at the level Holm's procedure
  gives it.

Every interval describes one design point or one pairing of the design; nothing pools points.
Pure functions of numbers; no pandas, no JAX.
"""

from __future__ import annotations

import math
from typing import Iterable, NamedTuple, Sequence

import numpy as np

from mcjax.analysis.statistics import (CONFIDENCE, mean_ci, mean_tails, order_tails, t_critical, wilson_interval,
                                       wilson_tails)

STATISTICS = ("mean", "median", "quantile", "rate")
RELATIONS = ("below", "above", "within")
VERDICTS = ("holds", "fails", "undecided")


class Estimate(NamedTuple):
    """A statistic of ``n`` runs with its interval ``[low, high]`` (NaN when it has none)."""

    statistic: str
    value: float
    low: float
    high: float
    n: int


class Verdict(NamedTuple):
    """``verdict`` (one of :data:`VERDICTS`) and, when undecided, roughly the runs that would decide it."""

    verdict: str
    runs_to_decide: int | None = None


class PairingError(ValueError):
    """The two sides of a paired comparison were not run on the same seeds."""


def _finite(values: Iterable[float]) -> np.ndarray:
    x = np.asarray(list(values) if not isinstance(values, np.ndarray) else values, dtype=np.float64).ravel()
    return x[np.isfinite(x)]


def estimate(values: Iterable, statistic: str = "mean", *, q: float | None = None,
             confidence: float = CONFIDENCE) -> Estimate:
    """``statistic`` (:data:`STATISTICS`) of one design point's runs ``values`` with its interval:
    ``mean`` and ``median``/``quantile`` over the finite values; ``rate`` the fraction of true
    values (flags) over all of them. ``q`` in (0, 1): the quantile's level (``median``: 0.5)."""
    if statistic not in STATISTICS:
        raise ValueError(f"statistic must be one of {', '.join(STATISTICS)}; got {statistic!r}")
    if statistic == "rate":
        flags = np.asarray(list(values) if not isinstance(values, np.ndarray) else values).ravel().astype(bool)
        n, k = len(flags), int(np.sum(flags))
        low, high = wilson_interval(k, n, confidence) if n else (math.nan, math.nan)
        return Estimate("rate", k / n if n else math.nan, low, high, n)
    x = _finite(values)
    if statistic == "mean":
        m = mean_ci(x, confidence)
        return Estimate("mean", m.mean, m.low, m.high, len(x))
    level = 0.5 if statistic == "median" else q
    if level is None or not 0.0 < level < 1.0:
        raise ValueError(f"q (the quantile's level) must be a number in (0, 1); got {q!r}")
    if len(x) == 0:
        return Estimate(statistic, math.nan, math.nan, math.nan, 0)
    from scipy.stats import quantile_test  # scipy's order-statistic interval (Conover 1999, §3.2)

    ci = quantile_test(x, p=level).confidence_interval(confidence)
    return Estimate(statistic, float(np.quantile(x, level)), float(ci.low), float(ci.high), len(x))


def paired(a: Sequence[float], b: Sequence[float], seeds_a: Sequence[int], seeds_b: Sequence[int],
           confidence: float = CONFIDENCE) -> Estimate:
    """The mean of ``a − b`` over the seeds both sides ran, matched by seed, with the Student-t
    interval of the differences (a paired t interval). :class:`PairingError` (one line) when the
    two sides' seeds are not the same set, or one side has a seed twice."""
    d = differences(a, b, seeds_a, seeds_b)
    m = mean_ci(d, confidence)
    return Estimate("paired difference", m.mean, m.low, m.high, int(np.sum(np.isfinite(d))))


def differences(a: Sequence[float], b: Sequence[float], seeds_a: Sequence[int], seeds_b: Sequence[int]) -> np.ndarray:
    """``a − b`` matched by seed, in the order of the seeds (:func:`paired`'s refusals)."""
    sa, sb = np.asarray(seeds_a).ravel(), np.asarray(seeds_b).ravel()
    if len(set(sa.tolist())) != len(sa) or len(set(sb.tolist())) != len(sb):
        raise PairingError("a paired comparison needs each seed once on each side; a side has a seed twice")
    if set(sa.tolist()) != set(sb.tolist()):
        only = sorted(set(sa.tolist()) ^ set(sb.tolist()))
        raise PairingError(f"a paired comparison needs the same seeds on both sides; {len(only)} seed(s) are on "
                           f"one side only (e.g. {only[:3]})")
    return np.asarray(a, np.float64).ravel()[np.argsort(sa)] - np.asarray(b, np.float64).ravel()[np.argsort(sb)]


def _runs_to_decide(est: Estimate, boundary: float, confidence: float = CONFIDENCE) -> int | None:
    """Runs that would shrink the interval's half-width to the estimate's distance from ``boundary``.
    A rate's Wilson interval does not shrink as 1/√n near 0 or 1 (at 0 of n its upper end is about
    z²/n): there, the fewest runs whose Wilson interval at the same observed rate leaves the boundary
    outside (found by bisection)."""
    half, distance = (est.high - est.low) / 2.0, abs(est.value - boundary)
    if not (distance > 0 and math.isfinite(half) and est.n > 0):
        return None
    guess = max(est.n + 1, math.ceil(est.n * (half / distance) ** 2))
    if est.statistic != "rate" or not 0.0 <= boundary <= 1.0:
        return guess

    def apart(n: int) -> bool:
        low, high = wilson_interval(round(est.value * n), n, confidence)
        return high < boundary if est.value < boundary else low > boundary

    lo, hi = est.n, max(guess, est.n + 1)
    while not apart(hi):
        lo, hi = hi, hi * 2
        if hi > 10**12:
            return None
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if apart(mid) else (mid, hi)
    return hi


def compare(est: Estimate, relation: str, value: float | None = None,
            band: tuple[float, float] | None = None, confidence: float = CONFIDENCE) -> Verdict:
    """The verdict of ``est`` being ``below`` / ``above`` ``value``, or ``within`` ``band`` =
    ``(low, high)`` (:data:`RELATIONS`): from where its interval lies (module docstring). An
    estimate without an interval (too few runs) is undecided. ``confidence``: the interval's, for
    the runs that would decide an undecided rate."""
    if relation not in RELATIONS:
        raise ValueError(f"relation must be one of {', '.join(RELATIONS)}; got {relation!r}")
    if relation == "within":
        if band is None or not band[0] <= band[1]:
            raise ValueError(f"within needs a band (low, high) with low <= high; got {band!r}")
    elif value is None:
        raise ValueError(f"{relation} needs a value")
    if not (math.isfinite(est.low) and math.isfinite(est.high)):
        return Verdict("undecided")
    if relation == "below":
        if est.high < value:
            return Verdict("holds")
        return Verdict("fails") if est.low > value else Verdict("undecided", _runs_to_decide(est, value, confidence))
    if relation == "above":
        if est.low > value:
            return Verdict("holds")
        return Verdict("fails") if est.high < value else Verdict("undecided", _runs_to_decide(est, value, confidence))
    lo, hi = band
    if lo <= est.low and est.high <= hi:
        return Verdict("holds")
    if est.high < lo or est.low > hi:
        return Verdict("fails")
    edge = lo if abs(est.value - lo) <= abs(est.value - hi) else hi
    return Verdict("undecided", _runs_to_decide(est, edge, confidence))


def consistent(est: Estimate, paper: float, runs: int, confidence: float = CONFIDENCE) -> Verdict:
    """The verdict of the paper's ``paper`` (a mean or a rate of its ``runs`` runs) being consistent
    with ``est`` (module docstring); undecided when ``est`` has no interval."""
    if est.statistic not in ("mean", "rate"):
        raise ValueError(f"consistent takes a mean or a rate; got {est.statistic!r}")
    if runs < 2 or not (math.isfinite(est.low) and math.isfinite(est.high)) or est.n < 2:
        return Verdict("undecided")
    half = (est.high - est.low) / 2.0
    if est.statistic == "mean":
        spread = half * math.sqrt(est.n) / t_critical(est.n - 1, confidence)
        paper_half = t_critical(runs - 1, confidence) * spread / math.sqrt(runs)
    else:
        from scipy.stats import norm

        paper_half = float(norm.ppf(0.5 + confidence / 2)) * math.sqrt(est.value * (1.0 - est.value) / runs)
    return Verdict("holds" if abs(paper - est.value) <= math.hypot(half, paper_half) else "fails")


def ordered(estimates: Sequence[Estimate], decreasing: bool = False) -> Verdict:
    """The verdict of ``estimates`` (each of its own runs) increasing (``decreasing``: decreasing)
    in the order given: every neighbouring pair's intervals apart in that direction → holds; a
    pair apart the other way → fails; otherwise undecided."""
    if len(estimates) < 2:
        raise ValueError(f"an order needs at least two estimates; got {len(estimates)}")
    sign = -1.0 if decreasing else 1.0
    decided = True
    for a, b in zip(estimates, estimates[1:]):
        lo_a, hi_a = sorted((sign * a.low, sign * a.high))
        lo_b, hi_b = sorted((sign * b.low, sign * b.high))
        if not all(map(math.isfinite, (lo_a, hi_a, lo_b, hi_b))):
            decided = False
        elif lo_a > hi_b:
            return Verdict("fails")
        elif not hi_a < lo_b:
            decided = False
    return Verdict("holds" if decided else "undecided")


def tails(values: Iterable, statistic: str, value: float, *, q: float | None = None) -> tuple[float, float]:
    """``(below, above)``: the smallest one-sided level ``a`` at which :func:`estimate`'s interval
    of ``statistic`` at confidence ``1 − 2a`` lies entirely below / above ``value`` — the one-sided
    p-values of the test that interval inverts: Student-t for a mean (pass a paired difference's
    per-seed differences as a mean's values), the score test for a rate, the binomial test for a
    median or quantile (:func:`mcjax.analysis.statistics.mean_tails` and its neighbours). 1.0: at
    no level (no interval, or a zero-width one on the value)."""
    if statistic == "rate":
        flags = np.asarray(list(values) if not isinstance(values, np.ndarray) else values).ravel().astype(bool)
        below, above = wilson_tails(int(np.sum(flags)), len(flags), value)
    else:
        x = _finite(values)
        if statistic == "mean":
            n = len(x)
            sd = float(np.std(x, ddof=1)) if n > 1 else math.nan
            below, above = mean_tails(float(np.mean(x)) if n else math.nan, sd / math.sqrt(max(n, 1)), n - 1, value)
        else:
            level = 0.5 if statistic == "median" else q
            below, above = order_tails(int(np.sum(x < value)), int(np.sum(x <= value)), len(x), level)
    return float(below), float(above)


#: The smallest and largest one-sided level :func:`first_level` looks at (1e-12: decided at any
#: level a family of claims uses; 0.45: an interval of confidence 0.1).
TAIL_RANGE = (1e-12, 0.45)


def first_level(decided, steps: int = 30) -> float:
    """The smallest one-sided level ``a`` at which ``decided(a)`` (its verdict from intervals of
    confidence ``1 − 2a``: once decided, decided at every larger ``a``, the intervals being nested),
    by bisection on ``log a`` over :data:`TAIL_RANGE` (relative precision ~3e-8): 0.0 when decided
    at the smallest, 1.0 when not at the largest."""
    lo, hi = TAIL_RANGE
    if decided(lo):
        return 0.0
    if not decided(hi):
        return 1.0
    lo, hi = math.log(lo), math.log(hi)
    for _ in range(steps):
        mid = (lo + hi) / 2
        lo, hi = (lo, mid) if decided(math.exp(mid)) else (mid, hi)
    return math.exp(hi)
