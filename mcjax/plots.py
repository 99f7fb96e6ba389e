"""The report's figures: a sweep's error metric, divergence rate and graph connectivity
against its swept axes, as matplotlib figures and PNG files, each with a caption.

* :func:`plots` -- :class:`Plot` (file name, Figure, caption) and :class:`Skipped` (a plot
  not drawn, and why) records for a runs table (see its docstring for the plot kinds).
* :func:`figures` -- the ``(file name, Figure)`` pairs of :func:`plots`, unsaved.
* :func:`make_plots` / :func:`write_plots` -- write those figures as PNG files to
  ``OUT/report/`` (the paths; the paths with captions and the skipped plots).
* :func:`x_axis` -- how an axis' values are placed on the x axis (:class:`XAxis`).
* :func:`filter_colors` -- one colour per filter, by the metadata's display order.

Honest plots, by rule:

* every point shows the number of runs it rests on wherever that number varies within a
  figure (else the subtitle gives it once);
* a point resting on fewer than :data:`MIN_RUNS` runs is drawn hollow, with no interval,
  and lines do not pass through it;
* nothing is pooled over another swept axis silently: a plot against one axis draws one
  panel per value of the other axes (one line per value for the connectivity plot, which
  does not depend on the filter); only beyond :data:`MAX_PANELS` combinations (and in the
  heatmaps of three or more axes) are runs pooled, and then the title says over what and
  why; a metric that does not depend on the plotted axis at all (equal in every run at
  every value) is not plotted against it (a :class:`Skipped` record says so);
* axes are in the parameter's display unit (km, deg, ...: :func:`mcjax.tables.display`)
  and every number is formatted by :func:`mcjax.tables.format_number`, as in the tables.

Titles and labels come from the dataset's metadata (:mod:`mcjax.tables`). A scenario
without a divergence flag gets no divergence plots; one without graph statistics (e.g. a
single agent) gets no connectivity plot.

Figures are :class:`matplotlib.figure.Figure` objects drawn on an explicit Agg canvas,
never :mod:`matplotlib.pyplot`: the global backend and pyplot's figure registry are left
untouched and nothing needs a display.  This module does not import JAX.
"""

from __future__ import annotations

import itertools
import math
import os
import re
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping, NamedTuple, Sequence

import numpy as np
import pandas as pd
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import LogNorm, Normalize
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import FuncFormatter, NullFormatter

from mcjax import tables
from mcjax.statistics import CONFIDENCE, mean_ci
from mcjax.tables import Schema, axis_label, display, format_number, label, ordered_filters, summarize, unit

__all__ = ["PALETTE", "MIN_RUNS", "MAX_PANELS", "XAxis", "Plot", "Skipped", "x_axis", "filter_colors",
           "plots", "figures", "write_plots", "make_plots"]

#: Line colours, assigned to filters in display order (cycled beyond ten filters).
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
           "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf")
#: A point resting on fewer runs is drawn hollow, without interval, and left out of lines.
MIN_RUNS = 5
#: At most this many panels (combinations of the other axes' values) per figure; beyond,
#: the runs are pooled over the other axes and the title says so.
MAX_PANELS = 12
#: Relative tolerance under which a metric counts as equal across an axis' values (the
#: same seed at two points may differ in the last bits: different lanes of a batch).
SAME_RTOL = 1e-9

_PCT = f"{100 * CONFIDENCE:g} %"


class Plot(NamedTuple):
    """A figure of the report, its file name and a caption saying what it shows."""

    name: str
    figure: Figure
    caption: str


class Skipped(NamedTuple):
    """A plot the report does not draw, and why."""

    name: str
    reason: str


class PlotFile(NamedTuple):
    """A written figure: its path and caption."""

    path: Path
    caption: str


# --------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------


class XAxis(NamedTuple):
    """x positions of an axis' values: the values in the axis' display unit (numeric axis)
    or 0, 1, ... (categorical axis, e.g. per-agent tuples); log scale when numeric, positive
    and spanning more than two decades."""

    name: str
    values: tuple
    numeric: bool
    log: bool
    pos: Mapping[Any, float]
    unit: str = ""
    factor: float = 1.0

    def x(self, values: Iterable[Any]) -> np.ndarray:
        return np.asarray([self.pos[v] for v in values], dtype=float)

    def text(self, value: Any) -> str:
        """A value in the display unit, formatted as in the tables."""
        return format_number(_scaled(value, self.factor), 4)


def _scaled(value: Any, factor: float) -> Any:
    if isinstance(value, (tuple, list)):
        return tuple(_scaled(v, factor) for v in value)
    if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_)):
        return value * factor if factor != 1.0 else value
    return value


def x_axis(name: str, values: Sequence[Any], unit: str = "", factor: float = 1.0) -> XAxis:
    """The :class:`XAxis` of an axis with the distinct (sorted) ``values``, shown in
    ``unit`` (``factor`` times the stored value)."""
    values = tuple(values)
    numeric = all(isinstance(v, (int, float, np.integer, np.floating))
                  and not isinstance(v, (bool, np.bool_)) for v in values)
    pos = {v: (float(v) * factor if numeric else float(i)) for i, v in enumerate(values)}
    return XAxis(name, values, numeric, numeric and _spans_decades(pos.values()), pos, unit, factor)


def _axis_for(name: str, values: Sequence[Any], sch: Schema) -> XAxis:
    shown, factor = display(name, sch)
    return x_axis(name, values, shown, factor)


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


def _number_ticks(axis) -> None:
    axis.set_major_formatter(FuncFormatter(lambda v, _: format_number(float(v), 4)))


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
        _number_ticks(ax.xaxis)
    else:
        ax.set_xticks(ticks)
        ax.set_xticklabels([xa.text(v) for v in xa.values], rotation=30, ha="right")


def _spans_decades(values: Iterable[float], decades: float = 2.0) -> bool:
    v = np.asarray([x for x in values if x is not None], dtype=float)
    v = v[np.isfinite(v)]
    return bool(v.size and np.all(v > 0) and v.max() / v.min() > 10.0**decades)


def _maybe_log_y(ax, values: Iterable[float]) -> None:
    if _spans_decades(values):
        ax.set_yscale("log")
        ax.yaxis.set_minor_formatter(NullFormatter())
    _number_ticks(ax.yaxis)


def _with_unit(text: str, u: str) -> str:
    return f"{text} [{u}]" if u else text


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", str(name))


def filter_colors(values: Iterable[Any], order: Sequence[str]) -> dict[Any, str]:
    """Colour of each distinct filter value: :data:`PALETTE` by position in ``order``
    (the metadata's ``filters``), then the unknown values alphabetically."""
    order = list(order)
    known = {f: i for i, f in enumerate(order)}
    extra = sorted({str(v) for v in values} - set(order))
    index = {**known, **{f: len(order) + i for i, f in enumerate(extra)}}
    return {v: PALETTE[index[str(v)] % len(PALETTE)] for v in pd.unique(pd.Series(list(values), dtype=object))}


def _new_figure(figsize: tuple[float, float]) -> Figure:
    fig = Figure(figsize=figsize, dpi=100, layout="constrained")
    FigureCanvasAgg(fig)  # explicit Agg canvas: no pyplot, no global backend switch
    return fig


def _n_range(n: np.ndarray, what: str) -> str:
    n = np.asarray(n, dtype=int)
    if n.size == 0:
        return ""
    lo, hi = int(n.min()), int(n.max())
    return f"n = {lo} runs per {what}" if lo == hi else f"n = {lo}–{hi} runs per {what}"


def _errorbar(mean, lo, hi) -> np.ndarray:
    mean, lo, hi = (np.asarray(v, dtype=float) for v in (mean, lo, hi))
    return np.clip(np.vstack([np.nan_to_num(mean - lo), np.nan_to_num(hi - mean)]), 0, None)


def _facets(data: pd.DataFrame, others: Sequence[str]) -> list[tuple]:
    """The combinations of the other axes' values present in ``data``, sorted."""
    if not others:
        return [()]
    combos = list(data[list(others)].drop_duplicates().itertuples(index=False, name=None))
    try:
        return sorted(combos)
    except TypeError:
        return combos


def _facet_title(others: Sequence[str], values: tuple, axes: Mapping[str, XAxis], sch: Schema) -> str:
    parts = []
    for name, value in zip(others, values):
        xa = axes.get(name)
        shown = xa.text(value) if xa is not None else format_number(value, 4)
        u = xa.unit if xa is not None else display(name, sch)[0]
        parts.append(f"{name} = {shown}" + (f" {u}" if u else ""))
    return ", ".join(parts)


def _pooled_note(others: Sequence[str], axes: Mapping[str, XAxis], why: str) -> str:
    counts = " × ".join(f"{len(axes[o].values)} {o}" for o in others)
    return f"pooled over {', '.join(others)} ({counts} values): {why}"


def _runs(df: pd.DataFrame, sch: Schema, axes: Sequence[str]) -> pd.DataFrame:
    """One row per run (for per-run outputs, which repeat across filters)."""
    if {"point_id", "seed_index"} <= set(df.columns):
        return df.drop_duplicates(subset=["point_id", "seed_index"])
    if "seed_index" in df.columns:
        return df.drop_duplicates(subset=["seed_index", *axes])
    return df[df["filter"] == ordered_filters(df["filter"], sch.filters)[0]]


def _independent(data: pd.DataFrame, columns: Sequence[str], axis: str, others: Sequence[str],
                 per_filter: bool) -> bool:
    """Whether every one of ``columns`` is the same (within :data:`SAME_RTOL`) at every value
    of ``axis`` in every run: the same seed, the same values of the other axes (and the same
    filter). False when that cannot be told (no seed column, or a run missing somewhere)."""
    if "seed_index" not in data.columns or not columns:
        return False
    keys = [*others, "seed_index", *(["filter"] if per_filter else [])]
    n_values = data[axis].nunique(dropna=False)
    for col in columns:
        x = data[col]
        if x.dtype == bool or str(x.dtype) == "boolean":
            x = x.astype(float)
        frame = pd.DataFrame({"_v": pd.to_numeric(x, errors="coerce").astype(float),
                              **{k: data[k] for k in keys}, "_a": data[axis]})
        grouped = frame.groupby(keys, sort=False, dropna=False)
        if (grouped["_a"].nunique(dropna=False) != n_values).any():
            return False
        v = frame["_v"].to_numpy()
        first = grouped["_v"].transform("first").to_numpy()
        both_nan = np.isnan(v) & np.isnan(first)
        close = np.abs(v - first) <= SAME_RTOL * np.maximum(1.0, np.abs(first))
        if not np.all(both_nan | close):
            return False
    return True


def _counts(data: pd.DataFrame, keys: Sequence[str], sch: Schema) -> pd.DataFrame:
    """Per group: ``n_err`` (runs with a finite error: what the mean rests on) and, with a
    divergence flag, ``n_ok_err`` (the same among the non-divergent runs)."""
    err = pd.to_numeric(data[sch.error], errors="coerce").astype(float)
    cols = {"n_err": np.isfinite(err.to_numpy())}
    if sch.divergence:
        div = pd.array(data[sch.divergence], dtype="boolean").fillna(False).to_numpy(dtype=bool)
        cols["n_ok_err"] = cols["n_err"] & ~div
    frame = pd.DataFrame({**{k: data[k].to_numpy() for k in keys}, **{c: v.astype(int) for c, v in cols.items()}})
    return frame.groupby(list(keys), sort=False, dropna=False).sum().reset_index()


def _summary_with_counts(data: pd.DataFrame, sch: Schema, axes: Sequence[str]) -> pd.DataFrame:
    s = summarize(data, sch, list(axes))
    c = _counts(data, [*axes, "filter"], sch)
    return s.merge(c, on=[*axes, "filter"], how="left", sort=False)


# --------------------------------------------------------------------------------------
# figures
# --------------------------------------------------------------------------------------


class _Stat(NamedTuple):
    column: str      # summary column drawn
    low: str         # its interval
    high: str
    count: str       # summary column with the runs each point rests on
    rate: bool       # a proportion (error bars) rather than a mean (shaded interval)


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


def _line_figure(summary: pd.DataFrame, xa: XAxis, sch: Schema, colors: Mapping[Any, str], st: _Stat,
                 others: Sequence[str], facets: list[tuple], axes: Mapping[str, XAxis], *, title: str,
                 ylabel: str, pooled: str | None) -> tuple[Figure, str]:
    """One panel per facet (combination of the other axes' values), one line per filter of
    ``st.column`` against ``xa``; returns the figure and the sentences about its points."""
    k = len(facets)
    ncols = _columns(k)
    nrows = math.ceil(k / ncols)
    fig = _new_figure((7.0, 4.6) if k == 1 else (3.9 * ncols + 0.9, 3.0 * nrows + 1.4))
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
                ax.errorbar(x[ok], y[ok], yerr=_errorbar(y[ok], lo[ok], hi[ok]), fmt="none", capsize=3, color=c)
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
        _number_ticks(axs[0].yaxis)
    else:
        _maybe_log_y(axs[0], drawn)
    handles, labels = axs[0].get_legend_handles_labels()
    if few_total:
        handles.append(Line2D([], [], ls="none", marker="o", ms=7, mfc="white", mec="0.3", mew=1.5))
        labels.append(f"< {MIN_RUNS} runs (not joined)")
    axs[0].legend(handles, labels, title="filter", fontsize="small")
    what = "point and filter"
    notes = [f"numbers beside the points: runs each rests on ({_n_range(n_all, what)})" if vary
             else _n_range(n_all, what)]
    if pooled:
        notes.append(pooled)
    fig.suptitle(f"{title}\n" + "; ".join(notes), fontsize="medium")
    sentences = []
    if vary:
        sentences.append(f"The number beside each point is the number of runs it rests on ({_n_range(n_all, what)}).")
    else:
        sentences.append(f"Every point rests on {int(n_all.max())} runs." if n_all.size else "")
    if few_total:
        sentences.append(f"{few_total} point(s) rest on fewer than {MIN_RUNS} runs: drawn hollow, without "
                         f"interval, and not joined by the line.")
    return fig, " ".join(t for t in sentences if t)


def _connectivity_figure(data: pd.DataFrame, xa: XAxis, sch: Schema, others: Sequence[str],
                         facets: list[tuple], axes: Mapping[str, XAxis], pooled: str | None) -> tuple[Figure, str]:
    """Graph statistics against one axis, from one row per run (they do not depend on the
    filter): mean over runs of the per-run mean (t-interval), minimum over runs of the
    per-run minimum, mean disconnected steps; one line per facet (combination of the other
    axes' values)."""
    cm, cmin, ds = sch.connectivity_mean, sch.connectivity_min, sch.disconnected_steps
    runs = _runs(data, sch, [xa.name, *others])
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
    fig = _new_figure((7.0, 5.6 if (top_cols and ds) else 4.4))
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
                                 alpha=0.2, linewidth=0, label=(f"{_PCT} t-interval" if name is None else None))
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
        ax1.set_ylabel(_with_unit(" / ".join(top_cols), unit(top_cols[0], sch)))
        ax1.grid(True, alpha=0.3, which="both")
        ax1.legend(fontsize="x-small" if others else "small")
        _number_ticks(ax1.yaxis)
        if xa.log:
            ax1.set_xscale("log")
    if ds:
        ax2 = panels[-1]
        ax2.set_ylabel(_with_unit(f"mean {ds}\nper run", unit(ds, sch)))
        ax2.grid(True, alpha=0.3, which="both")
        _number_ticks(ax2.yaxis)
    _style_x(panels[-1], xa, sch)
    notes = [f"numbers beside the points: runs each rests on ({_n_range(n_all, 'point')})" if vary
             else _n_range(n_all, "point")]
    if others and not pooled:
        notes.append(f"one line per value of {', '.join(others)}")
    if pooled:
        notes.append(pooled)
    panels[0].set_title(f"Graph connectivity vs {xa.name}\n" + "; ".join(notes), fontsize="medium")
    text = (f"The number beside each point is the number of runs it rests on ({_n_range(n_all, 'point')})."
            if vary else f"Every point rests on {int(n_all.max())} runs.")
    if few_total:
        text += (f" {few_total} point(s) rest on fewer than {MIN_RUNS} runs: drawn hollow and not joined "
                 f"by the line.")
    return fig, text


def _heatmap_figure(summary: pd.DataFrame, a: XAxis, b: XAxis, sch: Schema, st: _Stat, *,
                    title: str, cbar_label: str, pooled: str | None) -> tuple[Figure, str]:
    """Small multiples, one panel per filter, of ``st.column`` over the grid ``a`` × ``b``;
    cells resting on fewer than :data:`MIN_RUNS` runs are left grey and say their count."""
    filters = ordered_filters(summary["filter"], sch.filters)
    m = len(filters)
    ncols = min(3, m)
    nrows = math.ceil(m / ncols)
    fig = _new_figure((3.6 * ncols + 1.2, 3.2 * nrows + 1.1))
    grid = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False)).ravel()
    ia = {v: i for i, v in enumerate(a.values)}
    ib = {v: i for i, v in enumerate(b.values)}
    counts = summary[st.count].to_numpy(dtype=int)
    vals = summary[st.column].to_numpy(dtype=float)
    trusted = vals[np.isfinite(vals) & (counts >= MIN_RUNS)]
    vary = np.unique(counts[np.isfinite(vals)]).size > 1
    if st.rate:
        norm = Normalize(0.0, 1.0)
        cmap = colormaps["Reds"].with_extremes(bad="0.85")
    else:
        lo, hi = (float(trusted.min()), float(trusted.max())) if trusted.size else (0.0, 1.0)
        norm = LogNorm(lo, hi) if _spans_decades(trusted) else Normalize(lo, hi if hi > lo else lo + 1.0)
        cmap = colormaps["viridis"].with_extremes(bad="0.85")
    annotate = len(a.values) * len(b.values) <= 100
    image = None
    few_total = 0
    for ax, f in zip(grid, filters):
        mat = np.full((len(b.values), len(a.values)), np.nan)
        nmat = np.zeros_like(mat, dtype=int)
        sf = summary[summary["filter"] == f]
        for va, vb, v, n in zip(sf[a.name], sf[b.name], sf[st.column], sf[st.count]):
            mat[ib[vb], ia[va]] = v
            nmat[ib[vb], ia[va]] = n
        shown = np.where(nmat >= MIN_RUNS, mat, np.nan)
        image = ax.imshow(np.ma.masked_invalid(shown), origin="lower", aspect="auto", cmap=cmap,
                          norm=norm, interpolation="nearest")
        ax.set_xticks(range(len(a.values)))
        ax.set_xticklabels([a.text(v) for v in a.values], rotation=30, ha="right", fontsize="small")
        ax.set_yticks(range(len(b.values)))
        ax.set_yticklabels([b.text(v) for v in b.values], fontsize="small")
        ax.set_xlabel(axis_label(a.name, sch), fontsize="small")
        ax.set_ylabel(axis_label(b.name, sch), fontsize="small")
        ax.set_title(str(f), fontsize="medium")
        for (j, i), v in np.ndenumerate(mat):
            n = nmat[j, i]
            if np.isfinite(v) and n < MIN_RUNS:
                few_total += 1
            if not annotate:
                continue
            if np.isfinite(v) and n >= MIN_RUNS:
                shade = norm(v)
                dark = (shade > 0.55) if st.rate else (shade < 0.5)
                text = format_number(v, 2 if st.rate else 3) + (f"\nn={n}" if vary else "")
                ax.text(i, j, text, ha="center", va="center", fontsize="x-small",
                        color="white" if dark else "black")
            elif np.isfinite(v):
                ax.text(i, j, f"({format_number(v, 2 if st.rate else 3)})\nn={n}", ha="center", va="center",
                        fontsize="x-small", color="0.35", style="italic")
            else:
                ax.text(i, j, "–", ha="center", va="center", fontsize="x-small")
    for ax in grid[m:]:
        ax.set_visible(False)
    if image is not None:
        cbar = fig.colorbar(image, ax=list(grid[:m]), label=cbar_label, shrink=0.9)
        if not isinstance(norm, LogNorm):
            _number_ticks(cbar.ax.yaxis)
    notes = [f"n per cell where it varies ({_n_range(counts, 'cell and filter')})" if vary
             else _n_range(counts, "cell and filter")]
    if few_total:
        notes.append(f"grey italic: < {MIN_RUNS} runs")
    if pooled:
        notes.append(pooled)
    fig.suptitle(f"{title}\n" + "; ".join(notes), fontsize="medium")
    text = (f"Each cell gives its number of runs n ({_n_range(counts, 'cell and filter')})." if vary
            else f"Every cell rests on {int(counts.max())} runs." if counts.size else "")
    if few_total:
        text += (f" {few_total} cell(s) rest on fewer than {MIN_RUNS} runs: left grey, their value in "
                 f"brackets.")
    return fig, text


def _bar_figure(summary: pd.DataFrame, sch: Schema, colors: Mapping[Any, str]) -> tuple[Figure, str]:
    """Single sweep point: bars per filter of the mean error (all runs and, with a
    divergence flag, non-divergent runs) and of the divergence rate; a bar resting on fewer
    than :data:`MIN_RUNS` runs is hatched, without interval; n is written on every bar."""
    e, u = sch.error, unit(sch.error, sch)
    filters = ordered_filters(summary["filter"], sch.filters)
    s = summary.set_index("filter").loc[filters]
    x = np.arange(len(filters))
    cols = [colors[f] for f in filters]
    panels = 2 if sch.divergence else 1
    fig = _new_figure((max(7.0, 1.6 * len(filters) + 3) if panels == 2 else max(4.5, 1.0 * len(filters) + 2.5),
                       4.6))
    axs = np.atleast_1d(fig.subplots(1, panels))
    ax1 = axs[0]
    names = [str(f) for f in filters]
    few_total = 0

    def bars(ax, xs, mean, lo, hi, n, width, **style):
        nonlocal few_total
        mean, n = np.asarray(mean, dtype=float), np.asarray(n, dtype=int)
        ok = n >= MIN_RUNS
        few_total += int((~ok & np.isfinite(mean)).sum())
        err = _errorbar(mean, lo, hi)
        err[:, ~ok] = 0.0
        rects = ax.bar(xs, np.nan_to_num(mean), width, yerr=err, capsize=3, **style)
        for r, okay in zip(rects, ok):
            if not okay:
                r.set_alpha(0.25)
                r.set_hatch("xx")
        for xv, mv, nv in zip(xs, mean, n):
            if np.isfinite(mv):
                ax.annotate(f"n={nv}", (xv, mv), textcoords="offset points", xytext=(0, 2), ha="center",
                            fontsize=7)

    if sch.divergence:
        w = 0.38
        bars(ax1, x - w / 2, s[f"{e}_mean"], s[f"{e}_ci_low"], s[f"{e}_ci_high"], s["n_err"], w, color=cols)
        bars(ax1, x + w / 2, s[f"{e}_ok_mean"], s[f"{e}_ok_ci_low"], s[f"{e}_ok_ci_high"], s["n_ok_err"], w,
             color=cols, alpha=0.5, hatch="//", edgecolor="0.3")
        ax1.legend(handles=[Patch(facecolor="0.45", label="all runs"),
                            Patch(facecolor="0.45", alpha=0.5, hatch="//", edgecolor="0.3",
                                  label="non-divergent runs")], fontsize="small")
        _maybe_log_y(ax1, np.r_[s[f"{e}_mean"].to_numpy(dtype=float), s[f"{e}_ok_mean"].to_numpy(dtype=float)])
    else:
        bars(ax1, x, s[f"{e}_mean"], s[f"{e}_ci_low"], s[f"{e}_ci_high"], s["n_err"], 0.6, color=cols)
        _maybe_log_y(ax1, s[f"{e}_mean"].to_numpy(dtype=float))
    ax1.set_xticks(x)
    ax1.set_xticklabels(names, rotation=20)
    ax1.set_ylabel(_with_unit(f"mean {e}", u))
    ax1.set_title(f"Mean {e} ({_PCT} t-interval)", fontsize="medium")
    ax1.grid(True, axis="y", alpha=0.3, which="both")
    if sch.divergence:
        ax2 = axs[1]
        bars(ax2, x, s["div_rate"], s["div_ci_low"], s["div_ci_high"], s["n"], 0.6, color=cols)
        top = min(1.05, max(0.05, 1.12 * float(np.nanmax(np.r_[s["div_ci_high"].to_numpy(dtype=float), 0.0]))))
        ax2.set_ylim(0, top)
        ax2.set_xticks(x)
        ax2.set_xticklabels(names, rotation=20)
        ax2.set_ylabel("divergence rate (fraction of runs)")
        ax2.set_title(f"Divergence rate ({_PCT} Wilson interval)", fontsize="medium")
        ax2.grid(True, axis="y", alpha=0.3)
        _number_ticks(ax2.yaxis)
    what = f"{e} and divergence" if sch.divergence else e
    fig.suptitle(f"Single sweep point: {what} per filter\n{_n_range(summary['n'], 'filter')}; "
                 f"n on each bar: the runs it rests on", fontsize="medium")
    text = "The n above each bar is the number of runs it rests on."
    if few_total:
        text += f" {few_total} bar(s) rest on fewer than {MIN_RUNS} runs: hatched, without interval."
    return fig, text


def _plot_axes(data: pd.DataFrame, axes: Sequence[str], sch: Schema) -> dict[str, XAxis]:
    xaxes: dict[str, XAxis] = {}
    for a in axes:
        values = list(pd.unique(data[a]))
        if len(values) > 1:
            try:
                values = sorted(values)
            except TypeError:
                pass
            xaxes[a] = _axis_for(a, values, sch)
    return xaxes


def plots(df: pd.DataFrame, metadata: Mapping[str, Any] | Schema,
          axes: str | Sequence[str] | None = None) -> Iterator[Plot | Skipped]:
    """:class:`Plot` for each figure of a runs table (made one at a time), and a
    :class:`Skipped` record for each plot left out on purpose.

    ``axes`` defaults to the swept axes of the metadata.  Only axes with more than one
    distinct value are plotted ("plot axes").  With ``<err>`` the error column and ``A`` a
    plot axis (numeric axes in their display unit, log scale when the values span more than
    two decades; list-valued axes as categories), one line per filter:

    * ``<err>_vs_<A>.png``: mean error (runs with a finite error), shaded 95 % t-interval;
    * with a divergence flag, ``<err>_nondiverged_vs_<A>.png`` (the same over non-divergent
      runs) and ``divergence_vs_<A>.png`` (divergence rate, 95 % Wilson interval error bars,
      series dodged sideways so equal rates stay readable);
    * with graph statistics, ``connectivity_vs_<A>.png``: mean over runs of the per-run
      mean connectivity (95 % t-interval), the minimum over runs of the per-run minimum and
      the mean number of disconnected steps, once per run (the graph does not depend on
      the filter).

    With other plot axes, each figure has one panel per combination of their values (the
    connectivity plot one line per combination), up to :data:`MAX_PANELS`; beyond, the runs
    are pooled over them and the title says so.  A metric equal in every run at every value
    of ``A`` (within :data:`SAME_RTOL`; e.g. a static graph against a target's turn rate)
    is not plotted against ``A``: a :class:`Skipped` record says why.

    For every pair ``(A, B)`` of plot axes, small multiples (one panel per filter, shared
    colour scale): ``heatmap_<err>_<A>__<B>.png`` and, with a divergence flag,
    ``heatmap_<err>_nondiverged_<A>__<B>.png`` and ``heatmap_divergence_<A>__<B>.png``;
    with a third plot axis the cells pool over it (said in the title).

    With no plot axis (a single point): ``summary_bars.png``, bars per filter of the mean
    error (95 % t-interval) and divergence rate (95 % Wilson interval).

    Raises:
        ValueError: the table is empty, or the metadata does not fit it (see
            :func:`mcjax.tables.schema`).
    """
    if not isinstance(df, pd.DataFrame):
        raise TypeError(f"figures: df must be a pandas DataFrame, got {type(df).__name__}")
    if df.empty:
        raise ValueError("figures: the runs table is empty")
    sch = tables.schema(metadata, df.columns)
    axes = tables.resolve_axes(sch, df.columns, axes)
    if "filter" not in df.columns:
        raise ValueError(f"figures: no 'filter' column in the runs table; it has {list(df.columns)}")
    data = tables.prepare(df, axes)
    colors = filter_colors(data["filter"], sch.filters)
    e = sch.error
    err_label = label(e, sch)
    u = unit(e, sch)
    xaxes = _plot_axes(data, axes, sch)
    plot_axes = list(xaxes)
    if not xaxes:
        s = _summary_with_counts(data, sch, [])
        fig, text = _bar_figure(s, sch, colors)
        yield Plot("summary_bars.png", fig, f"One sweep point: the mean {err_label} per filter over all runs"
                   + (" and over the non-divergent runs, and the divergence rate" if sch.divergence else "")
                   + f" ({_PCT} intervals). " + text)
        return
    for name, xa in xaxes.items():
        others = [o for o in plot_axes if o != name]
        facets = _facets(data, others)
        pooled = None
        if len(facets) > MAX_PANELS:
            pooled = _pooled_note(others, xaxes, f"{len(facets)} combinations are more than {MAX_PANELS} "
                                                 f"panels; see the heatmaps")
            panel_axes, facets = [], [()]
        else:
            panel_axes = others
        s = _summary_with_counts(data, sch, [name, *panel_axes])
        tag = _safe(name)
        where = (f" One panel per value of {', '.join(panel_axes)}." if panel_axes else "") + (
            f" Runs {pooled}." if pooled else "")
        x_text = axis_label(name, sch)
        error_cols = [e, *([sch.divergence] if sch.divergence else [])]
        if _independent(data, error_cols, name, others, per_filter=True):
            reason = (f"{', '.join(error_cols)} do(es) not depend on {name}: equal in every run at every "
                      f"value of {name}")
            yield Skipped(f"{_safe(e)}_vs_{tag}.png", reason)
            if sch.divergence:
                yield Skipped(f"{_safe(e)}_nondiverged_vs_{tag}.png", reason)
                yield Skipped(f"divergence_vs_{tag}.png", reason)
        else:
            fig, text = _line_figure(
                s, xa, sch, colors, _Stat(f"{e}_mean", f"{e}_ci_low", f"{e}_ci_high", "n_err", False),
                panel_axes, facets, xaxes, title=f"Mean {e} vs {name} (shaded: {_PCT} t-interval)",
                ylabel=f"mean {err_label}", pooled=pooled)
            yield Plot(f"{_safe(e)}_vs_{tag}.png", fig,
                       f"Mean {err_label} over the runs with a finite {e}, against {x_text}, one line per "
                       f"filter; shaded: its {_PCT} Student-t interval.{where} {text}")
            if sch.divergence:
                fig, text = _line_figure(
                    s, xa, sch, colors,
                    _Stat(f"{e}_ok_mean", f"{e}_ok_ci_low", f"{e}_ok_ci_high", "n_ok_err", False),
                    panel_axes, facets, xaxes,
                    title=f"Mean {e} of non-divergent runs vs {name} (shaded: {_PCT} t-interval)",
                    ylabel=_with_unit(f"mean {e}, non-divergent runs", u), pooled=pooled)
                yield Plot(f"{_safe(e)}_nondiverged_vs_{tag}.png", fig,
                           f"Mean {err_label} over the runs that did not diverge ({sch.divergence} false), "
                           f"against {x_text}, one line per filter; shaded: its {_PCT} Student-t interval. "
                           f"How many runs that is varies with the divergence rate.{where} {text}")
                fig, text = _line_figure(
                    s, xa, sch, colors, _Stat("div_rate", "div_ci_low", "div_ci_high", "n", True),
                    panel_axes, facets, xaxes,
                    title=f"Divergence rate vs {name} (bars: {_PCT} Wilson interval)",
                    ylabel="divergence rate (fraction of runs)", pooled=pooled)
                yield Plot(f"divergence_vs_{tag}.png", fig,
                           f"Fraction of runs with {sch.divergence} true, against {x_text}, one line per "
                           f"filter (shifted sideways a little so equal rates stay apart); bars: its {_PCT} "
                           f"Wilson interval.{where} {text}")
        if sch.connectivity:
            runs = _runs(data, sch, plot_axes)
            cname = f"connectivity_vs_{tag}.png"
            if _independent(runs, list(sch.connectivity), name, others, per_filter=False):
                yield Skipped(cname, f"{', '.join(sch.connectivity)} do not depend on {name}: equal in every run "
                                     f"at every value of {name}")
            else:
                cpooled, cfacets, cothers = pooled, facets, panel_axes
                if not pooled and len(facets) > len(PALETTE):
                    cpooled = _pooled_note(others, xaxes, f"{len(facets)} combinations are more lines than "
                                                          f"{len(PALETTE)} colours")
                    cfacets, cothers = [()], []
                fig, text = _connectivity_figure(data, xa, sch, cothers, cfacets, xaxes, cpooled)
                lines = f" One line per value of {', '.join(cothers)}." if cothers else ""
                yield Plot(cname, fig,
                           f"Graph connectivity against {x_text}, once per run (the comm graph does not depend "
                           f"on the filter): the mean over runs of {sch.connectivity_mean or '–'} with its {_PCT} "
                           f"t-interval, the smallest {sch.connectivity_min or '–'} of any run, and the mean "
                           f"{sch.disconnected_steps or '–'} per run.{lines}"
                           + (f" Runs {cpooled}." if cpooled else "") + f" {text}")
    for (na, a), (nb, b) in itertools.combinations(xaxes.items(), 2):
        rest = [o for o in plot_axes if o not in (na, nb)]
        pooled = (_pooled_note(rest, xaxes, "a heatmap shows two axes; the line plots show each value")
                  if rest else None)
        s = _summary_with_counts(data, sch, [na, nb])
        tag = f"{_safe(na)}__{_safe(nb)}"
        grid_text = f"{axis_label(na, sch)} × {axis_label(nb, sch)}"
        extra = f" Cells {pooled}." if pooled else ""
        if sch.divergence:
            fig, text = _heatmap_figure(s, a, b, sch, _Stat("div_rate", "div_ci_low", "div_ci_high", "n", True),
                                        title=f"Divergence rate over {na} × {nb}", cbar_label="divergence rate",
                                        pooled=pooled)
            yield Plot(f"heatmap_divergence_{tag}.png", fig,
                       f"Divergence rate over {grid_text}, one panel per filter.{extra} {text}")
        fig, text = _heatmap_figure(s, a, b, sch, _Stat(f"{e}_mean", f"{e}_ci_low", f"{e}_ci_high", "n_err", False),
                                    title=f"Mean {e} over {na} × {nb}", cbar_label=f"mean {err_label}",
                                    pooled=pooled)
        yield Plot(f"heatmap_{_safe(e)}_{tag}.png", fig,
                   f"Mean {err_label} (runs with a finite {e}) over {grid_text}, one panel per filter.{extra} {text}")
        if sch.divergence:
            fig, text = _heatmap_figure(
                s, a, b, sch, _Stat(f"{e}_ok_mean", f"{e}_ok_ci_low", f"{e}_ok_ci_high", "n_ok_err", False),
                title=f"Mean {e} of non-divergent runs over {na} × {nb}",
                cbar_label=_with_unit(f"mean {e}, non-divergent runs", u), pooled=pooled)
            yield Plot(f"heatmap_{_safe(e)}_nondiverged_{tag}.png", fig,
                       f"Mean {err_label} of the non-divergent runs over {grid_text}, one panel per filter."
                       f"{extra} {text}")


def figures(df: pd.DataFrame, metadata: Mapping[str, Any] | Schema,
            axes: str | Sequence[str] | None = None) -> Iterator[tuple[str, Figure]]:
    """``(file name, Figure)`` for each :class:`Plot` of :func:`plots`, made one at a time."""
    for item in plots(df, metadata, axes):
        if isinstance(item, Plot):
            yield item.name, item.figure


def write_plots(df: pd.DataFrame, metadata: Mapping[str, Any] | Schema, out_dir: str | os.PathLike,
                axes: str | Sequence[str] | None = None,
                note: str | None = None) -> tuple[list[PlotFile], list[Skipped]]:
    """Write the :func:`plots` of a runs table as PNG files to ``out_dir/report/``
    (created if missing): the written files with their captions, in the order made, and
    the plots skipped. ``note`` (e.g. that the dataset is incomplete) is printed in red
    along the bottom of every figure."""
    report_dir = Path(out_dir) / "report"
    written: list[PlotFile] = []
    skipped: list[Skipped] = []
    for item in plots(df, metadata, axes):
        if isinstance(item, Skipped):
            skipped.append(item)
            continue
        report_dir.mkdir(parents=True, exist_ok=True)
        fig = item.figure
        if note:
            fig.supxlabel(note, color="#b00000", fontsize="small")  # constrained layout makes room
        path = report_dir / item.name
        fig.savefig(path, format="png")
        fig.clear()
        written.append(PlotFile(path, item.caption))
    return written, skipped


def make_plots(df: pd.DataFrame, metadata: Mapping[str, Any] | Schema, out_dir: str | os.PathLike,
               axes: str | Sequence[str] | None = None, note: str | None = None) -> list[Path]:
    """The paths of :func:`write_plots`."""
    return [p.path for p in write_plots(df, metadata, out_dir, axes, note)[0]]
