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

Both return :class:`typing.NamedTuple` records, which compare equal to plain tuples.
Pure functions of numbers; no pandas, no JAX.
"""

from __future__ import annotations

import math
from typing import Iterable, NamedTuple

import numpy as np
from scipy import stats

__all__ = ["CONFIDENCE", "MeanCI", "Interval", "t_critical", "mean_ci", "wilson_interval", "chi2_band",
           "consistency", "CONSISTENCY", "floor_multiple"]

#: What :func:`consistency` says of an average NEES or NIS against its band.
CONSISTENCY = ("consistent", "over-confident", "under-confident")

#: Confidence level of every interval in the report.
CONFIDENCE = 0.95


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
