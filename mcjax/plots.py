"""The report's figures: a sweep's error metric, divergence rate and graph connectivity
against its swept axes, as matplotlib figures and PNG files.

* :func:`figures` -- ``(file name, Figure)`` pairs for a runs table (see its docstring for
  the plot kinds); the figures are returned unsaved, so their labels can be inspected.
* :func:`make_plots` -- writes those figures as PNG files to ``OUT/report/``.
* :func:`x_axis` -- how an axis' values are placed on the x axis (:class:`XAxis`).
* :func:`filter_colors` -- one colour per filter, by the metadata's display order.

Titles and labels come from the dataset's metadata (:mod:`mcjax.tables`): the error metric
is labelled with its column name and declared unit, an axis with its parameter's unit.  A
scenario without a divergence flag gets no divergence plots; one without graph statistics
(e.g. a single agent) gets no connectivity plot.

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
from matplotlib.patches import Patch

from mcjax import tables
from mcjax.statistics import CONFIDENCE, mean_ci
from mcjax.tables import Schema, format_number, label, ordered_filters, summarize, unit

__all__ = ["PALETTE", "XAxis", "x_axis", "filter_colors", "figures", "make_plots"]

#: Line colours, assigned to filters in display order (cycled beyond ten filters).
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
           "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf")

_PCT = f"{100 * CONFIDENCE:g} %"


# --------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------


class XAxis(NamedTuple):
    """x positions of an axis' values: the values themselves (numeric axis) or 0, 1, ...
    (categorical axis, e.g. per-agent tuples); log scale when numeric, positive and
    spanning more than two decades."""

    name: str
    values: tuple
    numeric: bool
    log: bool
    pos: Mapping[Any, float]

    def x(self, values: Iterable[Any]) -> np.ndarray:
        return np.asarray([self.pos[v] for v in values], dtype=float)


def x_axis(name: str, values: Sequence[Any]) -> XAxis:
    """The :class:`XAxis` of an axis with the distinct (sorted) ``values``."""
    values = tuple(values)
    numeric = all(isinstance(v, (int, float, np.integer, np.floating))
                  and not isinstance(v, (bool, np.bool_)) for v in values)
    pos = {v: (float(v) if numeric else float(i)) for i, v in enumerate(values)}
    return XAxis(name, values, numeric, numeric and _spans_decades(values), pos)


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


def _style_x(ax, xa: XAxis, sch: Schema) -> None:
    ax.set_xlabel(label(xa.name, sch))
    if xa.log:
        ax.set_xscale("log")
    if not xa.numeric:
        ax.set_xticks(list(xa.pos.values()))
        ax.set_xticklabels([format_number(v, 4) for v in xa.values], rotation=30, ha="right")


def _spans_decades(values: Iterable[float], decades: float = 2.0) -> bool:
    v = np.asarray([x for x in values if x is not None], dtype=float)
    v = v[np.isfinite(v)]
    return bool(v.size and np.all(v > 0) and v.max() / v.min() > 10.0**decades)


def _maybe_log_y(ax, values: Iterable[float]) -> None:
    if _spans_decades(values):
        ax.set_yscale("log")


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


def _n_text(summary: pd.DataFrame) -> str:
    n = summary["n"].to_numpy()
    if n.size == 0:
        return ""
    lo, hi = int(n.min()), int(n.max())
    return f"n = {lo} runs per point and filter" if lo == hi else f"n = {lo}–{hi} runs per point and filter"


def _pooled_text(own: Sequence[str], axes: Sequence[str]) -> str:
    others = [a for a in axes if a not in set(own)]
    return f"; pooled over {', '.join(others)}" if others else ""


def _errorbar(mean, lo, hi) -> np.ndarray:
    mean, lo, hi = (np.asarray(v, dtype=float) for v in (mean, lo, hi))
    return np.clip(np.vstack([np.nan_to_num(mean - lo), np.nan_to_num(hi - mean)]), 0, None)


# --------------------------------------------------------------------------------------
# figures
# --------------------------------------------------------------------------------------


def _line_figure(summary: pd.DataFrame, xa: XAxis, sch: Schema, colors: Mapping[Any, str],
                 stat: str, *, title: str, subtitle: str, ylabel: str, rate: bool) -> Figure:
    """One line per filter of ``<stat>`` against the axis, with its interval
    ``<stat-stem>_ci_low/high`` (``div_ci_*`` for the rate): shaded, or error bars for a rate."""
    lo, hi = (("div_ci_low", "div_ci_high") if rate
              else (stat.removesuffix("_mean") + "_ci_low", stat.removesuffix("_mean") + "_ci_high"))
    fig = _new_figure((7.0, 4.6))
    ax = fig.add_subplot()
    filters = ordered_filters(summary["filter"], sch.filters)
    for i, f in enumerate(filters):
        s = summary[summary["filter"] == f]
        s = s.assign(_x=xa.x(s[xa.name])).sort_values("_x")
        x = s["_x"].to_numpy()
        yv, lv, hv = (s[c].to_numpy(dtype=float) for c in (stat, lo, hi))
        if rate:
            ax.errorbar(_dodge(xa, x, i, len(filters)), yv, yerr=_errorbar(yv, lv, hv), marker="o",
                        ms=4, capsize=3, color=colors[f], label=str(f))
        else:
            ax.plot(x, yv, marker="o", ms=4, color=colors[f], label=str(f))
            ax.fill_between(x, lv, hv, color=colors[f], alpha=0.18, linewidth=0)
    _style_x(ax, xa, sch)
    ax.set_ylabel(ylabel)
    if rate:
        top = np.nanmax(np.r_[summary[hi].to_numpy(dtype=float), summary[stat].to_numpy(dtype=float), 0.0])
        top = min(1.05, max(0.05, 1.12 * top))
        ax.set_ylim(-0.02 * top, top)
    else:
        _maybe_log_y(ax, summary[stat])
    ax.grid(True, alpha=0.3, which="both")
    ax.legend(title="filter", fontsize="small")
    ax.set_title(f"{title}\n{subtitle}", fontsize="medium")
    return fig


def _runs(df: pd.DataFrame, sch: Schema, axes: Sequence[str]) -> pd.DataFrame:
    """One row per run (for per-run outputs, which repeat across filters)."""
    if {"point_id", "seed_index"} <= set(df.columns):
        return df.drop_duplicates(subset=["point_id", "seed_index"])
    if "seed_index" in df.columns:
        return df.drop_duplicates(subset=["seed_index", *axes])
    return df[df["filter"] == ordered_filters(df["filter"], sch.filters)[0]]


def _connectivity_figure(df: pd.DataFrame, xa: XAxis, sch: Schema, axes: Sequence[str]) -> Figure:
    """Graph statistics against one axis, from one row per run (they do not depend on the
    filter): mean over runs of the per-run mean (t-interval), minimum over runs of the
    per-run minimum, mean disconnected steps."""
    cm, cmin, ds = sch.connectivity_mean, sch.connectivity_min, sch.disconnected_steps
    runs = _runs(df, sch, axes)
    rows = []
    for value, g in runs.groupby(xa.name, sort=False):
        row = {"x": xa.pos[value], "n": len(g)}
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
    if top_cols:
        ax1 = panels[0]
        if cm:
            ax1.plot(s["x"], s["mean"], marker="o", ms=4, color=PALETTE[0], label=f"mean over runs of {cm}")
            ax1.fill_between(s["x"], s["lo"], s["hi"], color=PALETTE[0], alpha=0.2, linewidth=0,
                             label=f"{_PCT} t-interval")
        if cmin:
            ax1.plot(s["x"], s["min"], marker="v", ms=4, ls="--", color=PALETTE[3],
                     label=f"min over runs of {cmin}")
        ax1.axhline(0.0, color="0.4", lw=0.8)
        ax1.set_ylabel(_with_unit(" / ".join(top_cols), unit(top_cols[0], sch)))
        ax1.grid(True, alpha=0.3, which="both")
        ax1.legend(fontsize="small")
        if xa.log:
            ax1.set_xscale("log")
    if ds:
        ax2 = panels[-1]
        ax2.plot(s["x"], s["disc"], marker="o", ms=4, color=PALETTE[7])
        ax2.set_ylabel(_with_unit(f"mean {ds}\nper run", unit(ds, sch)))
        ax2.grid(True, alpha=0.3, which="both")
    _style_x(panels[-1], xa, sch)
    n = s["n"].to_numpy()
    ntxt = f"n = {n.min()} runs per point" if n.min() == n.max() else f"n = {n.min()}–{n.max()} runs per point"
    panels[0].set_title(f"Graph connectivity vs {xa.name}\n{ntxt}{_pooled_text([xa.name], axes)}",
                        fontsize="medium")
    return fig


def _heatmap_figure(summary: pd.DataFrame, a: XAxis, b: XAxis, sch: Schema, stat: str, *,
                    title: str, cbar_label: str, rate: bool, axes: Sequence[str]) -> Figure:
    """Small multiples, one panel per filter, of ``stat`` over the grid ``a`` × ``b``."""
    filters = ordered_filters(summary["filter"], sch.filters)
    m = len(filters)
    ncols = min(3, m)
    nrows = math.ceil(m / ncols)
    fig = _new_figure((3.6 * ncols + 1.2, 3.2 * nrows + 0.9))
    grid = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False)).ravel()
    ia = {v: i for i, v in enumerate(a.values)}
    ib = {v: i for i, v in enumerate(b.values)}
    vals = summary[stat].to_numpy(dtype=float)
    finite = vals[np.isfinite(vals)]
    if rate:
        norm = Normalize(0.0, 1.0)
        cmap = colormaps["Reds"].with_extremes(bad="0.85")
    else:
        lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
        norm = LogNorm(lo, hi) if _spans_decades(finite) else Normalize(lo, hi if hi > lo else lo + 1.0)
        cmap = colormaps["viridis"].with_extremes(bad="0.85")
    annotate = len(a.values) * len(b.values) <= 100
    image = None
    for ax, f in zip(grid, filters):
        mat = np.full((len(b.values), len(a.values)), np.nan)
        sf = summary[summary["filter"] == f]
        for va, vb, v in zip(sf[a.name], sf[b.name], sf[stat]):
            mat[ib[vb], ia[va]] = v
        image = ax.imshow(np.ma.masked_invalid(mat), origin="lower", aspect="auto", cmap=cmap,
                          norm=norm, interpolation="nearest")
        ax.set_xticks(range(len(a.values)))
        ax.set_xticklabels([format_number(v, 4) for v in a.values], rotation=30, ha="right",
                           fontsize="small")
        ax.set_yticks(range(len(b.values)))
        ax.set_yticklabels([format_number(v, 4) for v in b.values], fontsize="small")
        ax.set_xlabel(label(a.name, sch), fontsize="small")
        ax.set_ylabel(label(b.name, sch), fontsize="small")
        ax.set_title(str(f), fontsize="medium")
        if annotate:
            for (j, i), v in np.ndenumerate(mat):
                if np.isfinite(v):
                    shade = norm(v)
                    dark = (shade > 0.55) if rate else (shade < 0.5)
                    ax.text(i, j, format_number(v, 2 if rate else 3), ha="center", va="center",
                            fontsize="x-small", color="white" if dark else "black")
                else:
                    ax.text(i, j, "–", ha="center", va="center", fontsize="x-small")
    for ax in grid[m:]:
        ax.set_visible(False)
    if image is not None:
        fig.colorbar(image, ax=list(grid[:m]), label=cbar_label, shrink=0.9)
    fig.suptitle(f"{title}\n{_n_text(summary)}{_pooled_text([a.name, b.name], axes)}",
                 fontsize="medium")
    return fig


def _bar_figure(summary: pd.DataFrame, sch: Schema, colors: Mapping[Any, str]) -> Figure:
    """Single sweep point: bars per filter of the mean error (all runs and, with a
    divergence flag, non-divergent runs) and of the divergence rate."""
    e, u = sch.error, unit(sch.error, sch)
    filters = ordered_filters(summary["filter"], sch.filters)
    s = summary.set_index("filter").loc[filters]
    x = np.arange(len(filters))
    cols = [colors[f] for f in filters]
    panels = 2 if sch.divergence else 1
    fig = _new_figure((max(7.0, 1.6 * len(filters) + 3) if panels == 2 else max(4.5, 1.0 * len(filters) + 2.5),
                       4.4))
    axs = np.atleast_1d(fig.subplots(1, panels))
    ax1 = axs[0]
    names = [str(f) for f in filters]
    mean = s[f"{e}_mean"]
    if sch.divergence:
        w = 0.38
        ok = s[f"{e}_ok_mean"]
        ax1.bar(x - w / 2, mean, w, yerr=_errorbar(mean, s[f"{e}_ci_low"], s[f"{e}_ci_high"]),
                color=cols, capsize=3)
        ax1.bar(x + w / 2, ok, w, yerr=_errorbar(ok, s[f"{e}_ok_ci_low"], s[f"{e}_ok_ci_high"]),
                color=cols, alpha=0.5, hatch="//", edgecolor="0.3", capsize=3)
        ax1.legend(handles=[Patch(facecolor="0.45", label="all runs"),
                            Patch(facecolor="0.45", alpha=0.5, hatch="//", edgecolor="0.3",
                                  label="non-divergent runs")], fontsize="small")
        _maybe_log_y(ax1, np.r_[mean.to_numpy(dtype=float), ok.to_numpy(dtype=float)])
    else:
        ax1.bar(x, mean, 0.6, yerr=_errorbar(mean, s[f"{e}_ci_low"], s[f"{e}_ci_high"]),
                color=cols, capsize=3)
        _maybe_log_y(ax1, mean.to_numpy(dtype=float))
    ax1.set_xticks(x)
    ax1.set_xticklabels(names, rotation=20)
    ax1.set_ylabel(_with_unit(f"mean {e}", u))
    ax1.set_title(f"Mean {e} ({_PCT} t-interval)", fontsize="medium")
    ax1.grid(True, axis="y", alpha=0.3, which="both")
    if sch.divergence:
        ax2 = axs[1]
        ax2.bar(x, s["div_rate"], 0.6, yerr=_errorbar(s["div_rate"], s["div_ci_low"], s["div_ci_high"]),
                color=cols, capsize=3)
        top = min(1.05, max(0.05, 1.12 * float(np.nanmax(np.r_[s["div_ci_high"].to_numpy(dtype=float), 0.0]))))
        ax2.set_ylim(0, top)
        ax2.set_xticks(x)
        ax2.set_xticklabels(names, rotation=20)
        ax2.set_ylabel("divergence rate (fraction of runs)")
        ax2.set_title(f"Divergence rate ({_PCT} Wilson interval)", fontsize="medium")
        ax2.grid(True, axis="y", alpha=0.3)
    what = f"{e} and divergence" if sch.divergence else e
    fig.suptitle(f"Single sweep point: {what} per filter\n{_n_text(summary)}", fontsize="medium")
    return fig


def figures(df: pd.DataFrame, metadata: Mapping[str, Any] | Schema,
            axes: str | Sequence[str] | None = None) -> Iterator[tuple[str, Figure]]:
    """``(file name, Figure)`` for each plot of a runs table, made one at a time.

    ``axes`` defaults to the swept axes of the metadata.  Only axes with more than one
    distinct value are plotted ("plot axes").  With ``<err>`` the error column and ``A`` a
    plot axis (numeric axes on a value scale, log scale when the values span more than two
    decades; list-valued axes as categories), one line per filter:

    * ``<err>_vs_<A>.png``: mean error (runs with a finite error), shaded 95 % t-interval;
    * with a divergence flag, ``<err>_nondiverged_vs_<A>.png`` (the same over non-divergent
      runs) and ``divergence_vs_<A>.png`` (divergence rate, 95 % Wilson interval error bars,
      series dodged sideways so equal rates stay readable);
    * with graph statistics, ``connectivity_vs_<A>.png``: mean over runs of the per-run
      mean connectivity (95 % t-interval), the minimum over runs of the per-run minimum and
      the mean number of disconnected steps, once per run (the graph does not depend on
      the filter).

    With other plot axes, the runs at each value of ``A`` are **pooled** over them (the
    title says so).  For every pair ``(A, B)`` of plot axes, small multiples (one panel per
    filter, shared colour scale): ``heatmap_<err>_<A>__<B>.png`` and, with a divergence
    flag, ``heatmap_<err>_nondiverged_<A>__<B>.png`` and ``heatmap_divergence_<A>__<B>.png``.

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
    xaxes: dict[str, XAxis] = {}
    for a in axes:
        values = list(pd.unique(data[a]))
        if len(values) > 1:
            try:
                values = sorted(values)
            except TypeError:
                pass
            xaxes[a] = x_axis(a, values)
    plot_axes = list(xaxes)
    if not xaxes:
        yield "summary_bars.png", _bar_figure(summarize(data, sch, []), sch, colors)
        return
    for name, xa in xaxes.items():
        s = summarize(data, sch, [name])
        tag = _safe(name)
        sub = f"{_n_text(s)}{_pooled_text([name], plot_axes)}"
        yield f"{_safe(e)}_vs_{tag}.png", _line_figure(
            s, xa, sch, colors, f"{e}_mean", title=f"Mean {e} vs {name} (shaded: {_PCT} t-interval)",
            subtitle=sub, ylabel=f"mean {err_label}", rate=False)
        if sch.divergence:
            yield f"{_safe(e)}_nondiverged_vs_{tag}.png", _line_figure(
                s, xa, sch, colors, f"{e}_ok_mean",
                title=f"Mean {e} of non-divergent runs vs {name} (shaded: {_PCT} t-interval)",
                subtitle=sub, ylabel=_with_unit(f"mean {e}, non-divergent runs", u), rate=False)
            yield f"divergence_vs_{tag}.png", _line_figure(
                s, xa, sch, colors, "div_rate",
                title=f"Divergence rate vs {name} (bars: {_PCT} Wilson interval)", subtitle=sub,
                ylabel="divergence rate (fraction of runs)", rate=True)
        if sch.connectivity:
            yield f"connectivity_vs_{tag}.png", _connectivity_figure(data, xa, sch, plot_axes)
    for (na, a), (nb, b) in itertools.combinations(xaxes.items(), 2):
        s = summarize(data, sch, [na, nb])
        tag = f"{_safe(na)}__{_safe(nb)}"
        if sch.divergence:
            yield f"heatmap_divergence_{tag}.png", _heatmap_figure(
                s, a, b, sch, "div_rate", title=f"Divergence rate over {na} × {nb}",
                cbar_label="divergence rate", rate=True, axes=plot_axes)
        yield f"heatmap_{_safe(e)}_{tag}.png", _heatmap_figure(
            s, a, b, sch, f"{e}_mean", title=f"Mean {e} over {na} × {nb}",
            cbar_label=f"mean {err_label}", rate=False, axes=plot_axes)
        if sch.divergence:
            yield f"heatmap_{_safe(e)}_nondiverged_{tag}.png", _heatmap_figure(
                s, a, b, sch, f"{e}_ok_mean", title=f"Mean {e} of non-divergent runs over {na} × {nb}",
                cbar_label=_with_unit(f"mean {e}, non-divergent runs", u), rate=False, axes=plot_axes)


def make_plots(df: pd.DataFrame, metadata: Mapping[str, Any] | Schema, out_dir: str | os.PathLike,
               axes: str | Sequence[str] | None = None, note: str | None = None) -> list[Path]:
    """Write the :func:`figures` of a runs table as PNG files to ``out_dir/report/``
    (created if missing); return their paths in the order made. ``note`` (e.g. that the
    dataset is incomplete) is printed in red along the bottom of every figure."""
    report_dir = Path(out_dir) / "report"
    paths: list[Path] = []
    for name, fig in figures(df, metadata, axes):
        report_dir.mkdir(parents=True, exist_ok=True)
        if note:
            fig.supxlabel(note, color="#b00000", fontsize="small")  # constrained layout makes room
        path = report_dir / name
        fig.savefig(path, format="png")
        fig.clear()
        paths.append(path)
    return paths
