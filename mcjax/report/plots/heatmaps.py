"""Heatmaps of the report: a statistic over two swept axes, one panel per filter on a shared
colour scale (:func:`heatmap_figure`).

This module does not import JAX.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
from matplotlib import colormaps
from matplotlib.colors import LogNorm, Normalize
from matplotlib.figure import Figure

from mcjax.report.plots.common import (LOG_Y_DECADES, MIN_RUNS, Stat, XAxis, n_range, new_figure, number_ticks, percent_ticks,
                                spans_decades)
from mcjax.analysis.tables import Schema, axis_label, format_number, ordered_filters

__all__ = ["heatmap_figure"]

def heatmap_figure(summary: pd.DataFrame, a: XAxis, b: XAxis, sch: Schema, st: Stat, *,
                    title: str, cbar_label: str, pooled: str | None) -> tuple[Figure, str]:
    """Small multiples, one panel per filter, of ``st.column`` over the grid ``a`` × ``b``;
    cells resting on fewer than :data:`MIN_RUNS` runs are left grey and say their count."""
    filters = ordered_filters(summary["filter"], sch.filters)
    m = len(filters)
    ncols = min(3, m)
    nrows = math.ceil(m / ncols)
    fig = new_figure((3.6 * ncols + 1.2, 3.2 * nrows + 1.1))
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
        norm = LogNorm(lo, hi) if spans_decades(trusted, LOG_Y_DECADES) else Normalize(lo, hi if hi > lo else lo + 1.0)
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
                text = (f"{100 * v:.3g} %" if st.rate else format_number(v, 3)) + (f"\nn={n}" if vary else "")
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
        if st.rate:
            percent_ticks(cbar.ax.yaxis)
        elif not isinstance(norm, LogNorm):
            number_ticks(cbar.ax.yaxis)
    notes = [f"n per cell where it varies ({n_range(counts, 'cell and filter')})" if vary
             else n_range(counts, "cell and filter")]
    if few_total:
        notes.append(f"grey italic: < {MIN_RUNS} runs")
    if pooled:
        notes.append(pooled)
    fig.suptitle(f"{title}\n" + "; ".join(notes), fontsize="medium")
    text = (f"Each cell gives its number of runs n ({n_range(counts, 'cell and filter')})." if vary
            else f"Every cell rests on {int(counts.max())} runs." if counts.size else "")
    if few_total:
        text += (f" {few_total} cell(s) rest on fewer than {MIN_RUNS} runs: left grey, their value in "
                 f"brackets.")
    return fig, text
