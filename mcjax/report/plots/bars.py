"""The report's figure of a single sweep point: bars per filter (:func:`bar_figure`).

This module does not import JAX.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.patches import Patch

from mcjax.report.plots.common import (MIN_RUNS, PCT, errorbar, maybe_log_y, n_range, new_figure, percent_ticks,
                                with_unit)
from mcjax.analysis.tables import Schema, ordered_filters, unit

__all__ = ["bar_figure"]

def bar_figure(summary: pd.DataFrame, sch: Schema, colors: Mapping[Any, str]) -> tuple[Figure, str]:
    """Single sweep point: bars per filter of the mean error (all runs and, with a
    divergence flag, non-divergent runs) and of the divergence rate; a bar resting on fewer
    than :data:`MIN_RUNS` runs is hatched, without interval; n is written on every bar, above
    its interval's cap. Where no run diverged, the divergence panel and the non-divergent bars
    (the same runs) are left out and the title says so."""
    e, u = sch.error, unit(sch.error, sch)
    filters = ordered_filters(summary["filter"], sch.filters)
    s = summary.set_index("filter").loc[filters]
    x = np.arange(len(filters))
    cols = [colors[f] for f in filters]
    diverging = bool(sch.divergence) and int(np.nansum(s["diverged"].to_numpy(dtype=float))) > 0
    panels = 2 if diverging else 1
    fig = new_figure((max(7.0, 1.6 * len(filters) + 3) if panels == 2 else max(4.5, 1.0 * len(filters) + 2.5),
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
        err = errorbar(mean, lo, hi)
        err[:, ~ok] = 0.0
        rects = ax.bar(xs, np.nan_to_num(mean), width, yerr=err, capsize=3, **style)
        for r, okay in zip(rects, ok):
            if not okay:
                r.set_alpha(0.25)
                r.set_hatch("xx")
        top = np.nan_to_num(mean) + np.nan_to_num(err[1])  # the upper cap (the bar's top without one)
        for xv, mv, tv, nv in zip(xs, mean, top, n):
            if np.isfinite(mv):
                ax.annotate(f"n={nv}", (xv, tv), textcoords="offset points", xytext=(0, 3), ha="center",
                            va="bottom", fontsize=7)

    if diverging:
        w = 0.38
        bars(ax1, x - w / 2, s[f"{e}_mean"], s[f"{e}_ci_low"], s[f"{e}_ci_high"], s["n_err"], w, color=cols)
        bars(ax1, x + w / 2, s[f"{e}_ok_mean"], s[f"{e}_ok_ci_low"], s[f"{e}_ok_ci_high"], s["n_ok_err"], w,
             color=cols, alpha=0.5, hatch="//", edgecolor="0.3")
        ax1.legend(handles=[Patch(facecolor="0.45", label="all runs"),
                            Patch(facecolor="0.45", alpha=0.5, hatch="//", edgecolor="0.3",
                                  label="non-divergent runs")], fontsize="small")
        maybe_log_y(ax1, np.r_[s[f"{e}_mean"].to_numpy(dtype=float), s[f"{e}_ok_mean"].to_numpy(dtype=float)])
    else:
        bars(ax1, x, s[f"{e}_mean"], s[f"{e}_ci_low"], s[f"{e}_ci_high"], s["n_err"], 0.6, color=cols)
        maybe_log_y(ax1, s[f"{e}_mean"].to_numpy(dtype=float))
    ax1.set_xticks(x)
    ax1.set_xticklabels(names, rotation=20)
    ax1.set_ylabel(with_unit(f"mean {e}", u))
    ax1.set_title(f"Mean {e} ({PCT} t-interval)", fontsize="medium")
    ax1.grid(True, axis="y", alpha=0.3, which="both")
    if diverging:
        ax2 = axs[1]
        bars(ax2, x, s["div_rate"], s["div_ci_low"], s["div_ci_high"], s["n"], 0.6, color=cols)
        top = min(1.05, max(0.05, 1.12 * float(np.nanmax(np.r_[s["div_ci_high"].to_numpy(dtype=float), 0.0]))))
        ax2.set_ylim(0, top)
        ax2.set_xticks(x)
        ax2.set_xticklabels(names, rotation=20)
        ax2.set_ylabel("divergence rate (% of runs)")
        ax2.set_title(f"Divergence rate ({PCT} Wilson interval)", fontsize="medium")
        ax2.grid(True, axis="y", alpha=0.3)
        percent_ticks(ax2.yaxis)
    what = f"{e} and divergence" if diverging else e
    calm = "; no run diverged" if sch.divergence and not diverging else ""
    fig.suptitle(f"Single sweep point: {what} per filter{calm}\n{n_range(summary['n'], 'filter')}; "
                 f"n on each bar: the runs it rests on", fontsize="medium")
    text = "The n above each bar is the number of runs it rests on."
    if calm:
        text += " No run diverged, so no divergence rate is drawn."
    if few_total:
        text += f" {few_total} bar(s) rest on fewer than {MIN_RUNS} runs: hatched, without interval."
    return fig, text
