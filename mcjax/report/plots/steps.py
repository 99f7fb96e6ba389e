"""Per-step figures from a sweep's timeseries (``OUT/timeseries/``, written with ``timeseries =
true``): one panel per design point (never runs pooled across points), one line per filter.

* ``error_and_floor.png`` -- each filter's error per step, RMS over the point's runs, with the error
  floor beneath (the series with role ``"floor"``: the posterior Cramér–Rao bound, the square
  root of its variance averaged over the runs), when the dataset declares one;
* ``nees_per_step.png`` / ``nis_per_step.png`` -- each filter's NEES (NIS) per step, averaged over
  the point's runs, with the χ² band of a consistent filter's average over that many runs
  (:func:`mcjax.analysis.statistics.chi2_band`, the degrees of freedom declared with the series).

Read from the metadata's ``timeseries_outputs`` (roles and dof); nothing names a scenario. No JAX.
"""

from __future__ import annotations

import math
from typing import Any, Iterator, Mapping, Sequence

import numpy as np
import pandas as pd

from mcjax.analysis import quality, tables
from mcjax.analysis.statistics import chi2_band
from mcjax.analysis.summary import Summary, summary_for
from mcjax.report.plots.common import MAX_PANELS, Plot, Skipped, filter_colors, new_figure

__all__ = ["step_plots"]


def _role(declared: Mapping[str, Any], role: str) -> str | None:
    return next((k for k, d in declared.items() if isinstance(d, Mapping) and d.get("role") == role), None)


def _panels(fig, k: int):
    ncols = min(k, 3)
    nrows = math.ceil(k / ncols)
    axs = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False, sharex=True)).ravel()
    for ax in axs[k:]:
        ax.set_visible(False)
    return axs[:k]


def _points(runs: pd.DataFrame, axes: Sequence[str], sch) -> list[tuple[list, str]]:
    """The design points as (their point_ids, "a = 1, b = 2")."""
    data = tables.prepare(runs, axes)

    def text(a, v):
        unit, factor = tables.display(a, sch)
        v = float(v) * factor if isinstance(v, (int, float, np.number)) and not isinstance(v, bool) else v
        return tables.format_number(v, 4) + (f" {unit}" if unit else "")

    out = []
    for key, where in quality.point_labels(data, axes, text):
        mask = np.ones(len(data), bool)
        for a, v in zip(axes, key):
            mask &= quality.same_value(data[a], v)
        out.append((sorted(set(data.loc[mask, "point_id"].tolist())), where.removeprefix("at ")))
    return out


def step_plots(ts: pd.DataFrame, ts_metadata: Mapping[str, Any], runs: pd.DataFrame,
               metadata: Mapping[str, Any], *, summary: Summary | None = None) -> Iterator[Plot | Skipped]:
    """The per-step figures (module docstring) of a timeseries table ``ts`` with its metadata, the
    design points read from the runs table and its metadata (or the page's ``summary`` of them)."""
    declared = ts_metadata.get("timeseries_outputs") or {}
    summary = summary_for(runs, metadata, tables.swept_axes(metadata, runs.columns), summary)
    sch, axes = summary.schema, list(summary.plot_axes)
    points = _points(summary.data, axes, sch)
    error, floor = _role(declared, "error"), _role(declared, "floor")
    wanted = ([("error_and_floor.png", error, floor)] if error and floor else []) + \
        [(f"{r}_per_step.png", _role(declared, r), None) for r in ("nees", "nis") if _role(declared, r)]
    if not wanted:
        return
    if len(points) > MAX_PANELS:
        for name, *_ in wanted:
            yield Skipped(name, f"{len(points)} design points: more than {MAX_PANELS} panels (one per point)")
        return
    filters = [str(f) for f in tables.ordered_filters(ts["filter"], sch.filters)]
    colors = filter_colors(filters, sch.filters)
    for name, col, under in wanted:
        yield _figure(name, ts, declared, col, under, points, filters, colors)


def _figure(name, ts, declared, col, floor, points, filters, colors) -> Plot:
    k = len(points)
    fig = new_figure((min(k, 3) * 4.2 + 0.6, math.ceil(k / 3) * 3.2 + 0.6))
    axs = _panels(fig, k)
    d = declared[col]
    dof = d.get("dof")
    unit = d.get("unit") or ""
    ns = set()
    for ax, (ids, where) in zip(axs, points):
        rows = ts[ts["point_id"].isin(ids)]
        for f in filters:
            r = rows[rows["filter"] == f]
            if r.empty:
                continue
            g = r.groupby("t")[col]
            y = np.sqrt(g.apply(lambda s: np.nanmean(np.asarray(s, float) ** 2))) if floor else g.mean()
            ax.plot(y.index, y.to_numpy(), color=colors[f], lw=1.2, label=f)
        n_runs = rows.drop_duplicates(["point_id", "seed_index"]).shape[0]
        ns.add(n_runs)
        if floor:
            b = rows.drop_duplicates(["point_id", "seed_index", "t"]).groupby("t")[floor]
            yb = np.sqrt(b.apply(lambda s: np.nanmean(np.asarray(s, float) ** 2)))
            ax.plot(yb.index, yb.to_numpy(), color="black", ls="--", lw=1.4, label="floor (PCRB)")
        elif dof:
            band = chi2_band(int(dof), max(n_runs, 1))
            ax.axhspan(band.low, band.high, color="0.8", zorder=0, label=f"95 % band ({n_runs} runs)")
            ax.axhline(int(dof), color="0.4", lw=0.8, zorder=0)
        ax.set_yscale("log")
        ax.set_title(where or "this point", fontsize="small")
        ax.set_xlabel("step")
        ax.set_ylabel(f"{col} [{unit}]" if unit else col)
    axs[0].legend(fontsize="x-small")
    runs = ", ".join(map(str, sorted(ns)))
    if floor:
        caption = (f"{col} per step, the RMS over each point's runs ({runs} runs), per filter; the dashed line is "
                   f"the error floor ({floor}: the posterior Cramér–Rao bound of every agent's measurements, the "
                   f"square root of its mean variance over the runs): no filter's mean squared error can lie "
                   f"below it.")
    else:
        caption = (f"{col} per step, averaged over each point's runs ({runs} runs), per filter, against the 95 % band "
                   f"of a consistent filter's average ({dof} dof, grey): above it the filter is over-confident (its "
                   f"errors are larger than its covariance says), below it under-confident. The band is that of "
                   f"independent values; averaging over agents only narrows a consistent filter's spread, so it "
                   f"is conservative.")
    return Plot(name, fig, caption)
