"""Confidence intervals used by the report: a mean with its Student-t interval and a
binomial proportion with its Wilson score interval.

* :func:`t_critical` -- two-sided Student-t critical value ``t((1 + c)/2, dof)``
  (``scipy.stats.t.ppf``).
* :func:`mean_ci` -- ``(mean, low, high)``: mean of the finite values and the interval
  ``mean ± t·sd/√n`` (``sd`` with ``ddof=1``); NaN interval for fewer than two values.
* :func:`wilson_interval` -- ``(low, high)``: Wilson score interval of ``k/n`` without
  continuity correction (``scipy.stats.binomtest(k, n).proportion_ci(method="wilson")``).
* :func:`chi2_band` -- the two-sided band of an average of NEES (or NIS) values: for ``runs``
  independent runs of a ``dof``-dimensional error of a consistent filter, ``N·ε̄`` is χ² with
  ``N·dof`` degrees of freedom, so ``ε̄`` lies in ``[χ²_{N·dof}(α/2), χ²_{N·dof}(1 − α/2)] / N``
  (Bar-Shalom, Li & Kirubarajan 2001, §5.4.2); :func:`consistency` says where an average lies.
* :func:`floor_multiple` -- a filter's RMS error as a multiple of an error floor's,
  ``√(mean e² / mean b²)`` over paired runs, with a delta-method interval.
* :func:`mean_tails`, :func:`wilson_tails`, :func:`order_tails` -- the one-sided p-values of the
  tests the intervals above invert (Student-t; the score test of a proportion, which the Wilson
  interval inverts; the binomial test of a quantile, which ``scipy.stats.quantile_test``'s
  interval inverts): ``(below, above)``, the smallest one-sided level ``a`` at which the interval
  of confidence ``1 − 2a`` lies entirely below / above a value. Vectorised (numpy arrays in).
* :func:`holm` -- Holm's (1979) sequentially rejective Bonferroni procedure, weighted, over the
  last axis of an array of one-sided p-values (or, ``step_down=False``, plain Bonferroni): which
  are rejected with a family-wise error ``<= alpha``, the level each was tested at, and the
  adjusted p-values.

Both return :class:`typing.NamedTuple` records, which compare equal to plain tuples.
Pure functions of numbers; no pandas, no JAX.
"""

from __future__ import annotations

import math
from typing import Iterable, NamedTuple

import numpy as np
from scipy import stats

__all__ = ["CONFIDENCE", "MeanCI", "Interval", "t_critical", "mean_ci", "wilson_interval", "chi2_band",
           "consistency", "CONSISTENCY", "floor_multiple", "mean_tails", "wilson_tails", "order_tails",
           "FAMILY_ERROR", "Holm", "holm"]

#: What :func:`consistency` says of an average NEES or NIS against its band.
CONSISTENCY = ("consistent", "over-confident", "under-confident")

#: Confidence level of every interval in the report.
CONFIDENCE = 0.95
#: The family-wise error of :func:`holm` unless told (1 − :data:`CONFIDENCE`, exactly 0.05).
FAMILY_ERROR = round(1 - CONFIDENCE, 12)


class MeanCI(NamedTuple):
    """A mean and its confidence interval (NaN where undefined)."""

    mean: float
    low: float
    high: float


class Interval(NamedTuple):
    """A confidence interval of a proportion (NaN where undefined)."""

    low: float
    high: float


def _check_confidence(confidence: float) -> float:
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    return float(confidence)


def t_critical(dof: float, confidence: float = CONFIDENCE) -> float:
    """Two-sided Student-t critical value ``t((1 + confidence)/2, dof)``; NaN for ``dof < 1``
    (or NaN), the normal quantile for ``dof = inf``."""
    confidence = _check_confidence(confidence)
    dof = float(dof)
    if not dof >= 1:  # also NaN
        return math.nan
    return float(stats.t.ppf(0.5 + confidence / 2, dof))


def mean_ci(values: Iterable[float], confidence: float = CONFIDENCE) -> MeanCI:
    """Mean of the finite ``values`` and its Student-t confidence interval.

    Non-finite values (NaN, ±inf) are left out.  No finite value: all NaN; one finite
    value: the mean with a NaN interval.  Equal values give a zero-width interval.
    """
    confidence = _check_confidence(confidence)
    x = np.asarray(values if hasattr(values, "__len__") else list(values), dtype=float).ravel()
    x = x[np.isfinite(x)]
    n = x.size
    if n == 0:
        return MeanCI(math.nan, math.nan, math.nan)
    mean = float(x.mean())
    if n == 1:
        return MeanCI(mean, math.nan, math.nan)
    half = t_critical(n - 1, confidence) * float(x.std(ddof=1)) / math.sqrt(n)
    return MeanCI(mean, mean - half, mean + half)


def wilson_interval(k: int, n: int, confidence: float = CONFIDENCE) -> Interval:
    """Wilson score interval of the proportion ``k/n`` (no continuity correction).

    ``low = 0`` exactly when ``k = 0`` and ``high = 1`` exactly when ``k = n``;
    ``n = 0`` gives ``(nan, nan)``.

    Raises:
        ValueError: unless ``0 <= k <= n``, or ``confidence`` is not in (0, 1).
    """
    confidence = _check_confidence(confidence)
    k, n = int(k), int(n)
    if n < 0 or k < 0 or k > n:
        raise ValueError(f"wilson_interval needs 0 <= k <= n, got k={k}, n={n}")
    if n == 0:
        return Interval(math.nan, math.nan)
    ci = stats.binomtest(k, n).proportion_ci(confidence_level=confidence, method="wilson")
    low = 0.0 if k == 0 else max(0.0, float(ci.low))  # exact ends (scipy's can be off by round-off)
    high = 1.0 if k == n else min(1.0, float(ci.high))
    return Interval(low, high)


def chi2_band(dof: int, runs: int, confidence: float = CONFIDENCE) -> Interval:
    """The two-sided ``confidence`` band of the average of ``runs`` independent NEES (or NIS)
    values of a ``dof``-dimensional error, when the filter is consistent: the quantiles of
    χ² with ``runs·dof`` degrees of freedom, divided by ``runs`` (Bar-Shalom, Li & Kirubarajan
    2001, eq. 5.4.2-5; ``scipy.stats.chi2``). Its middle is ``dof``."""
    confidence = _check_confidence(confidence)
    if int(dof) < 1 or int(runs) < 1:
        raise ValueError(f"chi2_band needs dof >= 1 and runs >= 1, got dof={dof}, runs={runs}")
    k = int(dof) * int(runs)
    low, high = stats.chi2.ppf([(1 - confidence) / 2, (1 + confidence) / 2], k)
    return Interval(float(low) / runs, float(high) / runs)


def consistency(average: float, band: Interval) -> str:
    """Where an average NEES or NIS lies against its :func:`chi2_band`: ``"over-confident"``
    above it (the errors are larger than the filter's covariance says), ``"under-confident"``
    below it (smaller), ``"consistent"`` inside (one of :data:`CONSISTENCY`)."""
    if not math.isfinite(average):
        raise ValueError(f"consistency needs a finite average; got {average!r}")
    return "over-confident" if average > band.high else "under-confident" if average < band.low else "consistent"


def floor_multiple(errors, floors, confidence: float = CONFIDENCE) -> MeanCI:
    """How many times a floor a filter's RMS error is, over paired runs: ``√(mean e² / mean b²)``
    of each run's RMS error ``e`` and its floor ``b`` (e.g. the posterior Cramér–Rao bound's RMSE
    along the same run; runs where either is not finite are left out). The interval is that of
    the ratio of means ``r = ē²/b̄²`` by the delta method — ``var r ≈ (var e² − 2r cov(e², b²) +
    r² var b²) / (n · (b̄²)²)``, Student-t with n − 1 dof — taken to the square root (a monotone
    map). NaN interval for fewer than two runs."""
    confidence = _check_confidence(confidence)
    e = np.asarray(errors, float) ** 2
    b = np.asarray(floors, float) ** 2
    if e.shape != b.shape:
        raise ValueError(f"floor_multiple needs paired runs; got {e.shape} errors and {b.shape} floors")
    ok = np.isfinite(e) & np.isfinite(b)
    e, b = e[ok], b[ok]
    n = e.size
    if n == 0 or not np.mean(b) > 0:
        return MeanCI(math.nan, math.nan, math.nan)
    r = float(np.mean(e) / np.mean(b))
    if n < 2:
        return MeanCI(math.sqrt(r), math.nan, math.nan)
    cov = np.cov(e, b, ddof=1)
    var = (cov[0, 0] - 2 * r * cov[0, 1] + r * r * cov[1, 1]) / (n * np.mean(b) ** 2)
    half = t_critical(n - 1, confidence) * math.sqrt(max(float(var), 0.0))
    return MeanCI(math.sqrt(r), math.sqrt(max(r - half, 0.0)), math.sqrt(r + half))


def paired_by_seed(runs, columns: list[str], initial: int, tuned: int, filters) -> list[dict]:
    """Per filter (in the order ``filters``) and column, the mean over seeds of the run at point
    ``tuned`` minus the run at point ``initial`` of the same seed, with its 95 % Student-t
    interval (:func:`mean_ci`), beside each point's mean. ``runs``: a DataFrame with
    ``filter``, ``point_id``, ``seed_index`` and the columns."""
    rows = []
    for f in filters:
        g = runs[runs["filter"] == f]
        a = g[g["point_id"] == initial].set_index("seed_index")
        b = g[g["point_id"] == tuned].set_index("seed_index")
        for c in columns:
            d = (b[c].astype(float) - a[c].astype(float)).dropna()
            m = mean_ci(d.to_numpy())
            rows.append({"filter": f, "output": c, "initial": float(a[c].astype(float).mean()),
                         "tuned": float(b[c].astype(float).mean()), "paired_difference": m.mean,
                         "ci_low": m.low, "ci_high": m.high, "n": len(d)})
    return rows


def mean_tails(mean, se, dof, value) -> tuple[np.ndarray, np.ndarray]:
    """``(below, above)``: the one-sided p-values of a Student-t statistic against ``value`` —
    ``below = P(t_dof >= (value − mean)/se)``, the smallest ``a`` at which the interval
    ``mean ± t(1 − a, dof)·se`` (:func:`mean_ci` at confidence ``1 − 2a``) lies below ``value``;
    ``above`` the same for lying above. ``se = 0`` (equal values): 0 on the side the mean lies
    strictly on, else 1; ``dof < 1`` (no interval): 1. Arrays broadcast; float64 arrays out."""
    mean, se, dof, value = np.broadcast_arrays(*(np.asarray(a, np.float64) for a in (mean, se, dof, value)))
    below, above = np.ones(mean.shape), np.ones(mean.shape)
    ok = (dof >= 1) & np.isfinite(mean) & np.isfinite(se)
    pos = ok & (se > 0)
    z = np.divide(value - mean, se, out=np.zeros(mean.shape), where=pos)
    below[pos] = stats.t.sf(z[pos], dof[pos])
    above[pos] = stats.t.cdf(z[pos], dof[pos])
    flat = ok & (se == 0)
    below[flat] = np.where(mean[flat] < value[flat], 0.0, 1.0)
    above[flat] = np.where(mean[flat] > value[flat], 0.0, 1.0)
    return below, above


def wilson_tails(k, n, value) -> tuple[np.ndarray, np.ndarray]:
    """``(below, above)``: the one-sided p-values of the score test of the proportion ``k/n``
    against ``value`` — the test the Wilson interval inverts (Wilson 1927), so ``below`` is the
    smallest ``a`` at which :func:`wilson_interval` at confidence ``1 − 2a`` lies below ``value``:
    ``Φ(z)``, ``z = (k/n − value) / √(value (1 − value) / n)``, for ``0 < value < 1``. At the
    ends, from the interval itself (it reaches 0 only at ``k = 0`` and 1 only at ``k = n``):
    below 1 when ``k < n`` and above 0 when ``k > 0`` at every level (p = 0), never below 0 or
    above 1 (p = 1). ``n = 0``: 1. Arrays broadcast."""
    k, n, value = np.broadcast_arrays(*(np.asarray(a, np.float64) for a in (k, n, value)))
    below, above = np.ones(k.shape), np.ones(k.shape)
    ok = n > 0
    inner = ok & (value > 0) & (value < 1)
    sd = np.sqrt(np.where(inner, value * (1 - value) / np.where(ok, n, 1.0), 1.0))
    z = np.where(inner, (k / np.where(ok, n, 1.0) - value) / sd, 0.0)
    below[inner], above[inner] = stats.norm.cdf(z[inner]), stats.norm.sf(z[inner])
    below[ok & ((value > 1) | ((value == 1) & (k < n)))] = 0.0
    above[ok & ((value < 0) | ((value == 0) & (k > 0)))] = 0.0
    return below, above


def order_tails(less, at_most, n, level) -> tuple[np.ndarray, np.ndarray]:
    """``(below, above)``: the one-sided p-values of the binomial (sign) test of the ``level``
    quantile of ``n`` values against a value, ``less`` of them below it and ``at_most`` at or
    below it (Conover 1999, §3.2: ``scipy.stats.quantile_test``'s ``less`` and ``greater``
    p-values, ``P(B >= less)`` and ``P(B <= at_most)``, B ~ Binomial(n, level)) — the test whose
    inversion is that function's order-statistic interval, so ``below`` is the smallest ``a`` at
    which its interval at confidence ``1 − 2a`` lies below the value. An interval needs both its
    order statistics: no ``a`` below ``(1 − level)^n`` (its lower end) or ``level^n`` (its upper
    end) gives one, so neither p-value is below those. Arrays broadcast."""
    less, at_most, n, level = np.broadcast_arrays(*(np.asarray(a, np.float64) for a in (less, at_most, n, level)))
    ends = np.maximum((1 - level) ** n * (1 + 1e-12), level ** n)  # both order statistics exist
    none = n < 1
    below = np.where(none, 1.0, np.maximum(stats.binom.sf(less - 1, n, level), ends))
    above = np.where(none, 1.0, np.maximum(stats.binom.cdf(at_most, n, level), ends))
    return below, above


class Holm(NamedTuple):
    """What :func:`holm` decided, each array in the order given: ``rejected`` (bool), the one-sided
    ``level`` each hypothesis was tested at (a rejected one: its step's; the others: the level at
    which the procedure stopped), the ``adjusted`` p-values (the smallest family-wise error at
    which each is rejected) and ``tests``, the family's total weight."""

    rejected: np.ndarray
    level: np.ndarray
    adjusted: np.ndarray
    tests: np.ndarray


def holm(p, weights=1.0, totals=None, alpha: float = FAMILY_ERROR, *, step_down: bool = True) -> Holm:
    """Holm's sequentially rejective Bonferroni procedure (Holm 1979, Scand. J. Statist. 6:65–70),
    weighted, over the last axis of ``p``: hypothesis i, of weight ``w_i``, is rejected at step j
    when ``p_i / w_i <= alpha / W_j``, the hypotheses taken in order of ``p_i / w_i`` and ``W_j``
    the total weight not yet rejected; the first that is not stops the procedure. With weight 1
    this is the textbook procedure, and the family-wise error (the chance of rejecting any true
    hypothesis) is at most ``alpha`` whatever the dependence between the tests.

    ``p``: per-weight p-values ``p_i / w_i`` (leading axes: independent families, as in a
    simulation). ``totals``: each unit's weight in ``W`` (default ``weights``), of which a
    rejection takes off ``weights`` — for a unit standing for several hypotheses of which one at
    most is rejected, ``totals`` the most weight of them that can be true at once and ``weights``
    how much less can be once one is rejected (Shaffer 1986, J. Amer. Statist. Assoc. 81:826–831:
    Holm's count lowered by the hypotheses' logical relations keeps the error at most ``alpha``).
    ``step_down=False``: Bonferroni (every unit tested at ``alpha / W``)."""
    p = np.asarray(p, np.float64)
    w = np.broadcast_to(np.asarray(weights, np.float64), p.shape)
    tot = w if totals is None else np.broadcast_to(np.asarray(totals, np.float64), p.shape)
    total = tot.sum(axis=-1, keepdims=True)
    if not step_down:
        level = np.broadcast_to(alpha / total, p.shape).copy()
        return Holm(p <= level, level, np.minimum(1.0, p * total), total[..., 0])
    order = np.argsort(p, axis=-1, kind="stable")
    ps, ws = np.take_along_axis(p, order, -1), np.take_along_axis(w, order, -1)
    left = total - (np.cumsum(ws, axis=-1) - ws)  # the weight not yet rejected at each step
    rejected = np.logical_and.accumulate(ps <= alpha / left, axis=-1)
    adjusted = np.minimum(1.0, np.maximum.accumulate(ps * left, axis=-1))
    kept = total - np.sum(ws * rejected, axis=-1, keepdims=True)  # 0 only when every hypothesis is rejected
    stop = alpha / np.where(kept > 0, kept, 1.0)
    level = np.where(rejected, alpha / left, stop)
    back = np.argsort(order, axis=-1)
    return Holm(*(np.take_along_axis(a, back, -1) for a in (rejected, level, adjusted)), total[..., 0])
