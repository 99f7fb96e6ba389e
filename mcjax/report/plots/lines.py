"""Line figures of the report: a statistic against one swept axis, one panel per value of
the other axes and one line per filter (:func:`line_figure`), and the graph connectivity
against one axis, once per run (:func:`connectivity_figure`).

This module does not import JAX.
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import NullFormatter

from mcjax.report.plots.common import (MIN_RUNS, PALETTE, PCT, Stat, XAxis, errorbar, maybe_log_y, n_range, new_figure,
                                number_ticks, one_row_per_run, percent_ticks, with_unit)
from mcjax.analysis.statistics import mean_ci
from mcjax.analysis.tables import Schema, axis_label, display, format_number, ordered_filters, unit

__all__ = ["line_figure", "connectivity_figure"]

def _dodge(xa: XAxis, x: np.ndarray, i: int, m: int) -> np.ndarray:
    """Shift series ``i`` of ``m`` sideways so error bars do not overlap."""
    if m <= 1:
        return x
    k = i - (m - 1) / 2
    if not xa.numeric:
        return x + 0.06 * k
    v = np.asarray(list(xa.pos.values()))
    if xa.log:
        return x * 10.0 ** (0.006 * k * np.log10(v.max() / v.min()))
    span = float(v.max() - v.min()) or max(abs(float(v.max())), 1.0)
    return x + 0.006 * k * span


def _style_x(ax, xa: XAxis, sch: Schema, *, label_it: bool = True) -> None:
    if label_it:
        ax.set_xlabel(axis_label(xa.name, sch))
    if xa.log:
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())
    ticks = list(xa.pos.values())
    if xa.numeric:
        if len(ticks) <= 12:  # ticks at the swept values themselves
            ax.set_xticks(ticks)
        number_ticks(ax.xaxis)
    else:
        ax.set_xticks(ticks)
        ax.set_xticklabels([xa.text(v) for v in xa.values], rotation=30, ha="right")


def _columns(k: int) -> int:
    """Panels per row for ``k`` panels: all in one row up to 3, else a near-square grid of
    at most 3 columns."""
    return k if k <= 3 else min(3, math.ceil(math.sqrt(k)))


def _grid(fig: Figure, k: int):
    ncols = _columns(k)
    nrows = math.ceil(k / ncols)
    axs = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False, sharex=True, sharey=True)).ravel()
    for ax in axs[k:]:
        ax.set_visible(False)
    for j in range(max(0, k - ncols), k):  # the lowest panel of each column shows its x tick labels
        axs[j].xaxis.set_tick_params(labelbottom=True)
    return axs[:k], ncols


def _facet_title(others: Sequence[str], values: tuple, axes: Mapping[str, XAxis], sch: Schema) -> str:
    parts = []
    for name, value in zip(others, values):
        xa = axes.get(name)
        shown = xa.text(value) if xa is not None else format_number(value, 4)
        u = xa.unit if xa is not None else display(name, sch)[0]
        parts.append(f"{name} = {shown}" + (f" {u}" if u else ""))
    return ", ".join(parts)


def line_figure(summary: pd.DataFrame, xa: XAxis, sch: Schema, colors: Mapping[Any, str], st: Stat,
                 others: Sequence[str], facets: list[tuple], axes: Mapping[str, XAxis], *, title: str,
                 ylabel: str, pooled: str | None) -> tuple[Figure, str]:
    """One panel per facet (combination of the other axes' values), one line per filter of
    ``st.column`` against ``xa``; returns the figure and the sentences about its points."""
    k = len(facets)
    ncols = _columns(k)
    nrows = math.ceil(k / ncols)
    fig = new_figure((7.0, 4.6) if k == 1 else (3.9 * ncols + 0.9, 3.0 * nrows + 1.4))
    axs, ncols = _grid(fig, k)
    filters = ordered_filters(summary["filter"], sch.filters)
    n_all = summary[st.count].to_numpy(dtype=int)
    drawn = summary[st.column].to_numpy(dtype=float)
    vary = np.unique(n_all[np.isfinite(drawn)]).size > 1
    few_total = 0
    for ax, facet in zip(axs, facets):
        sub = summary
        for name, value in zip(others, facet):
            sub = sub[sub[name].map(lambda v, value=value: v == value)]
        for i, f in enumerate(filters):
            s = sub[sub["filter"] == f]
            if s.empty:
                continue
            s = s.assign(_x=xa.x(s[xa.name])).sort_values("_x")
            x = s["_x"].to_numpy()
            if st.rate:
                x = _dodge(xa, x, i, len(filters))
            y, lo, hi = (s[c].to_numpy(dtype=float) for c in (st.column, st.low, st.high))
            n = s[st.count].to_numpy(dtype=int)
            ok = (n >= MIN_RUNS) & np.isfinite(y)
            few = (n < MIN_RUNS) & np.isfinite(y)
            few_total += int(few.sum())
            c = colors[f]
            line_y = np.where(ok, y, np.nan)  # lines break at the points left out
            ax.plot(x, line_y, marker="o", ms=4, color=c, label=str(f))
            if st.rate:
                ax.errorbar(x[ok], y[ok], yerr=errorbar(y[ok], lo[ok], hi[ok]), fmt="none", capsize=3, color=c)
            else:
                ax.fill_between(x, np.where(ok, lo, np.nan), np.where(ok, hi, np.nan), color=c, alpha=0.18,
                                linewidth=0)
            if few.any():
                ax.plot(x[few], y[few], ls="none", marker="o", ms=7, mfc="white", mec=c, mew=1.5)
            if vary:
                for xv, yv, nv in zip(x[np.isfinite(y)], y[np.isfinite(y)], n[np.isfinite(y)]):
                    ax.annotate(str(nv), (xv, yv), textcoords="offset points", xytext=(3, 4), fontsize=7,
                                color=c)
        _style_x(ax, xa, sch, label_it=False)
        ax.grid(True, alpha=0.3, which="both")
        if others:
            ax.set_title(_facet_title(others, facet, axes, sch), fontsize="small")
    for j, ax in enumerate(axs):
        if j % ncols == 0:
            ax.set_ylabel(ylabel)
        if j >= len(axs) - ncols:
            ax.set_xlabel(axis_label(xa.name, sch))
    if st.rate:
        top = np.nanmax(np.r_[summary[st.high].to_numpy(dtype=float), drawn, 0.0])
        top = min(1.05, max(0.05, 1.12 * top))
        axs[0].set_ylim(-0.02 * top, top)
        percent_ticks(axs[0].yaxis)
    else:
        maybe_log_y(axs[0], drawn)
    handles, labels = axs[0].get_legend_handles_labels()
    if few_total:
        handles.append(Line2D([], [], ls="none", marker="o", ms=7, mfc="white", mec="0.3", mew=1.5))
        labels.append(f"< {MIN_RUNS} runs (not joined)")
    axs[0].legend(handles, labels, title="filter", fontsize="small")
    what = "point and filter"
    notes = [f"numbers beside the points: runs each rests on ({n_range(n_all, what)})" if vary
             else n_range(n_all, what)]
    if pooled:
        notes.append(pooled)
    fig.suptitle(f"{title}\n" + "; ".join(notes), fontsize="medium")
    sentences = []
    if vary:
        sentences.append(f"The number beside each point is the number of runs it rests on ({n_range(n_all, what)}).")
    else:
        sentences.append(f"Every point rests on {int(n_all.max())} runs." if n_all.size else "")
    if few_total:
        sentences.append(f"{few_total} point(s) rest on fewer than {MIN_RUNS} runs: drawn hollow, without "
                         f"interval, and not joined by the line.")
    return fig, " ".join(t for t in sentences if t)


def connectivity_figure(data: pd.DataFrame, xa: XAxis, sch: Schema, others: Sequence[str],
                         facets: list[tuple], axes: Mapping[str, XAxis], pooled: str | None) -> tuple[Figure, str]:
    """Graph statistics against one axis, from one row per run (they do not depend on the
    filter): mean over runs of the per-run mean (t-interval), minimum over runs of the
    per-run minimum, mean disconnected steps; one line per facet (combination of the other
    axes' values)."""
    cm, cmin, ds = sch.connectivity_mean, sch.connectivity_min, sch.disconnected_steps
    runs = one_row_per_run(data, sch, [xa.name, *others])
    rows = []
    group_keys = [xa.name, *others]
    for key, g in runs.groupby(group_keys, sort=False, dropna=False):
        key = key if isinstance(key, tuple) else (key,)
        row = {"x": xa.pos[key[0]], "facet": tuple(key[1:]), "n": len(g)}
        if cm:
            row["mean"], row["lo"], row["hi"] = mean_ci(g[cm])
        if cmin:
            vals = g[cmin].to_numpy(dtype=float)
            vals = vals[np.isfinite(vals)]
            row["min"] = float(vals.min()) if vals.size else math.nan
        if ds:
            row["disc"] = mean_ci(g[ds]).mean
        rows.append(row)
    s = pd.DataFrame(rows).sort_values("x")
    top_cols = [c for c in (cm, cmin) if c]
    fig = new_figure((7.0, 5.6 if (top_cols and ds) else 4.4))
    panels = list(np.atleast_1d(fig.subplots(2, 1, sharex=True, height_ratios=[2, 1]) if (top_cols and ds)
                                else fig.subplots(1, 1)))
    n_all = s["n"].to_numpy(dtype=int)
    vary = np.unique(n_all).size > 1
    few_total = 0
    for j, facet in enumerate(facets):
        f = s[s["facet"].map(lambda v, facet=facet: v == facet)]
        color = PALETTE[j % len(PALETTE)]
        name = _facet_title(others, facet, axes, sch) if others else None
        x, n = f["x"].to_numpy(), f["n"].to_numpy(dtype=int)
        ok = n >= MIN_RUNS
        few_total += int((~ok).sum())
        if top_cols:
            ax1 = panels[0]
            if cm:
                y = f["mean"].to_numpy(dtype=float)
                ax1.plot(x, np.where(ok, y, np.nan), marker="o", ms=4, color=color,
                         label=(f"mean over runs of {cm}" if name is None else f"{name}: mean {cm}"))
                ax1.fill_between(x, np.where(ok, f["lo"], np.nan), np.where(ok, f["hi"], np.nan), color=color,
                                 alpha=0.2, linewidth=0, label=(f"{PCT} t-interval" if name is None else None))
                if (~ok).any():
                    ax1.plot(x[~ok], y[~ok], ls="none", marker="o", ms=7, mfc="white", mec=color, mew=1.5)
                if vary:
                    for xv, yv, nv in zip(x, y, n):
                        ax1.annotate(str(nv), (xv, yv), textcoords="offset points", xytext=(3, 4), fontsize=7,
                                     color=color)
            if cmin:
                ym = f["min"].to_numpy(dtype=float)
                ax1.plot(x, np.where(ok, ym, np.nan), marker="v", ms=4, ls="--",
                         color=PALETTE[3] if name is None else color,
                         label=(f"min over runs of {cmin}" if name is None else f"{name}: min {cmin}"))
        if ds:
            yd = f["disc"].to_numpy(dtype=float)
            panels[-1].plot(x, np.where(ok, yd, np.nan), marker="o", ms=4,
                            color=PALETTE[7] if name is None else color)
            if (~ok).any():
                panels[-1].plot(x[~ok], yd[~ok], ls="none", marker="o", ms=7, mfc="white",
                                mec=PALETTE[7] if name is None else color, mew=1.5)
    if top_cols:
        ax1 = panels[0]
        ax1.axhline(0.0, color="0.4", lw=0.8)
        ax1.set_ylabel(with_unit(" / ".join(top_cols), unit(top_cols[0], sch)))
        ax1.grid(True, alpha=0.3, which="both")
        ax1.legend(fontsize="x-small" if others else "small")
        number_ticks(ax1.yaxis)
        if xa.log:
            ax1.set_xscale("log")
    if ds:
        ax2 = panels[-1]
        ax2.set_ylabel(with_unit(f"mean {ds}\nper run", unit(ds, sch)))
        ax2.grid(True, alpha=0.3, which="both")
        number_ticks(ax2.yaxis)
    _style_x(panels[-1], xa, sch)
    notes = [f"numbers beside the points: runs each rests on ({n_range(n_all, 'point')})" if vary
             else n_range(n_all, "point")]
    if others and not pooled:
        notes.append(f"one line per value of {', '.join(others)}")
    if pooled:
        notes.append(pooled)
    panels[0].set_title(f"Graph connectivity vs {xa.name}\n" + "; ".join(notes), fontsize="medium")
    text = (f"The number beside each point is the number of runs it rests on ({n_range(n_all, 'point')})."
            if vary else f"Every point rests on {int(n_all.max())} runs.")
    if few_total:
        text += (f" {few_total} point(s) rest on fewer than {MIN_RUNS} runs: drawn hollow and not joined "
                 f"by the line.")
    return fig, text
