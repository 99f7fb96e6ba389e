"""The report's "What this shows": sentences about a sweep generated from its data, each
backed by the intervals it quotes (the glossary and the base Params table beside them:
:mod:`mcjax.report.glossary`).

* :func:`box` -- the box: a few :class:`Finding` sentences about the whole sweep (at most ~8 on
  any built-in sweep), the table of the filters' order at each design point and the consistency
  and error-floor table (:mod:`mcjax.analysis.quality`) under them. :func:`findings` -- its
  sentences alone.
* :func:`percent` -- a rate with its interval as ``"2.0 % [0.6, 7.0]"``; :func:`quote` -- a mean
  with its interval.

The sentences, in this order: the scenario's headline comparisons (its metadata's ``headlines``:
pairs of filters, the one expected lower first -- :class:`mcjax.contract.Scenario`), where each
holds; the full order of the filters' mean error at each design point, one clause per order
with the points it holds at ("a < b < c at every radius from 60 to 100 km"),
the exceptions named, the rest in the order table; per swept axis, how each filter's mean error
changes from its first value to its last; where runs diverge; where the comm graph disconnects;
one sentence about consistency and one about the floor. A sentence about several design points
names them compactly -- a range of an axis, a product of ranges, "every point but ..." -- and is
about each of them: runs at different design points are never pooled into one interval.

The rule of every sentence: an order between two filters (or between two values of an axis)
is stated only when their 95 % intervals do not overlap -- the mean error's Student-t
intervals, the divergence rate's Wilson intervals. Separate intervals are a conservative
test (two means whose intervals touch may still differ); where they overlap the sentence
says so and claims no order. In an order, ``<`` stands between two groups of filters only where
every filter before it lies below every filter after it (their intervals apart); filters ``≈``
each other are not ordered. Counts ("no run diverged") are stated as counts, with the upper end
of the rate's interval. :class:`Finding` keeps each order it claims, at its design point, and
each change along an axis, so a test can check every claim against the intervals.

Everything is read from the dataset's metadata (the scenario's declarations): nothing
here names a scenario, a filter or a unit. This module imports neither JAX nor matplotlib.
"""

from __future__ import annotations

import math
import re
from typing import Any, Mapping, NamedTuple, Sequence

import numpy as np
import pandas as pd

from mcjax.analysis import connectivity, quality, tables
from mcjax.analysis.statistics import wilson_interval
from mcjax.analysis.summary import Summary, summary_for
from mcjax.analysis.wording import MAX_CLAUSES, PCT, Grid, Point, apart, listing, ordered, percent, quote
from mcjax.analysis.wording import where as name_points

__all__ = ["PCT", "MAX_CLAUSES", "Finding", "Box", "box", "findings", "headlines", "percent", "quote"]





class Finding(NamedTuple):
    """One sentence of "What this shows": the swept axis it is about ("" for one about the whole
    sweep), its text, the orders it claims -- ``(lower, higher, point)``: filter ``lower``'s
    statistic is below filter ``higher``'s at the design point ``point`` (``((axis, value),
    ...)``), their intervals apart -- and its kind: ``"headline"`` and ``"order"`` (orders of the
    mean error), ``"trend"``, ``"divergence"`` (orders of the divergence rate), ``"graph"``,
    ``"consistency"`` or ``"floor"`` (:mod:`mcjax.analysis.quality`). A trend keeps its changes in
    ``moves``: ``(filter, from_point, to_point, "falls" | "rises")``, the two intervals apart."""

    axis: str
    text: str
    orders: tuple[tuple[str, str, Point], ...] = ()
    kind: str = "order"
    panel: tuple[tuple[str, Any], ...] = ()   # kept for readers of older Findings: always () now
    moves: tuple[tuple[str, Point, Point, str], ...] = ()


class Box(NamedTuple):
    """What "What this shows" holds (:func:`box`)."""

    sentences: list[Finding]
    orders: pd.DataFrame | None    # per design point (its axes' values as in the runs): the filters' order
    quality: pd.DataFrame | None   # quality.quality_table: per point and filter, NEES / NIS verdicts and the floor
    legend: list[str]              # the quality table's one legend (empty without it)


def _space(text: str) -> str:
    return f" {text}" if text else ""


# ------------------------------------------------------------------------------ the sentences


def _interval(rows: pd.DataFrame, f: str, e: str) -> tuple[float, float, float]:
    return (float(rows.loc[f, f"{e}_mean"]), float(rows.loc[f, f"{e}_ci_low"]), float(rows.loc[f, f"{e}_ci_high"]))


def headlines(metadata: Mapping[str, Any] | Any, filters: Sequence[str]) -> list[tuple[str, str]]:
    """The metadata's headline comparisons (``headlines``: pairs of filters, the one expected lower
    first) whose filters are both in ``filters``."""
    pairs = metadata.get("headlines") if isinstance(metadata, Mapping) else None
    out = []
    for p in pairs if isinstance(pairs, (list, tuple)) else ():
        if isinstance(p, (list, tuple)) and len(p) == 2 and all(str(f) in filters for f in p) and p[0] != p[1]:
            out.append((str(p[0]), str(p[1])))
    return out


def _headline(grid: Grid, e: str, unit: str, first: str, seconds: list[str], quoted: set) -> Finding | None:
    """``first`` against each of ``seconds``: where its mean error is lower, higher, or their
    intervals overlap, with the numbers where its lead is largest (``quoted`` is told each
    ``(filter, point)`` whose interval it quotes)."""
    clauses, orders = [], []
    for b in seconds:
        lower, higher, overlap = [], [], []
        for key in grid.points:
            r = grid.rows[key]
            if first not in r.index or b not in r.index:
                continue
            (ma, la, ha), (mb, lb, hb) = _interval(r, first, e), _interval(r, b, e)
            if not (math.isfinite(ma) and math.isfinite(mb)):
                continue
            if apart(la, ha, lb, hb):
                lower.append(key)
                orders.append((first, b, grid.point(key)))
            elif apart(lb, hb, la, ha):
                higher.append(key)
                orders.append((b, first, grid.point(key)))
            else:
                overlap.append(key)
        present = [k for k in grid.points if k in set(lower + higher + overlap)]
        if not present:
            continue

        def numbers(key, b=b):
            r = grid.rows[key]
            quoted.update({(first, key), (b, key)})
            return (grid.at(key, ": ") + quote(*_interval(r, first, e), unit) + " against "
                    + quote(*_interval(r, b, e), unit))

        def ratio(key, top, bottom):
            r = grid.rows[key]
            low = float(r.loc[bottom, f"{e}_mean"])
            return float(r.loc[top, f"{e}_mean"]) / low if low > 0 else math.inf

        parts = []
        if lower:
            best = max(lower, key=lambda k: ratio(k, b, first))
            parts.append(f"lower mean {e}{_space(grid.where(lower, present))}, the {PCT} intervals apart "
                         f"({numbers(best)})")
        if higher:
            worst = max(higher, key=lambda k: ratio(k, first, b))
            parts.append(f"higher{_space(grid.where(higher, present))}, the intervals apart ({numbers(worst)})")
        if overlap and (lower or higher):  # the rest of the points
            where = grid.where(overlap, present)
            parts.append(f"the intervals overlap {where}" if len(where) <= 60 and not where.startswith("at every")
                         else "elsewhere the intervals overlap")
        elif overlap:
            parts.append(f"the {PCT} intervals of their mean {e} overlap{_space(grid.where(overlap, present))} "
                         f"({numbers(overlap[-1])})")
        clauses.append(f"against {b}: " + ", ".join(parts))
    if not clauses:
        return None
    return Finding("", f"{first} " + "; ".join(clauses) + ".", tuple(orders), "headline")


def _chain(rows: pd.DataFrame, filters: Sequence[str], e: str) -> tuple[list[list[str]], list[tuple[str, str]]]:
    """The filters at one point as groups, lowest mean error first, with ``<`` between two groups
    only where every filter before lies below every filter after (intervals apart); inside a group
    the declared order. Returns the groups and every pair ``(lower, higher)`` a ``<`` claims."""
    present = [f for f in filters if f in rows.index and math.isfinite(float(rows.loc[f, f"{e}_mean"]))]
    ranked = sorted(present, key=lambda f: float(rows.loc[f, f"{e}_mean"]))
    iv = {f: _interval(rows, f, e) for f in ranked}
    groups: list[list[str]] = []
    start = 0
    for i in range(1, len(ranked) + 1):
        if i == len(ranked) or all(apart(iv[x][1], iv[x][2], iv[y][1], iv[y][2])
                                   for x in ranked[:i] for y in ranked[i:]):
            groups.append(sorted(ranked[start:i], key=present.index))
            start = i
    pairs = [(x, y) for gi, g in enumerate(groups) for x in g for h in groups[gi + 1:] for y in h]
    return groups, pairs


def _chain_text(groups: Sequence[Sequence[str]], label=lambda f: f) -> str:
    return " < ".join(" ≈ ".join(label(f) for f in g) for g in groups)


def _orders(grid: Grid, e: str, filters: Sequence[str]) -> tuple[Finding | None, dict]:
    """The sentence of the filters' order (each order with the points it holds at, the most
    common first, up to :data:`MAX_CLAUSES`) and every point's chain."""
    chains = {}
    for key in grid.points:
        groups, pairs = _chain(grid.rows[key], filters, e)
        if sum(map(len, groups)) >= 2:
            chains[key] = (groups, pairs)
    if not chains:
        return None, chains
    patterns: dict[tuple, list] = {}
    for key, (groups, _) in chains.items():
        patterns.setdefault(tuple(map(tuple, groups)), []).append(key)
    ranked = sorted(patterns.items(), key=lambda kv: -len(kv[1]))  # stable: the first point's order first on ties
    universe = list(chains)
    parts, orders = [], []
    for groups, keys in ranked[:MAX_CLAUSES]:
        parts.append(_chain_text(groups) + _space(grid.where(keys, universe)))
        orders += [(x, y, grid.point(k)) for k in keys for x, y in chains[k][1]]
    rest = sum(len(keys) for _, keys in ranked[MAX_CLAUSES:])
    if rest:
        parts.append(f"another order at {rest} more point{'s' if rest > 1 else ''} (the table below)")
    text = (f"Order of the mean {e}, lowest first ('<': every filter before it below every filter after it, the "
            f"{PCT} intervals apart; '≈': not ordered): " + "; ".join(parts) + ".")
    return Finding("", text, tuple(orders), "order"), chains


def _direction(rows_a: pd.DataFrame, rows_b: pd.DataFrame, f: str, e: str) -> str | None:
    """How ``f``'s mean error changes from point a to point b: "falls", "rises", "still" (None: missing)."""
    if f not in rows_a.index or f not in rows_b.index or not all(
            math.isfinite(float(r.loc[f, f"{e}_mean"])) for r in (rows_a, rows_b)):
        return None
    _, lo_a, hi_a = _interval(rows_a, f, e)
    _, lo_b, hi_b = _interval(rows_b, f, e)
    return "falls" if apart(lo_b, hi_b, lo_a, hi_a) else "rises" if apart(lo_a, hi_a, lo_b, hi_b) else "still"


def _pattern_words(pattern: tuple[tuple[str, str], ...]) -> str:
    by = {d: [f for f, x in pattern if x == d] for d in ("falls", "rises", "still")}
    n = len(pattern)
    if len(by["still"]) == n:
        return f"does not change beyond the {PCT} intervals for any filter"
    said = {"falls": "falls", "rises": "rises", "still": f"does not change beyond the {PCT} intervals"}
    return listing([f"{said[d]} for {'every filter' if len(fs) == n and n > 1 else listing(fs)}"
                     for d, fs in by.items() if fs])


def _trend(grid: Grid, a: str, e: str, unit: str, filters: Sequence[str], quoted: set = frozenset()) -> Finding | None:
    """How each filter's mean error changes from the axis' first value to its last: with one panel
    (no other axis), each change with its numbers (a mean whose interval a headline already quoted,
    ``quoted``: ``(filter, point)``, without it again); with several, the panels grouped by what changes."""
    i = grid.axes.index(a)
    ax = grid.shown[i]
    values = ordered(p[i] for p in grid.points)
    if len(values) < 2:
        return None
    first, last = values[0], values[-1]
    others = [j for j in range(len(grid.axes)) if j != i]
    key_of = {(p[i], tuple(p[j] for j in others)): p for p in grid.points}
    panels = ordered(tuple(p[j] for j in others) for p in grid.points)
    found: dict[tuple, tuple] = {}
    for q in panels:
        ka, kb = key_of.get((first, q)), key_of.get((last, q))
        if ka is None or kb is None:
            continue
        pattern = tuple((f, d) for f in filters if (d := _direction(grid.rows[ka], grid.rows[kb], f, e)) is not None)
        if pattern:
            found[q] = (ka, kb, pattern)
    if not found:
        return None
    head = f"From {ax.name} = {ax.text(first)} to {ax.text(last)}"
    if not others:  # one panel: every change with its numbers
        (ka, kb, pattern), = found.values()
        ra, rb = grid.rows[ka], grid.rows[kb]
        moves: dict[str, list[str]] = {"falls": [], "rises": []}
        still = []
        for f, d in pattern:
            if d == "still":
                still.append(f)
            else:
                ends = [_again(r, f, e, unit) if (f, k) in quoted else quote(*_interval(r, f, e), unit)
                        for r, k in ((ra, ka), (rb, kb))]
                moves[d].append(f"{f}'s from {ends[0]} to {ends[1]}")
        said = [f"the mean {e} {way}{' for every filter' if len(m) == len(pattern) else ''}: " + "; ".join(m)
                for way, m in moves.items() if m]
        if still:
            said.append(f"the mean {e} of {listing(still)} does not change beyond the {PCT} intervals (those at the "
                        f"two ends overlap)")
        text = f"{head} " + "; ".join(said) + "."
    else:
        groups: dict[tuple, list] = {}
        for q, (_, _, pattern) in found.items():
            groups.setdefault(pattern, []).append(q)
        ranked = sorted(groups.items(), key=lambda kv: -len(kv[1]))
        universe = list(found)
        axes = [grid.shown[j] for j in others]
        parts = [f"{_pattern_words(pattern)}{_space(name_points(qs, universe, axes))}" for pattern, qs in
                 ranked[:MAX_CLAUSES]]
        rest = sum(len(qs) for _, qs in ranked[MAX_CLAUSES:])
        if rest:
            parts.append(f"otherwise at {rest} more combination{'s' if rest > 1 else ''} of the other axes (the plots)")
        text = f"{head} the mean {e} " + "; ".join(parts) + "."
        found = {q: found[q] for _, qs in ranked[:MAX_CLAUSES] for q in qs}
    moves_ = tuple((f, grid.point(ka), grid.point(kb), d) for ka, kb, pattern in found.values()
                   for f, d in pattern if d != "still")
    return Finding(a, text, kind="trend", moves=moves_)


def _again(rows: pd.DataFrame, f: str, e: str, unit: str) -> str:
    """A mean whose interval a sentence above quoted: the mean alone, pointing there."""
    return f"{tables.format_number(float(rows.loc[f, f'{e}_mean']), tables.STAT_DIGITS)}{_space(unit)} (above)"


def _rates(grid: Grid, key: tuple, filters: Sequence[str]) -> str:
    rows = grid.rows[key]
    return ", ".join(f"{f} {percent(rows.loc[f, 'div_rate'], rows.loc[f, 'div_ci_low'], rows.loc[f, 'div_ci_high'])}"
                     for f in filters if f in rows.index)


def _divergence(grid: Grid, filters: Sequence[str]) -> Finding | None:
    """Where runs diverge, with the rates where they are highest, where the filters differ most
    and (one axis) where divergence starts."""
    k = {key: int(r["diverged"].sum()) for key, r in grid.rows.items()}
    n = {key: int(r["n"].min()) for key, r in grid.rows.items()}
    if not grid.axes:
        (key,) = grid.points
        if k[key]:
            return Finding("", f"Divergence rate: {_rates(grid, key, filters)}.", kind="divergence")
        hi = wilson_interval(0, n[key]).high
        return Finding("", f"No run of any filter diverged (0 of {n[key]} or more runs per filter; the rate's {PCT} "
                           f"interval ends at {100 * hi:.1f} %).", kind="divergence")
    seen = [p for p in grid.points if k[p] > 0]
    none = [p for p in grid.points if k[p] == 0]
    if not seen:
        hi = max(wilson_interval(0, n[p]).high for p in grid.points)
        return Finding("", f"No run of any filter diverged at {grid.every()} (0 runs of {min(n.values())} or more per "
                           f"point and filter; the rate's {PCT} interval ends at {100 * hi:.1f} % or below).",
                       kind="divergence")
    worst = max(seen, key=lambda p: float(grid.rows[p]["div_rate"].max()))
    spread = {p: float(np.ptp(grid.rows[p]["div_rate"].to_numpy(float))) for p in seen}
    widest = max(seen, key=spread.get)  # where the filters' rates differ most
    text = f"Runs diverge {grid.where(seen)}"
    edge = None
    if none:
        hi = max(wilson_interval(0, n[p]).high for p in none)
        if text.startswith("Runs diverge at every point but "):  # the exceptions are where none diverges
            text += f", where none of the runs does (0 %, the interval up to {100 * hi:.1f} %)"
        else:
            text += f" and in none of the runs {grid.where(none)} (0 %, the interval up to {100 * hi:.1f} %)"
        if len(grid.axes) == 1:
            ax, index = grid.shown[0], grid.points.index
            if max(map(index, seen)) < min(map(index, none)):
                edge = seen[-1]
                text += f"; divergence starts below {ax.text(none[0][0])}: {grid.at(edge, ':')} {_rates(grid, edge, filters)}"
            elif min(map(index, seen)) > max(map(index, none)):
                edge = seen[0]
                text += f"; divergence starts above {ax.text(none[-1][0])}: {grid.at(edge, ':')} {_rates(grid, edge, filters)}"
    if worst != edge:
        text += f"; {grid.at(worst, ':')} {_rates(grid, worst, filters)}"
    if widest not in (edge, worst) and spread[widest] > 0:
        text += f"; the filters differ most {grid.at(widest)}: {_rates(grid, widest, filters)}"
    orders = []
    rows = grid.rows[worst].sort_values("div_rate")
    if len(rows) > 1:
        lo = rows.iloc[0]
        if all(apart(lo["div_ci_low"], lo["div_ci_high"], r["div_ci_low"], r["div_ci_high"])
               for _, r in rows.iloc[1:].iterrows()):
            text += f"; there {rows.index[0]} diverges least (its interval below the others')"
            orders = [(str(rows.index[0]), str(f), grid.point(worst)) for f in rows.index[1:]]
    return Finding("", text + ".", tuple(orders), "divergence")


# ------------------------------------------------------------------------------ the box


def box(df: pd.DataFrame, metadata: Mapping[str, Any] | tables.Schema, axes: Sequence[str] | None = None, *,
        summary: Summary | None = None) -> Box:
    """What "What this shows" holds for a runs table (module docstring): its sentences, the table of
    the filters' order at each design point (None for a single point) and the consistency and floor
    table with its legend (None and [] when the dataset has neither). Filters and axes are named by
    the words the dataset declares for them (``filter_names``, a Param's ``label``), else by their
    code names; the orders and changes each Finding keeps use the code names. ``summary``: the
    page's :class:`mcjax.analysis.summary.Summary` of ``df`` (built here when not given)."""
    summary = summary_for(df, metadata, axes, summary)
    sch, data = summary.schema, summary.data
    filters = [str(f) for f in tables.ordered_filters(data["filter"], sch.filters)]
    e, unit = sch.error, tables.unit(sch.error, sch)
    grid = Grid(summary)
    found: list[Finding] = []
    quoted: set = set()  # (filter, point) whose mean error a headline quotes with its interval
    if len(filters) >= 2:
        firsts: dict[str, list[str]] = {}
        for a, b in headlines(metadata, filters):
            firsts.setdefault(a, []).append(b)
        found += [f for a, bs in firsts.items() if (f := _headline(grid, e, unit, a, bs, quoted)) is not None]
    order, chains = _orders(grid, e, filters)
    if order is not None:
        found.append(order)
    for a in grid.axes:
        t = _trend(grid, a, e, unit, filters, quoted)
        if t is not None:
            found.append(t)
    if sch.divergence:
        found.append(_divergence(grid, filters))
    found += [Finding("", t, kind="graph") for t in (connectivity.disconnections(grid, data, sch),
                                                      connectivity.mean_not_monotone(grid, data, sch, metadata)) if t]
    text = {a: ax.text for a, ax in zip(grid.axes, grid.shown)}
    entries = quality.quality_rows(data, sch, grid.axes, filters)
    found += [Finding("", t, kind=kind) for kind, t in
              quality.quality_sentences(data, sch, grid.axes, filters, lambda a, v: text[a](v), entries)]
    words = _words(metadata, sch)
    # the sentences name filters and axes by the glossary's words, not their code names
    found = [f._replace(text=_in_words(f.text, words)) for f in found]
    orders = None
    if len(grid.points) > 1 and chains:
        def cell(key):
            if key not in chains:
                return "—"
            rows = grid.rows[key]
            by_mean = [sorted(g, key=lambda f: float(rows.loc[f, f"{e}_mean"])) for g in chains[key][0]]
            return _replace_words(_chain_text(by_mean, lambda f: f"{f} {quote(*_interval(rows, f, e), unit)}"), words)
        orders = pd.DataFrame([{**dict(zip(grid.axes, key)), f"order of the mean {e}, lowest first": cell(key)}
                               for key in grid.points])
    q = quality.quality_table(data, sch, grid.axes, filters, entries)
    return Box(found, orders, q, quality.legend(sch, data) if q is not None else [])


def findings(df: pd.DataFrame, metadata: Mapping[str, Any] | tables.Schema,
             axes: Sequence[str] | None = None, *, summary: Summary | None = None) -> list[Finding]:
    """The sentences of "What this shows" (:func:`box`)."""
    return box(df, metadata, axes, summary=summary).sentences


def _words(metadata, sch: tables.Schema) -> dict[str, str]:
    """Code name -> words: each filter's declared short name (``filter_names``) and each Param's
    ``label`` (an empty dict for a dataset that declares none)."""
    names = metadata.get("filter_names") if isinstance(metadata, Mapping) else None
    out = {str(k): str(v) for k, v in (names or {}).items() if v}
    for name, decl in (sch.params or {}).items():
        if isinstance(decl, Mapping) and decl.get("label"):
            out[str(name)] = str(decl["label"])
    return out


def _replace_words(text: str, words: Mapping[str, str]) -> str:
    """``text`` with every code name of ``words`` standing alone (not inside another name) replaced."""
    for code in sorted(words, key=len, reverse=True):
        text = re.sub(rf"(?<![\w.]){re.escape(code)}(?!\w)", words[code], text)
    return text


def _in_words(text: str, words: Mapping[str, str]) -> str:
    """:func:`_replace_words`, the first letter capitalised (a sentence)."""
    text = _replace_words(text, words)
    return text[0].upper() + text[1:] if text else text
