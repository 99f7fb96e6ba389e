"""How good is a filter, in "What this shows": its consistency (average NEES and NIS against their
χ² bands) and its error as a multiple of the error floor (the posterior Cramér–Rao bound), one
sentence per design point — a point is one combination of every swept axis, never runs pooled
across points.

* consistency: per filter, the mean over the point's runs of the run's average NEES (the column
  with role ``"nees"``, its χ² degrees of freedom declared with it) against
  :func:`mcjax.analysis.statistics.chi2_band` for that many runs, named by
  :func:`mcjax.analysis.statistics.consistency`; likewise the NIS (role ``"nis"``). The band is that of N
  independent NEES values of one agent at one step; a run's value averages over agents and steps,
  which only narrows its spread when the filter is consistent, so the band is conservative: an
  average outside it is outside the narrower true band too.
* the floor: per filter, :func:`mcjax.analysis.statistics.floor_multiple` of the error column (role
  ``"error"``, a per-run RMS) over the floor column (role ``"floor"``, the bound's RMS along the
  same run), with its interval. The bound is on the mean squared error over runs, so the multiple
  is of the RMS over runs; below 1 (its interval wholly below) would be a bug, and is said so.

Read from the metadata's declarations; nothing names a scenario, a filter or a unit. No JAX,
no matplotlib.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Sequence

import numpy as np
import pandas as pd

from mcjax.analysis import tables
from mcjax.analysis.statistics import chi2_band, consistency, floor_multiple

__all__ = ["point_labels", "same_value", "consistency_sentences", "floor_sentences"]


def _number(x: float) -> str:
    return tables.format_number(x, tables.STAT_DIGITS)


def point_labels(data: pd.DataFrame, axes: Sequence[str], text: Callable[[str, Any], str]) -> list[tuple[Any, str]]:
    """The design points of ``data`` (one per combination of ``axes``' values, in order of first
    appearance sorted where the values allow) as ``(key, "at a = 1, b = 2")`` with ``text(axis, value)``
    the value's display; a single point (no axes) is ``((), "")``."""
    if not axes:
        return [((), "")]
    keys = list(data[list(axes)].drop_duplicates().itertuples(index=False, name=None))
    try:
        keys = sorted(keys)
    except TypeError:
        pass
    return [(k, "at " + ", ".join(f"{a} = {text(a, v)}" for a, v in zip(axes, k))) for k in keys]


def same_value(column: pd.Series, v: Any) -> np.ndarray:
    """Which cells of ``column`` hold ``v`` (a per-agent tuple compared whole; NaN matches NaN)."""
    if isinstance(v, float) and math.isnan(v):
        return column.isna().to_numpy()
    return column.map(lambda x: x == v).to_numpy(dtype=bool)


def _rows(data: pd.DataFrame, axes: Sequence[str], key: tuple) -> pd.DataFrame:
    if not axes:
        return data
    mask = np.ones(len(data), bool)
    for a, v in zip(axes, key):
        mask &= same_value(data[a], v)
    return data[mask]


#: Beyond this many design points the consistency of each filter is tallied over them in one sentence.
MAX_POINTS = 12


def _tally(data, axes, points, filters, col, dof, what) -> str:
    """How many of the design points find each filter consistent, over- and under-confident."""
    parts = []
    for f in filters:
        counts = dict.fromkeys(("consistent", "over-confident", "under-confident"), 0)
        for key, _ in points:
            rows = _rows(data, axes, key)
            v = pd.to_numeric(rows.loc[rows["filter"] == f, col], errors="coerce").to_numpy(float)
            v = v[np.isfinite(v)]
            if v.size:
                counts[consistency(float(v.mean()), chi2_band(dof, v.size))] += 1
        parts.append(f"{f} " + ", ".join(f"{k} at {n}" for k, n in counts.items() if n))
    return (f"Consistency over the {len(points)} design points (average {what}, {dof} dof, each point against the "
            f"band of its number of runs): " + "; ".join(parts) + ".")


def consistency_sentences(data: pd.DataFrame, sch: tables.Schema, axes: Sequence[str], filters: Sequence[str],
                          text: Callable[[str, Any], str]) -> list[str]:
    """One sentence per design point and declared statistic (NEES, NIS): each filter's average with
    where it lies against the band (module docstring)."""
    out = []
    for role, what in (("nees", "NEES"), ("nis", "NIS")):
        col = getattr(sch, role)
        if col is None or col not in data.columns:
            continue
        dof = int(sch.outputs[col].get("dof") or 0)
        if dof < 1:
            continue
        points = point_labels(data, axes, text)
        if len(points) > MAX_POINTS:  # one sentence counting each filter's verdicts over the points
            out.append(_tally(data, axes, points, filters, col, dof, what))
            continue
        for key, where in points:
            rows = _rows(data, axes, key)
            parts, sizes = [], set()
            for f in filters:
                v = pd.to_numeric(rows.loc[rows["filter"] == f, col], errors="coerce").to_numpy(float)
                v = v[np.isfinite(v)]
                if v.size == 0:
                    continue
                band = chi2_band(dof, v.size)
                sizes.add((v.size, band))
                verdict = consistency(float(v.mean()), band)
                parts.append(f"{f} {_number(float(v.mean()))}, {verdict}")
            if not parts:
                continue
            if len(sizes) == 1:
                (n, band), = sizes
                head = (f"a consistent filter's average over {n} runs lies in "
                        f"[{_number(band.low)}, {_number(band.high)}]")
            else:
                head = "the band depends on each filter's number of finite runs"
            out.append(f"Consistency{(' ' + where) if where else ''} (average {what}, {dof} dof; {head}): "
                       + "; ".join(parts) + " (over-confident: larger errors than the filter's covariance says; "
                       "under-confident: smaller).")
    return out


def floor_sentences(data: pd.DataFrame, sch: tables.Schema, axes: Sequence[str], filters: Sequence[str],
                    text: Callable[[str, Any], str]) -> list[str]:
    """One sentence per design point: each filter's RMS error as a multiple of the floor's, with its
    interval (module docstring)."""
    col, err = sch.floor, sch.error
    if col is None or col not in data.columns:
        return []
    unit = tables.unit(col, sch)
    out = []
    for key, where in point_labels(data, axes, text):
        rows = _rows(data, axes, key)
        parts, below = [], []
        floor_rms = None
        for f in filters:
            r = rows[rows["filter"] == f]
            e = pd.to_numeric(r[err], errors="coerce").to_numpy(float)
            b = pd.to_numeric(r[col], errors="coerce").to_numpy(float)
            m = floor_multiple(e, b)
            if not math.isfinite(m.mean):
                continue
            ok = np.isfinite(b)
            floor_rms = float(np.sqrt(np.mean(b[ok] ** 2)))
            interval = (f" [{_number(m.low)}, {_number(m.high)}]" if math.isfinite(m.low) and math.isfinite(m.high)
                        else " (no interval)")
            parts.append(f"{f} {_number(m.mean)}×{interval}")
            if math.isfinite(m.high) and m.high < 1:
                below.append(f)
        if not parts:
            continue
        u = f" {unit}" if unit else ""
        sentence = (f"Against the error floor{(' ' + where) if where else ''} (the posterior Cramér–Rao bound of "
                    f"every agent's measurements, RMS {_number(floor_rms)}{u} over the runs), each filter's RMS "
                    f"error is: " + "; ".join(parts) + ".")
        if below:
            sentence += (f" {', '.join(below)} below the floor is impossible for a correct bound: a bug to report, "
                         "not a finding.")
        out.append(sentence)
    return out
