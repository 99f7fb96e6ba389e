"""The sensitivity figure of the report: the mean error against a swept axis with, under it,
the mean derivative of the error with respect to each Param a sweep's ``[sensitivity]``
differentiated (columns ``d_<error>_d_<param>``), one line per filter.

Under the panel of the swept Param itself, the dashed line is the slope of the mean error
curve of the exact system between neighbouring points (central differences of the means):
the derivative of the smooth system beside what the exact one's points say.

This module does not import JAX.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from mcjax.analysis.statistics import mean_ci
from mcjax.analysis.tables import Schema, axis_label, label, ordered_filters, unit
from mcjax.report.plots.common import MIN_RUNS, PCT, XAxis, maybe_log_y, new_figure, number_ticks, with_unit

__all__ = ["sensitivity_columns", "sensitivity_figure"]


def sensitivity_columns(columns: Sequence[str], sch: Schema) -> dict[str, str]:
    """``{column: param}`` of the derivatives of the error output in a runs table."""
    head = f"d_{sch.error}_d_"
    return {c: c[len(head):] for c in columns if c.startswith(head) and c[len(head):] in sch.params}


def _means(data: pd.DataFrame, xa: XAxis, column: str, f) -> tuple[np.ndarray, ...]:
    rows = []
    for v, g in data[data["filter"] == f].groupby(xa.name, sort=False):
        values = pd.to_numeric(g[column], errors="coerce").to_numpy(dtype=float)
        m = mean_ci(values)
        rows.append((v, xa.pos[v], m.mean, m.low, m.high, np.isfinite(values).sum()))
    rows.sort(key=lambda r: r[1])
    return tuple(np.asarray([r[i] for r in rows], dtype=float) for i in range(6))


def sensitivity_figure(data: pd.DataFrame, xa: XAxis, sch: Schema, colors: Mapping, derivatives: Mapping[str, str],
                       pooled: str | None) -> tuple[Figure, str]:
    """The mean error (top) and the mean of each derivative column (one panel each, below)
    against ``xa``, one line per filter, shaded t-intervals; returns the figure and a sentence
    about it."""
    e = sch.error
    k = len(derivatives)
    fig = new_figure((7.0, 3.2 + 1.9 * k))
    axs = list(np.atleast_1d(fig.subplots(1 + k, 1, sharex=True, height_ratios=[2] + [1.3] * k)))
    filters = ordered_filters(data["filter"], sch.filters)
    tops, few = [], 0
    for f in filters:
        c = colors[f]
        v, x, y, lo, hi, n = _means(data, xa, e, f)
        ok = n >= MIN_RUNS
        few += int((~ok).sum())
        axs[0].plot(x, np.where(ok, y, np.nan), marker="o", ms=4, color=c, label=str(f))
        axs[0].fill_between(x, np.where(ok, lo, np.nan), np.where(ok, hi, np.nan), color=c, alpha=0.18, linewidth=0)
        tops.extend(y[ok])
        for ax, (col, p) in zip(axs[1:], derivatives.items()):
            _, xd, yd, lod, hid, nd = _means(data, xa, col, f)
            okd = nd >= MIN_RUNS
            ax.plot(xd, np.where(okd, yd, np.nan), marker="o", ms=3, color=c)
            ax.fill_between(xd, np.where(okd, lod, np.nan), np.where(okd, hid, np.nan), color=c, alpha=0.18,
                            linewidth=0)
            if p == xa.name and xa.numeric and len(v) >= 2:  # the exact system's slope, from its means
                ax.plot(x, np.gradient(y, v), ls="--", lw=1, color=c)
    axs[0].set_ylabel(f"mean {label(e, sch)}")
    axs[0].legend(title="filter", fontsize="small")
    maybe_log_y(axs[0], tops)
    for ax, (col, p) in zip(axs[1:], derivatives.items()):
        ax.axhline(0.0, color="0.4", lw=0.8)
        ax.set_ylabel(with_unit(f"d {e} / d {p}", unit(col, sch)), fontsize="small")
        number_ticks(ax.yaxis)
    for ax in axs:
        ax.grid(True, alpha=0.3, which="both")
        if xa.log:
            ax.set_xscale("log")
    axs[-1].set_xlabel(axis_label(xa.name, sch))
    if xa.numeric:
        axs[-1].set_xticks(list(xa.pos.values()))
        number_ticks(axs[-1].xaxis)
    note = f"; runs {pooled}" if pooled else ""
    axs[0].set_title(f"Mean {e} and its sensitivities vs {xa.name} (shaded: {PCT} t-interval){note}",
                     fontsize="medium")
    text = ("Under the error, the mean derivative of the error of the smooth system with respect to "
            + ", ".join(derivatives.values()) + ", written by the sweep's [sensitivity] (forward mode, the same "
            "runs)." + (f" Dashed: the slope of the exact mean {e} curve between neighbouring points."
                        if xa.name in derivatives.values() else ""))
    if few:
        text += f" {few} point(s) rest on fewer than {MIN_RUNS} runs and are left out."
    return fig, text
