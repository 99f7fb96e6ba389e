"""The report's "What this shows": sentences about a sweep generated from its data, each
backed by the intervals it quotes (the glossary and the base Params table beside them:
:mod:`mcjax.report.glossary`).

* :func:`findings` -- per swept axis, two to four :class:`Finding` sentences: which filter
  has the lowest mean error where, how the error changes along the axis, where runs diverge,
  where the comm graph disconnects. Every number comes with its 95 % interval.
* :func:`percent` -- a rate with its interval as ``"2.0 % [0.6, 7.0]"``.

The rule of every sentence: an order between two filters (or between two values of an axis)
is stated only when their 95 % intervals do not overlap -- the mean error's Student-t
intervals, the divergence rate's Wilson intervals. Separate intervals are a conservative
test (two means whose intervals touch may still differ); where they overlap the sentence
says so and claims no order. Counts ("no run diverged") are stated as counts, with the
upper end of the rate's interval. :class:`Finding` keeps each order it claims, so a test
can check every claim against the intervals.

Everything is read from the dataset's metadata (the scenario's declarations): nothing
here names a scenario, a filter or a unit. This module imports neither JAX nor matplotlib.
"""

from __future__ import annotations

import math
import re
from typing import Any, Mapping, NamedTuple, Sequence

import numpy as np
import pandas as pd

from mcjax.analysis import quality, tables
from mcjax.analysis.statistics import CONFIDENCE, mean_ci, wilson_interval
from mcjax.analysis.summary import Summary, summary_for

__all__ = ["PCT", "Finding", "findings", "percent", "quote"]

PCT = f"{100 * CONFIDENCE:g} %"


class Finding(NamedTuple):
    """One sentence of "What this shows": the swept axis it is about, its text, the orders it
    claims -- ``(lower, higher, where)``: filter ``lower``'s statistic is below filter
    ``higher``'s at the axis value ``where``, their intervals apart -- and its kind:
    ``"lowest"`` (the mean error's order), ``"trend"``, ``"divergence"`` (orders of the
    divergence rate), ``"graph"``, ``"consistency"`` or ``"floor"`` (per design point,
    :mod:`mcjax.analysis.quality`)."""

    axis: str
    text: str
    orders: tuple[tuple[str, str, Any], ...] = ()
    kind: str = "lowest"
    panel: tuple[tuple[str, Any], ...] = ()   # the other swept axes' values the sentence is about


def percent(rate: float, low: float, high: float) -> str:
    """A rate with its interval in percent, one decimal: ``"2.0 % [0.6, 7.0]"``."""
    if not math.isfinite(rate):
        return "nan"
    if not (math.isfinite(low) and math.isfinite(high)):
        return f"{100 * rate:.1f} %"
    return f"{100 * rate:.1f} % [{100 * low:.1f}, {100 * high:.1f}]"


def quote(mean: float, low: float, high: float, unit: str = "", every: str = "every run") -> str:
    """A mean with its interval in the tables' number format: ``"11.09 m [10.96, 11.22]"``; an interval of
    zero width (every value the same: ``every`` names them) says so: ``"every run: 17 steps"``."""
    u = f" {unit}" if unit else ""
    m = tables.format_number(mean, tables.STAT_DIGITS)
    if not (math.isfinite(low) and math.isfinite(high)):
        return f"{m}{u} (no interval)"
    if low == high:
        return f"{every}: {m}{u}"
    return f"{m}{u} [{tables.format_number(low, tables.STAT_DIGITS)}, {tables.format_number(high, tables.STAT_DIGITS)}]"


def _apart(lo_a: float, hi_a: float, lo_b: float, hi_b: float) -> bool:
    """Interval a lies wholly below interval b (both finite)."""
    return all(math.isfinite(x) for x in (lo_a, hi_a, lo_b, hi_b)) and hi_a < lo_b


def _listing(items: Sequence[str]) -> str:
    items = list(items)
    if len(items) <= 1:
        return "".join(items)
    return ", ".join(items[:-1]) + " and " + items[-1]


class _Axis(NamedTuple):
    name: str
    values: list
    unit: str
    factor: float

    def text(self, value: Any) -> str:
        """A value in the axis' display unit (a per-agent tuple element-wise), as the plots show it."""
        def scaled(v):
            if isinstance(v, (tuple, list)):
                return tuple(scaled(x) for x in v)
            if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_)):
                return float(v) * self.factor if self.factor != 1.0 else v
            return v
        return tables.format_number(scaled(value), 4) + (f" {self.unit}" if self.unit else "")

    def texts(self, values: Sequence[Any]) -> str:
        return _listing([self.text(v) for v in values])


def _sorted_values(series: pd.Series) -> list:
    values = list(pd.unique(series))
    try:
        return sorted(values)
    except TypeError:
        return values


def _lowest_error(s: pd.DataFrame, ax: _Axis, sch: tables.Schema, filters: list, unit: str,
                  pooled: str) -> Finding | None:
    """Which filter has the lowest mean error at which values of the axis."""
    e = sch.error
    winners: dict[Any, str | None] = {}
    overlaps: dict[Any, list[str]] = {}
    orders: list[tuple[str, str, Any]] = []
    chains: dict[Any, list[str]] = {}
    for v in ax.values:
        rows = s[s[ax.name].map(lambda x, v=v: x == v)].set_index("filter")
        rows = rows.loc[[f for f in filters if f in rows.index]]
        if len(rows) < 2:
            return None
        rows = rows.sort_values(f"{e}_mean")
        means, los, his = (rows[c].to_numpy(dtype=float) for c in (f"{e}_mean", f"{e}_ci_low", f"{e}_ci_high"))
        names = [str(f) for f in rows.index]
        for i in range(len(names)):
            for j in range(len(names)):
                if i != j and _apart(los[i], his[i], los[j], his[j]):
                    orders.append((names[i], names[j], v))
        best = names[0]
        clear = all(_apart(los[0], his[0], los[j], his[j]) for j in range(1, len(names)))
        winners[v] = best if clear else None
        if not clear:
            overlaps[v] = [n for j, n in enumerate(names[1:], 1) if not _apart(los[0], his[0], los[j], his[j])]
            overlaps[v].insert(0, best)
        elif all(_apart(los[j], his[j], los[j + 1], his[j + 1]) for j in range(len(names) - 1)):
            chains[v] = names
    parts = []
    for w in dict.fromkeys(x for x in winners.values() if x is not None):
        where = [v for v, x in winners.items() if x == w]
        at = max(where, key=lambda v: _gap(s, ax, v, w, e))  # where its lead is largest
        r = s[(s[ax.name].map(lambda x, at=at: x == at)) & (s["filter"] == w)].iloc[0]
        if at in chains and len(chains[at]) > 2:
            rows = s[s[ax.name].map(lambda x, at=at: x == at)].set_index("filter")
            chain = " < ".join(f"{f} {quote(rows.loc[f, f'{e}_mean'], rows.loc[f, f'{e}_ci_low'], rows.loc[f, f'{e}_ci_high'], unit)}"
                               for f in chains[at])
            detail = f"at {ax.text(at)} the whole order is apart: {chain}"
        else:
            rows = s[s[ax.name].map(lambda x, at=at: x == at)].set_index("filter")
            others = rows.drop(index=w).sort_values(f"{e}_mean")
            nxt = others.index[0]
            detail = (f"at {ax.text(at)} {quote(r[f'{e}_mean'], r[f'{e}_ci_low'], r[f'{e}_ci_high'], unit)} "
                      f"against {quote(others.loc[nxt, f'{e}_mean'], others.loc[nxt, f'{e}_ci_low'], others.loc[nxt, f'{e}_ci_high'], unit)} "
                      f"for the next lowest, {nxt}")
        parts.append(f"{w} at {ax.name} = {ax.texts(where)} ({detail})")
    said = "; ".join(f"at {ax.text(v)} {_listing(n)} overlap" for v, n in overlaps.items())
    if not parts:
        text = f"{pooled}No filter's mean {e} lies below all the others' beyond the {PCT} intervals ({said})"
    else:
        if overlaps:
            parts.append(f"elsewhere the {PCT} intervals of the lowest means overlap, so no filter is named "
                         f"lowest ({said})")
        text = f"{pooled}Lowest mean {e}: " + "; ".join(parts)
    return Finding(ax.name, text + ".", tuple(orders))


def _gap(s: pd.DataFrame, ax: _Axis, v: Any, winner: str, e: str) -> float:
    """How many times the winner's mean error the next lowest's is, at axis value ``v``."""
    rows = s[s[ax.name].map(lambda x: x == v)].set_index("filter")[f"{e}_mean"].astype(float)
    best, rest = rows.get(winner), rows.drop(index=winner)
    if rest.empty or not best or not math.isfinite(best):
        return 0.0
    return float(rest.min() / best) if best > 0 else math.inf


def _trend(s: pd.DataFrame, ax: _Axis, sch: tables.Schema, filters: list, unit: str, pooled: str) -> Finding | None:
    """How the error of each filter changes between the axis' first and last value."""
    e = sch.error
    first, last = ax.values[0], ax.values[-1]
    moves: dict[str, list[str]] = {"falls": [], "rises": []}
    still = []
    for f in filters:
        a = s[(s[ax.name].map(lambda x: x == first)) & (s["filter"] == f)]
        b = s[(s[ax.name].map(lambda x: x == last)) & (s["filter"] == f)]
        if a.empty or b.empty:
            continue
        a, b = a.iloc[0], b.iloc[0]
        qa = quote(a[f"{e}_mean"], a[f"{e}_ci_low"], a[f"{e}_ci_high"], unit)
        qb = quote(b[f"{e}_mean"], b[f"{e}_ci_low"], b[f"{e}_ci_high"], unit)
        lo_a, hi_a, lo_b, hi_b = (float(a[f"{e}_ci_low"]), float(a[f"{e}_ci_high"]),
                                  float(b[f"{e}_ci_low"]), float(b[f"{e}_ci_high"]))
        if _apart(lo_b, hi_b, lo_a, hi_a):
            moves["falls"].append(f"{f}'s from {qa} to {qb}")
        elif _apart(lo_a, hi_a, lo_b, hi_b):
            moves["rises"].append(f"{f}'s from {qa} to {qb}")
        else:
            still.append(f)
    if not any(moves.values()) and not still:
        return None
    said = [f"the mean {e} {way}{' for every filter' if len(m) == len(filters) else ''}: " + "; ".join(m)
            for way, m in moves.items() if m]
    if still:
        said.append(f"the mean {e} of {_listing(still)} does not change beyond the {PCT} intervals (those at the "
                    f"two ends overlap)")
    text = f"From {ax.name} = {ax.text(first)} to {ax.text(last)} " + "; ".join(said)
    return Finding(ax.name, (pooled + text)[0].upper() + (pooled + text)[1:] + ".", kind="trend")


def _rates_at(s: pd.DataFrame, ax: _Axis, v: Any, filters: list) -> str:
    rows = s[s[ax.name].map(lambda x: x == v)].set_index("filter")
    return ", ".join(f"{f} {percent(rows.loc[f, 'div_rate'], rows.loc[f, 'div_ci_low'], rows.loc[f, 'div_ci_high'])}"
                     for f in filters if f in rows.index)


def _divergence(s: pd.DataFrame, ax: _Axis, sch: tables.Schema, filters: list, pooled: str) -> Finding | None:
    """At which values of the axis runs diverge, with the rates at the edge."""
    if not sch.divergence:
        return None
    k = s.groupby(ax.name, sort=False)["diverged"].sum()
    seen = [v for v in ax.values if k.get(v, 0) > 0]
    none = [v for v in ax.values if k.get(v, 0) == 0]
    n = s.groupby(ax.name, sort=False)["n"].min()
    if not seen:
        hi = max(wilson_interval(0, int(n.get(v))).high for v in ax.values)
        return Finding(ax.name, f"{pooled}No run of any filter diverged at any {ax.name} (0 runs of "
                                f"{int(n.min())} or more per point and filter; the rate's {PCT} interval ends at "
                                f"{100 * hi:.1f} % or below).", kind="divergence")
    worst = max(seen, key=lambda v: float(s[s[ax.name].map(lambda x: x == v)]["div_rate"].max()))
    spread = {v: float(np.ptp(s[s[ax.name].map(lambda x, v=v: x == v)]["div_rate"].to_numpy(float))) for v in seen}
    apart = max(seen, key=spread.get)  # where the filters' rates differ most
    text = f"{pooled}Runs diverge at {ax.name} = {ax.texts(seen)}"
    if none:
        hi = max(wilson_interval(0, int(n.get(v))).high for v in none)
        text += f" and in none of the runs at {ax.texts(none)} (0 %, the interval up to {100 * hi:.1f} %)"
        edge = None
        if max(ax.values.index(v) for v in seen) < min(ax.values.index(v) for v in none):
            edge = seen[-1]
            text += f"; divergence starts below {ax.text(none[0])}: at {ax.text(edge)} {_rates_at(s, ax, edge, filters)}"
        elif min(ax.values.index(v) for v in seen) > max(ax.values.index(v) for v in none):
            edge = seen[0]
            text += f"; divergence starts above {ax.text(none[-1])}: at {ax.text(edge)} {_rates_at(s, ax, edge, filters)}"
        if worst != edge:
            text += f"; at {ax.text(worst)} {_rates_at(s, ax, worst, filters)}"
    else:
        text += f" (every value); at {ax.text(worst)} {_rates_at(s, ax, worst, filters)}"
        edge = None
    if apart not in (edge, worst) and spread[apart] > 0:
        text += f"; the filters differ most at {ax.text(apart)}: {_rates_at(s, ax, apart, filters)}"
    orders = []
    rows = s[s[ax.name].map(lambda x: x == worst)].sort_values("div_rate")
    if len(rows) > 1:
        lo = rows.iloc[0]
        if all(_apart(lo["div_ci_low"], lo["div_ci_high"], r["div_ci_low"], r["div_ci_high"])
               for _, r in rows.iloc[1:].iterrows()):
            text += f"; there {lo['filter']} diverges least (its interval below the others')"
            orders = [(str(lo["filter"]), str(r["filter"]), worst) for _, r in rows.iloc[1:].iterrows()]
    return Finding(ax.name, text[0].upper() + text[1:] + ".", tuple(orders), "divergence")


def _graph(df: pd.DataFrame, ax: _Axis, sch: tables.Schema, pooled: str) -> Finding | None:
    """Where the comm graph disconnects (runs with a disconnected step), once per run."""
    ds = sch.disconnected_steps
    if not ds:
        return None
    keys = [k for k in ("point_id", "seed_index") if k in df.columns]
    runs = df.drop_duplicates(subset=keys) if len(keys) == 2 else df[df["filter"] == df["filter"].iloc[0]]
    stats = {}
    for v in ax.values:
        g = runs[runs[ax.name].map(lambda x, v=v: x == v)][ds].to_numpy(dtype=float)
        g = g[np.isfinite(g)]
        if g.size == 0:
            continue
        k = int((g > 0).sum())
        stats[v] = (k, g.size, wilson_interval(k, g.size), mean_ci(g))
    if not stats:
        return None
    some = [v for v, st in stats.items() if st[0] > 0]
    none = [v for v, st in stats.items() if st[0] == 0]
    u = tables.unit(ds, sch)

    def at(v):
        k, n, ci, m = stats[v]
        steps = f"{ds}, {quote(m.mean, m.low, m.high, u)}" if m.low == m.high else \
            f"{ds}: mean {quote(m.mean, m.low, m.high, u)} per run"
        return f"at {ax.text(v)} in {percent(k / n, ci.low, ci.high)} of runs ({steps})"

    if not some:
        return Finding(ax.name, f"{pooled}The comm graph stays connected in every run at every {ax.name} "
                                f"({ds} = 0 in all {sum(st[1] for st in stats.values())} runs).", kind="graph")
    text = f"{pooled}The comm graph disconnects at some step " + "; ".join(at(v) for v in some)
    if none:
        hi = max(wilson_interval(0, stats[v][1]).high for v in none)
        text += f", and in no run at {ax.texts(none)} (0 %, the interval up to {100 * hi:.1f} %)"
    return Finding(ax.name, text[0].upper() + text[1:] + ".", kind="graph")


def findings(df: pd.DataFrame, metadata: Mapping[str, Any] | tables.Schema,
             axes: Sequence[str] | None = None, *, summary: Summary | None = None) -> list[Finding]:
    """The sentences of "What this shows" for a runs table: per swept axis with more than one
    value, which filter has the lowest mean error where, how each filter's error changes from
    the axis' first to its last value, where runs diverge and where the comm graph
    disconnects (each when the dataset declares it). With several axes, the sentences about
    one axis are made per panel — each combination of the other axes' values, named at the
    sentence's start and in :attr:`Finding.panel` — never over runs pooled across design points.
    A single point gets the sentence about the filters' order only. The consistency and
    error-floor sentences (:mod:`mcjax.analysis.quality`) are per design point. Filters and axes are named
    by the words the dataset declares for them (``filter_names``, a Param's ``label``), else by
    their code names. ``summary``: the page's :class:`mcjax.analysis.summary.Summary` of ``df``
    (built here when not given)."""
    summary = summary_for(df, metadata, axes, summary)
    sch, data, plot_axes = summary.schema, summary.data, list(summary.plot_axes)
    filters = [str(f) for f in tables.ordered_filters(data["filter"], sch.filters)]
    unit = tables.unit(sch.error, sch)
    out_quality = _quality(data, sch, plot_axes, filters)
    found = _findings(summary, filters, unit, out_quality)
    words = _words(metadata, sch)
    # the sentences name filters and axes by the glossary's words, not their code names
    return [f._replace(text=_in_words(f.text, words)) for f in found] if words else found


def _words(metadata, sch: tables.Schema) -> dict[str, str]:
    """Code name -> words: each filter's declared short name (``filter_names``) and each Param's
    ``label`` (an empty dict for a dataset that declares none)."""
    names = metadata.get("filter_names") if isinstance(metadata, Mapping) else None
    out = {str(k): str(v) for k, v in (names or {}).items() if v}
    for name, decl in (sch.params or {}).items():
        if isinstance(decl, Mapping) and decl.get("label"):
            out[str(name)] = str(decl["label"])
    return out


def _in_words(text: str, words: Mapping[str, str]) -> str:
    """``text`` with every code name of ``words`` standing alone (not inside another name) replaced."""
    for code in sorted(words, key=len, reverse=True):
        text = re.sub(rf"(?<![\w.]){re.escape(code)}(?!\w)", words[code], text)
    return text[0].upper() + text[1:] if text else text


def _findings(summary: Summary, filters: list, unit: str, out_quality: list[Finding]) -> list[Finding]:
    data, sch, plot_axes = summary.data, summary.schema, list(summary.plot_axes)
    if not plot_axes:
        return _point_sentences(summary, filters, unit, ()) + out_quality
    out: list[Finding] = []
    for a in plot_axes:
        shown, factor = tables.display(a, sch)
        others = [o for o in plot_axes if o != a]
        for panel, rows in _panels(data, others):
            values = _sorted_values(rows[a])
            if len(values) < 2:  # nothing varies along a in this panel (e.g. the axes of a zip)
                continue
            ax = _Axis(a, values, shown, factor)
            where = ", ".join(f"{o} = {_Axis(o, [], *tables.display(o, sch)).text(v)}" for o, v in panel)
            prefix = f"With {where}: " if where else ""
            s = summary.at([a], panel)  # tables.summarize(rows, sch, [a]), cut from the page's summary
            for make in (lambda: _lowest_error(s, ax, sch, filters, unit, prefix),
                         lambda: _trend(s, ax, sch, filters, unit, prefix),
                         lambda: _divergence(s, ax, sch, filters, prefix),
                         lambda: _graph(rows, ax, sch, prefix)):
                f = make()
                if f is not None:
                    out.append(f._replace(panel=panel))
    if not out:  # no axis varies alone (a zip): the sentences of each design point
        for panel, _ in _panels(data, plot_axes):
            out += _point_sentences(summary, filters, unit, panel)
    return out + out_quality


def _point_sentences(summary: Summary, filters: list, unit: str, panel: tuple) -> list[Finding]:
    """The filters' order and their divergence rates at one design point (``panel``: its axes'
    values, named first; () for a dataset of one point)."""
    sch = summary.schema
    where = ", ".join(f"{o} = {_Axis(o, [], *tables.display(o, sch)).text(v)}" for o, v in panel)
    prefix = f"At {where}: " if where else ""
    s = summary.at([], panel)  # the point's rows of the page's summary
    s.insert(0, "_point", "this point")
    out = []
    single = _lowest_error(s, _Axis("_point", ["this point"], "", 1.0), sch, filters, unit, "")
    if single is not None:
        text = single.text.replace("at _point = this point ", "").replace("at this point ", "")
        out.append(Finding("", prefix + text, tuple((a, b, None) for a, b, _ in single.orders), panel=panel))
    if sch.divergence:
        ax = _Axis("_point", ["this point"], "", 1.0)
        if int(s["diverged"].sum()):
            text = f"Divergence rate: {_rates_at(s, ax, 'this point', filters)}."
        else:
            hi = wilson_interval(0, int(s["n"].min())).high
            text = (f"No run of any filter diverged (0 of {int(s['n'].min())} or more runs per filter; the "
                    f"rate's {PCT} interval ends at {100 * hi:.1f} %).")
        out.append(Finding("", prefix + text, kind="divergence", panel=panel))
    return out


def _panels(data: pd.DataFrame, others: Sequence[str]) -> list[tuple[tuple, pd.DataFrame]]:
    """The panels of the other swept axes: ``(((axis, value), ...), rows)`` per combination of their
    values (one panel of every row without other axes). Sentences are made per panel: runs at
    different design points are never pooled into one interval."""
    if not others:
        return [((), data)]
    out = []
    for key, rows in data.groupby(list(others), sort=True, dropna=False):
        key = key if isinstance(key, tuple) else (key,)
        out.append((tuple(zip(others, key)), rows))
    return out


def _quality(data: pd.DataFrame, sch: tables.Schema, axes: Sequence[str], filters: list) -> list[Finding]:
    """The consistency and error-floor sentences, one per design point (:mod:`mcjax.analysis.quality`)."""
    shown = {a: _Axis(a, [], *tables.display(a, sch)) for a in axes}

    def text(a, v):
        return shown[a].text(v)

    return ([Finding("", t, kind="consistency") for t in quality.consistency_sentences(data, sch, axes, filters, text)]
            + [Finding("", t, kind="floor") for t in quality.floor_sentences(data, sch, axes, filters, text)])


# ------------------------------------------------------------------------------ glossary
