"""The report's sentences about the comm graph (:mod:`mcjax.analysis.findings` puts them in its box):
where the graph disconnects (:func:`disconnections`) and, where the per-run mean connectivity is not
monotone in the swept axis, why (:func:`mean_not_monotone`).

The per-run mean connectivity (``lambda2_mean``, the ``connectivity_mean`` role) is the mean of the
algebraic connectivity λ2 over every step of a run (:func:`mcjax.tracking.metrics.graph_summary`),
a step with the graph disconnected counting 0 (λ2 ≤ 1e-9, the steps ``disconnected_steps``
counts). So it mixes two things: how many steps the graph spent broken, and how well connected it
was otherwise. Over the connected steps alone it is ``mean × n_steps / (n_steps − disconnected)``
(each run's; a run never connected has none). Where that is monotone, the steps spent disconnected
make the mean non-monotone; where it is not monotone either, they do not: the connected graphs
themselves differ between the axis' values in the links they hold.

Read from the dataset's metadata (roles, ``config.n_steps``); nothing names a scenario. No JAX.
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np
import pandas as pd

from mcjax.analysis import quality, tables
from mcjax.analysis.statistics import mean_ci, wilson_interval
from mcjax.analysis.wording import MAX_CLAUSES, PCT, Grid, apart, listing, percent, quote
from mcjax.analysis.wording import where as name_points

__all__ = ["disconnections", "mean_not_monotone"]


def _runs(data: pd.DataFrame) -> pd.DataFrame:
    """One row per run (the graph does not depend on the filter)."""
    keys = [k for k in ("point_id", "seed_index") if k in data.columns]
    return data.drop_duplicates(subset=keys) if len(keys) == 2 else data[data["filter"] == data["filter"].iloc[0]]


def disconnections(grid: Grid, data: pd.DataFrame, sch: tables.Schema) -> str | None:
    """Where the comm graph disconnects (runs with a disconnected step), once per run."""
    ds = sch.disconnected_steps
    if not ds or not grid.axes:
        return None
    runs = _runs(data)
    stats = {}
    for p in grid.points:
        g = quality.rows_at(runs, grid.axes, p)[ds].to_numpy(dtype=float)
        g = g[np.isfinite(g)]
        if g.size:
            k = int((g > 0).sum())
            stats[p] = (k, g.size, wilson_interval(k, g.size), mean_ci(g))
    if not stats:
        return None
    universe = list(stats)
    some = [p for p, st in stats.items() if st[0] > 0]
    none = [p for p, st in stats.items() if st[0] == 0]
    u = tables.unit(ds, sch)

    def rate(p):
        k, n, ci, _ = stats[p]
        return percent(k / n, ci.low, ci.high)

    def said(p):
        m = stats[p][3]
        steps = f"{ds}, {quote(m.mean, m.low, m.high, u)}" if m.low == m.high else \
            f"{ds}: mean {quote(m.mean, m.low, m.high, u)} per run"
        return f"in {rate(p)} of runs ({steps})"

    if not some:
        return (f"The comm graph stays connected in every run {grid.where(universe, universe)} ({ds} = 0 in all "
                f"{sum(st[1] for st in stats.values())} runs).")
    alike: dict[str, list] = {}  # points with the same numbers are named together
    for p in some:
        alike.setdefault(said(p), []).append(p)
    if len(alike) <= MAX_CLAUSES + 1:
        text = "The comm graph disconnects at some step " + "; ".join(
            f"{grid.at(ps[0]) if len(ps) == 1 else name_points(ps, universe, grid.shown)} {words}"
            for words, ps in alike.items())
    else:
        every = [p for p in some if stats[p][0] == stats[p][1]]
        partly = [p for p in some if stats[p][0] < stats[p][1]]
        parts = []
        if every:
            parts.append(f"in every run {name_points(every, universe, grid.shown)}")
        if partly:
            lo = min(partly, key=lambda p: stats[p][0] / stats[p][1])
            hi = max(partly, key=lambda p: stats[p][0] / stats[p][1])
            parts.append(f"in some runs {name_points(partly, universe, grid.shown)} (" + (
                f"{rate(lo)} of them" if lo == hi else f"from {rate(lo)} of them {grid.at(lo)} to {rate(hi)} "
                                                       f"{grid.at(hi)}") + ")")
        text = "The comm graph disconnects at some step " + "; ".join(parts)
    if none:
        hi = max(wilson_interval(0, stats[p][1]).high for p in none)
        text += f", and in no run {name_points(none, universe, grid.shown)} (0 %, the interval up to {100 * hi:.1f} %)"
    return text + "."


def _moves(cis: list) -> tuple[bool, bool]:
    """Whether, from one value of the axis to the next, the mean falls somewhere and rises somewhere
    (each with the two intervals apart)."""
    falls = any(apart(b.low, b.high, a.low, a.high) for a, b in zip(cis, cis[1:]))
    rises = any(apart(a.low, a.high, b.low, b.high) for a, b in zip(cis, cis[1:]))
    return falls, rises


def mean_not_monotone(grid: Grid, data: pd.DataFrame, sch: tables.Schema,
                      metadata: Mapping[str, Any] | Any) -> str | None:
    """With one swept axis: where the mean over runs of the per-run mean connectivity falls from one
    value to the next and rises from another (intervals apart), why (module docstring), with each
    value's mean over every step and, with ``disconnected_steps`` and ``config.n_steps``, over the
    connected steps alone. None where it is monotone, or cannot be told."""
    lam, ds = sch.connectivity_mean, sch.disconnected_steps
    if not lam or len(grid.axes) != 1 or len(grid.points) < 3:
        return None
    runs = _runs(data)
    config = metadata.get("config") if isinstance(metadata, Mapping) else None
    steps = config.get("n_steps") if isinstance(config, Mapping) else None
    whole, connected, broken = [], [], []
    for i, p in enumerate(grid.points):
        at = quality.rows_at(runs, grid.axes, p)
        x = at[lam].to_numpy(dtype=float)
        whole.append(mean_ci(x[np.isfinite(x)]))
        if ds and isinstance(steps, int) and not isinstance(steps, bool) and steps > 0:
            up = steps - at[ds].to_numpy(dtype=float)
            if np.any(up < steps):
                broken.append(i)  # some run disconnected here: the two means differ
            with np.errstate(divide="ignore", invalid="ignore"):
                y = np.where(up > 0, x * steps / up, np.nan)
            connected.append(mean_ci(y[np.isfinite(y)]))
    if not all(math.isfinite(m.low) for m in whole) or _moves(whole) != (True, True):
        return None
    ax = grid.shown[0]

    def values(cis, keep=lambda i: True) -> str:
        return listing([f"{quote(m.mean, m.low, m.high)} at {ax.text(p[0])}"
                        for i, (p, m) in enumerate(zip(grid.points, cis)) if keep(i)])

    text = (f"The per-run {lam}, averaged over the runs, is not monotone in {ax.name} ({values(whole)}; {PCT} t-intervals): "
            f"it is each run's mean over all its steps, a step with the graph disconnected counting 0")
    if not connected or not all(math.isfinite(m.mean) for m in connected):
        return text + "."
    same = [ax.text(grid.points[i][0]) for i in range(len(grid.points)) if i not in broken]
    text += (f"; over the steps the graph was connected it is {values(connected, lambda i: i in broken)}"
             + (f" (the same at {listing(same)}, where it never disconnected)" if same else ""))
    if _moves(connected) == (True, True):
        return (text + f", not monotone either: the steps spent disconnected do not explain it; the connected "
                       f"graphs themselves differ from one {ax.name} to another in the links they hold.")
    return text + f", monotone: the steps the graph spent disconnected ({ds}) make the difference."
