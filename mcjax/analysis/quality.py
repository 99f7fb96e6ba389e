"""How good is a filter, in the report: its consistency (average NEES and NIS against their χ²
bands) and its error as a multiple of the error floor (the posterior Cramér–Rao bound), as one
table — one row per design point and filter (a point is one combination of every swept axis,
never runs pooled across points) — with one legend, and one sentence each for "What this shows".

* consistency: per filter and point, the mean over the runs that did not diverge of the run's
  average NEES (the column with role ``"nees"``, its χ² degrees of freedom declared with it) against
  :func:`mcjax.analysis.statistics.chi2_band` for that many runs, named by
  :func:`mcjax.analysis.statistics.consistency`; likewise the NIS (role ``"nis"``). A diverged
  run's NEES measures the divergence, not the filter's honesty about its error: those runs are
  left out and their share named; where more than :data:`NOT_JUDGED_ABOVE` of the runs diverged
  the runs left are a selected minority and no verdict is given ("not judged: 99 % of runs
  diverged"). The band is that of N independent NEES values of one agent at one step; a run's
  value averages over agents and steps, which only narrows its spread when the filter is
  consistent, so the band is conservative: an average outside it is outside the narrower true
  band too.
* the floor: per filter and point, :func:`mcjax.analysis.statistics.floor_multiple` of the error
  column (role ``"error"``, a per-run RMS) over the floor column (role ``"floor"``, the bound's RMS
  along the same run), with its interval, over every run (the bound is on the mean squared error
  over all runs: leaving the diverged ones out could put a correct filter below it). Below 1 (its
  interval wholly below) would be a bug, and is said so.

:func:`quality_table` gives the table (and :func:`legend` its legend), :func:`quality_sentences`
the box's sentences. Read from the metadata's declarations; nothing names a scenario, a filter or
a unit. No JAX, no matplotlib.
"""

from __future__ import annotations

import math
from typing import Any, Callable, NamedTuple, Sequence

import numpy as np
import pandas as pd

from mcjax.analysis import tables
from mcjax.analysis.statistics import (
    CONFIDENCE,
    CONSISTENCY,
    MeanCI,
    chi2_band,
    consistency,
    floor_multiple,
)

__all__ = ["NOT_JUDGED_ABOVE", "point_labels", "same_value", "rows_at", "Judged", "quality_rows", "quality_table",
           "legend", "quality_sentences"]

#: Where more than this share of a filter's runs at a point diverged, its consistency is not judged.
NOT_JUDGED_ABOVE = 0.5

_PCT = f"{100 * CONFIDENCE:g} %"
_STATS = (("nees", "NEES"), ("nis", "NIS"))


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


def rows_at(data: pd.DataFrame, axes: Sequence[str], key: tuple) -> pd.DataFrame:
    """The rows of ``data`` at one design point (``key``: the values of ``axes``)."""
    if not axes:
        return data
    mask = np.ones(len(data), bool)
    for a, v in zip(axes, key):
        mask &= same_value(data[a], v)
    return data[mask]


def _share(k: int, n: int) -> str:
    """``k`` of ``n`` in whole percent, never rounded to 0 % or 100 % when it is neither."""
    if k == n:
        return "100 %"
    return f"{min(max(round(100 * k / n), 1 if k else 0), 99)} %"


class Judged(NamedTuple):
    """A filter's average NEES (or NIS) at a point: over ``runs`` runs that did not diverge (of
    ``of``; ``diverged`` left out), its ``band`` for that many runs and the ``verdict`` — one of
    :data:`mcjax.analysis.statistics.CONSISTENCY`, or ``"not judged: 99 % of runs diverged"``."""

    average: float
    runs: int
    of: int
    diverged: int
    band: Any
    verdict: str

    @property
    def judged(self) -> bool:
        return not self.verdict.startswith("not judged")


def _judge(rows: pd.DataFrame, col: str, dof: int, divergence: str | None) -> Judged | None:
    v = pd.to_numeric(rows[col], errors="coerce").to_numpy(float)
    div = (pd.array(rows[divergence], dtype="boolean").fillna(False).to_numpy(dtype=bool) if divergence
           else np.zeros(len(v), bool))
    n, k = len(v), int(div.sum())
    kept = v[~div & np.isfinite(v)]
    if n == 0 or (kept.size == 0 and k < n):
        return None
    if k / n > NOT_JUDGED_ABOVE or kept.size == 0:
        avg = float(kept.mean()) if kept.size else math.nan
        band = chi2_band(dof, kept.size) if kept.size else None
        return Judged(avg, int(kept.size), n, k, band, f"not judged: {_share(k, n)} of runs diverged")
    band = chi2_band(dof, kept.size)
    return Judged(float(kept.mean()), int(kept.size), n, k, band, consistency(float(kept.mean()), band))


def _stats(sch: tables.Schema, data: pd.DataFrame) -> list[tuple[str, str, str, int]]:
    """``(role, word, column, dof)`` of each declared NEES / NIS present in ``data``."""
    out = []
    for role, word in _STATS:
        col = getattr(sch, role)
        if col is None or col not in data.columns:
            continue
        dof = int(sch.outputs[col].get("dof") or 0)
        if dof >= 1:
            out.append((role, word, col, dof))
    return out


def quality_rows(data: pd.DataFrame, sch: tables.Schema, axes: Sequence[str],
                 filters: Sequence[str]) -> list[dict]:
    """Per design point and filter: ``{"point": key, "filter": f, "nees": Judged | None, "nis": ...,
    "floor": MeanCI | None}`` (module docstring); empty when the dataset declares none of them."""
    stats = _stats(sch, data)
    floor = sch.floor if sch.floor is not None and sch.floor in data.columns else None
    if not stats and floor is None:
        return []
    out = []
    for key, _ in point_labels(data, axes, lambda a, v: ""):
        rows = rows_at(data, axes, key)
        for f in filters:
            r = rows[rows["filter"] == f]
            if r.empty:
                continue
            entry: dict = {"point": key, "filter": f}
            for role, _, col, dof in stats:
                entry[role] = _judge(r, col, dof, sch.divergence)
            if floor is not None:
                m = floor_multiple(pd.to_numeric(r[sch.error], errors="coerce").to_numpy(float),
                                   pd.to_numeric(r[floor], errors="coerce").to_numpy(float))
                entry["floor"] = m if math.isfinite(m.mean) else None
            out.append(entry)
    return out


def _multiple(m: MeanCI | None) -> str:
    if m is None:
        return "—"
    if math.isfinite(m.low) and math.isfinite(m.high):
        return f"{_number(m.mean)}× [{_number(m.low)}, {_number(m.high)}]"
    return f"{_number(m.mean)}× (no interval)"


def quality_table(data: pd.DataFrame, sch: tables.Schema, axes: Sequence[str],
                  filters: Sequence[str], entries: list[dict] | None = None) -> pd.DataFrame | None:
    """The table (None when the dataset has neither a NEES, a NIS nor a floor): the axes' values
    (as in the runs), ``filter``, then per declared statistic its average, the band for that many runs
    and the verdict, and ``runs judged`` ("93 of 100 (7 % diverged, left out)"); ``RMSE / floor`` with a floor.
    ``entries``: :func:`quality_rows` of the same arguments, when computed already."""
    entries = quality_rows(data, sch, axes, filters) if entries is None else entries
    if not entries:
        return None
    stats = _stats(sch, data)
    rows = []
    for e in entries:
        row: dict = {a: v for a, v in zip(axes, e["point"])}
        row["filter"] = e["filter"]
        judged = [e[role] for role, *_ in stats if e.get(role) is not None]
        if stats:
            j = judged[0] if judged else None
            row["runs judged"] = ("—" if j is None else f"{j.runs} of {j.of}"
                                  + (f" ({_share(j.diverged, j.of)} diverged, left out)" if j.diverged else ""))
        for role, word, _, dof in stats:
            j = e.get(role)
            row[f"average {word}"] = "—" if j is None or not math.isfinite(j.average) else _number(j.average)
            row[f"{word} band ({dof} dof)"] = (
                "—" if j is None or j.band is None else f"[{_number(j.band.low)}, {_number(j.band.high)}]")
            row[f"{word} verdict"] = "—" if j is None else j.verdict
        if "floor" in e:
            row["RMSE / floor"] = _multiple(e["floor"])
        rows.append(row)
    return pd.DataFrame(rows)


def legend(sch: tables.Schema, data: pd.DataFrame) -> list[str]:
    """The table's one legend: what each column is, what was computed and what is not in the dataset."""
    out = []
    stats = _stats(sch, data)
    for role, word, col, dof in stats:
        out.append(f"average {word} ({col}, {dof} dof): computed in every run of this dataset; the mean over the runs "
                   f"judged of each run's average. A consistent filter's mean over N runs lies in the {_PCT} χ² band "
                   f"for N runs (Bar-Shalom, Li & Kirubarajan 2001, §5.4): above it over-confident (its errors are "
                   f"larger than its covariance says), below it under-confident (smaller).")
    for role, word in _STATS:
        if role not in [s[0] for s in stats]:
            out.append(f"average {word}: not computed in this dataset (no output declares it).")
    if stats:
        out.append(f"Judged over the runs that did not diverge{f' ({sch.divergence} false)' if sch.divergence else ''}: "
                   f"a diverged run's value measures the divergence, not the filter's honesty. Where more than "
                   f"{100 * NOT_JUDGED_ABOVE:g} % of the runs diverged, the runs left are a selected minority: "
                   f"not judged.")
    if sch.floor is not None and sch.floor in data.columns:
        out.append(f"RMSE / floor: the RMS of {sch.error} over every run of the point as a multiple of the RMS of the "
                   f"error floor ({sch.floor}, the posterior Cramér–Rao bound along the same runs), with its {_PCT} "
                   f"interval; below 1 (the interval wholly below) is impossible for a correct bound: a bug.")
    else:
        out.append("RMSE / floor: the error floor is not computed in this dataset (no output declares it).")
    return out


def _tally(entries: list[dict], role: str, n_points: int) -> str:
    """Per filter, its verdicts over the points ("over-confident at 2 points, not judged at 2"),
    filters with the same words named together."""
    words: dict[str, list[str]] = {}
    for f in dict.fromkeys(e["filter"] for e in entries):
        counts: dict[str, int] = {}
        for e in entries:
            j = e.get(role)
            if e["filter"] == f and j is not None:
                key = j.verdict if j.judged else "not judged"
                counts[key] = counts.get(key, 0) + 1
        if not counts:
            continue
        counts = {k: counts[k] for k in (*CONSISTENCY, "not judged") if k in counts}
        if n_points == 1:
            said = next(iter(counts))
        elif len(counts) == 1 and sum(counts.values()) == n_points:
            said = f"{next(iter(counts))} at every point"
        else:
            said = ", ".join(f"{k} at {c} point{'s' if c > 1 else ''}" for k, c in counts.items())
        words.setdefault(said, []).append(f)
    return "; ".join(f"{_listing(fs)} {said}" for said, fs in words.items())


def _listing(items: Sequence[str]) -> str:
    items = list(items)
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def quality_sentences(data: pd.DataFrame, sch: tables.Schema, axes: Sequence[str], filters: Sequence[str],
                      text: Callable[[str, Any], str], entries: list[dict] | None = None) -> list[tuple[str, str]]:
    """The box's sentences, ``(kind, text)``: one about consistency (each filter's verdicts tallied over
    the points, both statistics) and one about the floor (each filter's multiple, its range over the
    points, and any below 1 named as a bug); the rest is in :func:`quality_table`. ``text(axis, value)``: a
    value's display; ``entries``: :func:`quality_rows` of the same arguments, when computed already."""
    entries = quality_rows(data, sch, axes, filters) if entries is None else entries
    if not entries:
        return []
    points = list(dict.fromkeys(e["point"] for e in entries))
    n = len(points)
    out = []
    stats = _stats(sch, data)
    parts = []
    for role, word, _, dof in stats:
        said = _tally(entries, role, n)
        if said:
            parts.append(f"average {word} ({dof} dof): {said}" if len(stats) > 1 else said)
    if parts:
        what = "average " + " and ".join(w for _, w, *_ in stats) if len(stats) > 1 else \
            f"average {stats[0][1]}, {stats[0][3]} dof"
        left = any(j.diverged for e in entries for r, *_ in stats if (j := e.get(r)) is not None)
        skipped = any(not j.judged for e in entries for r, *_ in stats if (j := e.get(r)) is not None)
        out.append(("consistency", f"Consistency ({what}, against the {_PCT} χ² band for that many runs"
                    + (", over the runs that did not diverge" if left else "")
                    + (f", not judged where more than {100 * NOT_JUDGED_ABOVE:g} % of a filter's runs diverged"
                       if skipped else "")
                    + "; per filter and point in the table below): " + "; ".join(parts) + "."))
    floors = [e for e in entries if e.get("floor") is not None]
    if floors:
        parts, below = [], []
        for f in dict.fromkeys(e["filter"] for e in floors):
            ms = [e for e in floors if e["filter"] == f]
            lo = min(ms, key=lambda e: e["floor"].mean)
            hi = max(ms, key=lambda e: e["floor"].mean)
            parts.append(f"{f} {_multiple(lo['floor'])}" if lo is hi else
                         f"{f} from {_multiple(lo['floor'])} to {_multiple(hi['floor'])}")
            below += [(f, e["point"]) for e in ms if math.isfinite(e["floor"].high) and e["floor"].high < 1]
        sentence = (f"Each filter's RMS error as a multiple of the error floor (the posterior Cramér–Rao bound"
                    f"{'; its lowest and highest over the design points' if n > 1 else ''}): " + "; ".join(parts))
        if below:
            where = [f + (" at " + ", ".join(f"{a} = {text(a, v)}" for a, v in zip(axes, p)) if axes else "")
                     for f, p in below]
            sentence += ("; below the floor, impossible for a correct bound (a bug to report, not a finding): "
                         + _listing(where))
        out.append(("floor", sentence + "."))
    return out
