"""How the report's sentences (:mod:`mcjax.analysis.findings`) write numbers and design points: a mean or a rate
with its interval (:func:`quote`, :func:`percent`), an axis' values ("every comm radius from 60 to 100 km"), a set
of points as the fewest products of ranges or "every point but ..." (:func:`where`), and :class:`Grid`, the
design points of a summary with their rows by filter. No JAX, no matplotlib."""

from __future__ import annotations

import itertools
import math
from typing import Any, NamedTuple, Sequence

import numpy as np

from mcjax.analysis import tables
from mcjax.analysis.statistics import CONFIDENCE
from mcjax.analysis.summary import Summary

__all__ = ["PCT", "MAX_CLAUSES", "Axis", "Grid", "apart", "listing", "ordered", "percent", "quote", "values_text", "where"]

PCT = f"{100 * CONFIDENCE:g} %"

#: At most this many clauses (orders, patterns of change) in one sentence, and this many products of
#: ranges to name a set of design points; the rest is in the tables (or the plots).
MAX_CLAUSES = 3

#: A design point as a Finding names it: ``((axis, value), ...)`` of every swept axis (``()``: one point).
Point = tuple


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


def apart(lo_a: float, hi_a: float, lo_b: float, hi_b: float) -> bool:
    """Interval a lies wholly below interval b (both finite)."""
    return all(math.isfinite(x) for x in (lo_a, hi_a, lo_b, hi_b)) and hi_a < lo_b


def listing(items: Sequence[str]) -> str:
    items = list(items)
    if len(items) <= 1:
        return "".join(items)
    return ", ".join(items[:-1]) + " and " + items[-1]


def ordered(values: Sequence[Any]) -> list:
    values = list(dict.fromkeys(values))
    try:
        return sorted(values)
    except TypeError:
        return values


class Axis(NamedTuple):
    name: str
    unit: str
    factor: float

    def bare(self, value: Any) -> str:
        """A value in the axis' display unit (a per-agent tuple element-wise), as the plots show it."""
        def scaled(v):
            if isinstance(v, (tuple, list)):
                return tuple(scaled(x) for x in v)
            if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_)):
                return float(v) * self.factor if self.factor != 1.0 else v
            return v
        return tables.format_number(scaled(value), 4)

    def text(self, value: Any) -> str:
        return self.bare(value) + (f" {self.unit}" if self.unit else "")


def values_text(ax: Axis, chosen: Sequence[Any], universe: list) -> str:
    """Some of an axis' values (``universe``: all of them, in order) in words: "every radius",
    "every radius from 60 to 100 km", "radius = 50 km and 80 km to 120 km"."""
    idx = sorted({universe.index(v) for v in chosen})
    if len(idx) == len(universe):
        return f"every {ax.name}"
    runs: list[list[int]] = []
    for i in idx:
        if runs and i == runs[-1][-1] + 1:
            runs[-1].append(i)
        else:
            runs.append([i])
    if len(runs) == 1 and len(runs[0]) >= 3:
        return f"every {ax.name} from {ax.bare(universe[runs[0][0]])} to {ax.text(universe[runs[0][-1]])}"
    items = []
    for r in runs:
        items += ([f"{ax.text(universe[r[0]])} to {ax.text(universe[r[-1]])}"] if len(r) >= 3
                  else [ax.text(universe[i]) for i in r])
    return f"{ax.name} = {listing(items)}"


def _split(points: list[tuple], order: list[int]) -> list[dict[int, list]]:
    """``points`` as products of per-axis value lists, splitting on the axes in ``order``."""
    i = order[0]
    if len(order) == 1:
        return [{i: list(dict.fromkeys(p[i] for p in points))}]
    rest: dict[Any, set] = {}
    for p in points:
        rest.setdefault(p[i], set()).add(tuple(p[j] for j in order[1:]))
    groups: dict[frozenset, list] = {}
    for v, r in rest.items():
        groups.setdefault(frozenset(r), []).append(v)
    out = []
    for vs in groups.values():
        for block in _split([p for p in points if p[i] == vs[0]], order[1:]):
            out.append({i: vs, **block})
    return out


def _blocks(points: list[tuple], n_axes: int) -> list[dict[int, list]]:
    """The fewest products of per-axis value lists covering ``points`` that a split along the axes
    (in every order, up to three axes) finds."""
    orders = itertools.permutations(range(n_axes)) if n_axes <= 3 else [tuple(range(n_axes))]
    return min((_split(points, list(o)) for o in orders), key=len)


def where(subset: Sequence[tuple], universe: Sequence[tuple], axes: Sequence[Axis]) -> str:
    """The design points ``subset`` of ``universe`` (tuples of the ``axes``' values) in words starting
    with "at" ("" for a single point without axes): every point, a range of one axis, products of
    ranges, "every point but ..." or, past :data:`MAX_CLAUSES` products, how many."""
    if not axes:
        return ""
    chosen = set(subset)
    sub = [p for p in universe if p in chosen]
    if len(sub) == len(universe):
        return f"at every {axes[0].name}" if len(axes) == 1 else "at every point"
    values = [ordered(p[i] for p in universe) for i in range(len(axes))]

    def parts(block: dict[int, list]) -> list[str]:  # an axis at every value goes unsaid beside one that is not
        said = [(values_text(axes[i], block[i], values[i]), len(set(block[i])) == len(values[i])) for i in range(len(axes))]
        return [t for t, every in said if not every] or [t for t, _ in said]

    def phrase(blocks: list[dict[int, list]]) -> str:  # one product: "a = 1 with b = 2"; several: "(a = 1, b = 2)"
        if len(blocks) == 1:
            return " with ".join(parts(blocks[0]))
        return listing(["(" + ", ".join(parts(b)) + ")" if len(parts(b)) > 1 else parts(b)[0] for b in blocks])

    if len(axes) == 1:
        return "at " + phrase([{0: [p[0] for p in sub]}])
    blocks = _blocks(sub, len(axes))
    rest = [p for p in universe if p not in chosen]
    others = _blocks(rest, len(axes))
    if len(others) < len(blocks) and len(others) <= MAX_CLAUSES:
        return "at every point but " + phrase(others)
    if len(blocks) <= MAX_CLAUSES:
        return "at " + phrase(blocks)
    return f"at {len(sub)} of the {len(universe)} points"


class Grid:
    """The design points of a summary (one per combination of the swept axes with more than one
    value): each point's summary rows by filter, its words."""

    def __init__(self, summary: Summary):
        sch = summary.schema
        self.axes = list(summary.plot_axes)
        self.shown = [Axis(a, *tables.display(a, sch)) for a in self.axes]
        table = summary.by(self.axes)
        keys = (list(table[self.axes].itertuples(index=False, name=None)) if self.axes else [()] * len(table))
        at: dict[tuple, list[int]] = {}
        for i, k in enumerate(keys):
            at.setdefault(k, []).append(i)
        self.rows = {k: table.iloc[idx].set_index("filter") for k, idx in at.items()}
        self.points = ordered(self.rows)

    def point(self, key: tuple) -> Point:
        return tuple(zip(self.axes, key))

    def label(self, key: tuple) -> str:
        """The point's values ("radius = 0 m, rate = 1 deg/s"; with one axis, the value alone)."""
        if len(self.axes) == 1:
            return self.shown[0].text(key[0])
        return ", ".join(f"{ax.name} = {ax.text(v)}" for ax, v in zip(self.shown, key))

    def at(self, key: tuple, then: str = "") -> str:
        """ "at radius = 50 km" + ``then`` ("" for the single point of a dataset without axes)."""
        return f"at {self.label(key)}{then}" if self.axes else ""

    def where(self, keys: Sequence[tuple], universe: Sequence[tuple] | None = None) -> str:
        return where(keys, self.points if universe is None else universe, self.shown)

    def every(self) -> str:
        return f"any {self.axes[0]}" if len(self.axes) == 1 else "any point"
