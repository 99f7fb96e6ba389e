"""Which figures a runs table gets, and writing them: :func:`plots` (made one at a time),
:func:`figures`, :func:`write_plots` and :func:`make_plots`; the rules are in
:mod:`mcjax.report.plots`.

This module does not import JAX.
"""

from __future__ import annotations

import itertools
import os
import re
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from mcjax.analysis import tables
from mcjax.report.plots.bars import bar_figure
from mcjax.report.plots.common import (DPI, MAX_PANELS, PALETTE, PCT, SAME_RTOL, Plot, PlotFile, Skipped, Stat, XAxis,
                                filter_colors, one_row_per_run, with_unit, x_axis)
from mcjax.analysis.summary import Summary, summarize_dataset, summary_for
from mcjax.analysis.tables import Schema, axis_label, display, label, unit
from mcjax.report.plots.heatmaps import heatmap_figure
from mcjax.report.plots.lines import connectivity_figure, line_figure
from mcjax.report.plots.sensitivity import sensitivity_columns, sensitivity_figure
from mcjax.report.plots.steps import step_plots

__all__ = ["plots", "figures", "write_plots", "make_plots"]

def _axis_for(name: str, values: Sequence[Any], sch: Schema) -> XAxis:
    shown, factor = display(name, sch)
    return x_axis(name, values, shown, factor)


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", str(name))


def _facets(data: pd.DataFrame, others: Sequence[str]) -> list[tuple]:
    """The combinations of the other axes' values present in ``data``, sorted."""
    if not others:
        return [()]
    combos = list(data[list(others)].drop_duplicates().itertuples(index=False, name=None))
    try:
        return sorted(combos)
    except TypeError:
        return combos


def _pooled_note(others: Sequence[str], axes: Mapping[str, XAxis], why: str) -> str:
    counts = " × ".join(f"{len(axes[o].values)} {o}" for o in others)
    return f"pooled over {', '.join(others)} ({counts} values): {why}"


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


def _summary_with_counts(summary: Summary, axes: Sequence[str]) -> pd.DataFrame:
    """The page's summary by ``axes`` (:meth:`~mcjax.analysis.summary.Summary.by`) with the
    counts of :func:`_counts`."""
    s = summary.by(axes)
    c = _counts(summary.data, [*axes, "filter"], summary.schema)
    return s.merge(c, on=[*axes, "filter"], how="left", sort=False)


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
          axes: str | Sequence[str] | None = None, *, summary: Summary | None = None) -> Iterator[Plot | Skipped]:
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
      the filter);
    * with sensitivity columns of the error (a sweep's ``[sensitivity]``),
      ``sensitivity_<err>_vs_<A>.png``: the mean error and, under it, the mean derivative
      with respect to each differentiated Param (:mod:`mcjax.report.plots.sensitivity`).

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

    Where no run diverged, the divergence figures and the non-divergent runs' (every run's) are
    left out, each with a :class:`Skipped` record saying so.

    ``summary``: the page's :class:`mcjax.analysis.summary.Summary` of ``df`` (built here when
    not given): the figures draw its numbers.

    Raises:
        ValueError: the table is empty, or the metadata does not fit it (see
            :func:`mcjax.analysis.tables.schema`).
    """
    if not isinstance(df, pd.DataFrame):
        raise TypeError(f"figures: df must be a pandas DataFrame, got {type(df).__name__}")
    if df.empty:
        raise ValueError("figures: the runs table is empty")
    sch = tables.schema(metadata, df.columns)
    tables.resolve_axes(sch, df.columns, axes)
    if "filter" not in df.columns:
        raise ValueError(f"figures: no 'filter' column in the runs table; it has {list(df.columns)}")
    summary = summary_for(df, metadata, axes, summary)
    sch, data = summary.schema, summary.data
    colors = filter_colors(data["filter"], sch.filters)
    e = sch.error
    err_label = label(e, sch)
    u = unit(e, sch)
    xaxes = _plot_axes(data, summary.plot_axes, sch)
    plot_axes = list(xaxes)
    # no run diverged: no divergence rate to draw, and the non-divergent runs are every run
    calm = bool(sch.divergence) and int(summary.table["diverged"].sum()) == 0
    if calm:
        why = f"no run diverged ({sch.divergence} false in all {len(summary.data)} rows)"
    if not xaxes:
        s = _summary_with_counts(summary, [])
        fig, text = bar_figure(s, sch, colors)
        yield Plot("summary_bars.png", fig, f"One sweep point: the mean {err_label} per filter over all runs"
                   + (" and over the non-divergent runs, and the divergence rate" if sch.divergence and not calm
                      else "") + f" ({PCT} intervals). " + text)
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
        s = _summary_with_counts(summary, [name, *panel_axes])
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
            fig, text = line_figure(
                s, xa, sch, colors, Stat(f"{e}_mean", f"{e}_ci_low", f"{e}_ci_high", "n_err", False),
                panel_axes, facets, xaxes, title=f"Mean {e} vs {name} (shaded: {PCT} t-interval)",
                ylabel=f"mean {err_label}", pooled=pooled)
            yield Plot(f"{_safe(e)}_vs_{tag}.png", fig,
                       f"Mean {err_label} over the runs with a finite {e}, against {x_text}, one line per "
                       f"filter; shaded: its {PCT} Student-t interval.{where} {text}")
            if calm:
                yield Skipped(f"{_safe(e)}_nondiverged_vs_{tag}.png", f"{why}: the same as {_safe(e)}_vs_{tag}.png")
                yield Skipped(f"divergence_vs_{tag}.png", f"{why}: every rate is 0")
            elif sch.divergence:
                fig, text = line_figure(
                    s, xa, sch, colors,
                    Stat(f"{e}_ok_mean", f"{e}_ok_ci_low", f"{e}_ok_ci_high", "n_ok_err", False),
                    panel_axes, facets, xaxes,
                    title=f"Mean {e} of non-divergent runs vs {name} (shaded: {PCT} t-interval)",
                    ylabel=with_unit(f"mean {e}, non-divergent runs", u), pooled=pooled)
                yield Plot(f"{_safe(e)}_nondiverged_vs_{tag}.png", fig,
                           f"Mean {err_label} over the runs that did not diverge ({sch.divergence} false), "
                           f"against {x_text}, one line per filter; shaded: its {PCT} Student-t interval. "
                           f"How many runs that is varies with the divergence rate.{where} {text}")
                fig, text = line_figure(
                    s, xa, sch, colors, Stat("div_rate", "div_ci_low", "div_ci_high", "n", True),
                    panel_axes, facets, xaxes,
                    title=f"Divergence rate vs {name} (bars: {PCT} Wilson interval)",
                    ylabel="divergence rate (% of runs)", pooled=pooled)
                yield Plot(f"divergence_vs_{tag}.png", fig,
                           f"Percentage of runs with {sch.divergence} true, against {x_text}, one line per "
                           f"filter (shifted sideways a little so equal rates stay apart); bars: its {PCT} "
                           f"Wilson interval.{where} {text}")
        derivatives = sensitivity_columns(data.columns, sch)
        if derivatives:
            spooled = _pooled_note(others, xaxes, "the sensitivity figure draws one line per filter") if others else None
            fig, text = sensitivity_figure(data, xa, sch, colors, derivatives, spooled)
            yield Plot(f"sensitivity_{_safe(e)}_vs_{tag}.png", fig,
                       f"Mean {err_label} against {x_text}, one line per filter. {text}"
                       + (f" Runs {spooled}." if spooled else ""))
        if sch.connectivity:
            runs = one_row_per_run(data, sch, plot_axes)
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
                fig, text = connectivity_figure(data, xa, sch, cothers, cfacets, xaxes, cpooled)
                lines = f" One line per value of {', '.join(cothers)}." if cothers else ""
                yield Plot(cname, fig,
                           f"Graph connectivity against {x_text}, once per run (the comm graph does not depend "
                           f"on the filter): the mean over runs of {sch.connectivity_mean or '–'} with its {PCT} "
                           f"t-interval, the smallest {sch.connectivity_min or '–'} of any run, and the mean "
                           f"{sch.disconnected_steps or '–'} per run.{lines}"
                           + (f" Runs {cpooled}." if cpooled else "") + f" {text}")
    for (na, a), (nb, b) in itertools.combinations(xaxes.items(), 2):
        rest = [o for o in plot_axes if o not in (na, nb)]
        pooled = (_pooled_note(rest, xaxes, "a heatmap shows two axes; the line plots show each value")
                  if rest else None)
        s = _summary_with_counts(summary, [na, nb])
        tag = f"{_safe(na)}__{_safe(nb)}"
        grid_text = f"{axis_label(na, sch)} × {axis_label(nb, sch)}"
        extra = f" Cells {pooled}." if pooled else ""
        if calm:
            yield Skipped(f"heatmap_divergence_{tag}.png", f"{why}: every rate is 0")
        elif sch.divergence:
            fig, text = heatmap_figure(s, a, b, sch, Stat("div_rate", "div_ci_low", "div_ci_high", "n", True),
                                        title=f"Divergence rate over {na} × {nb}", cbar_label="divergence rate",
                                        pooled=pooled)
            yield Plot(f"heatmap_divergence_{tag}.png", fig,
                       f"Divergence rate over {grid_text}, one panel per filter.{extra} {text}")
        fig, text = heatmap_figure(s, a, b, sch, Stat(f"{e}_mean", f"{e}_ci_low", f"{e}_ci_high", "n_err", False),
                                    title=f"Mean {e} over {na} × {nb}", cbar_label=f"mean {err_label}",
                                    pooled=pooled)
        yield Plot(f"heatmap_{_safe(e)}_{tag}.png", fig,
                   f"Mean {err_label} (runs with a finite {e}) over {grid_text}, one panel per filter.{extra} {text}")
        if calm:
            yield Skipped(f"heatmap_{_safe(e)}_nondiverged_{tag}.png", f"{why}: the same as heatmap_{_safe(e)}_{tag}.png")
        elif sch.divergence:
            fig, text = heatmap_figure(
                s, a, b, sch, Stat(f"{e}_ok_mean", f"{e}_ok_ci_low", f"{e}_ok_ci_high", "n_ok_err", False),
                title=f"Mean {e} of non-divergent runs over {na} × {nb}",
                cbar_label=with_unit(f"mean {e}, non-divergent runs", u), pooled=pooled)
            yield Plot(f"heatmap_{_safe(e)}_nondiverged_{tag}.png", fig,
                       f"Mean {err_label} of the non-divergent runs over {grid_text}, one panel per filter."
                       f"{extra} {text}")


def figures(df: pd.DataFrame, metadata: Mapping[str, Any] | Schema,
            axes: str | Sequence[str] | None = None, *, summary: Summary | None = None
            ) -> Iterator[tuple[str, Figure]]:
    """``(file name, Figure)`` for each :class:`Plot` of :func:`plots`, made one at a time."""
    for item in plots(df, metadata, axes, summary=summary):
        if isinstance(item, Plot):
            yield item.name, item.figure


def write_plots(df: pd.DataFrame, metadata: Mapping[str, Any] | Schema, out_dir: str | os.PathLike,
                axes: str | Sequence[str] | None = None,
                note: str | None = None, timeseries: tuple[pd.DataFrame, Mapping[str, Any]] | None = None,
                *, summary: Summary | None = None) -> tuple[list[PlotFile], list[Skipped]]:
    """Write the :func:`plots` of a runs table as PNG files (at :data:`~mcjax.report.plots.common.DPI`,
    twice the layout's resolution) to ``out_dir/report/`` (created if missing): the written files with their captions, in the order made, and
    the plots skipped. ``note`` (e.g. that the dataset is incomplete) is printed in red
    along the bottom of every figure. ``timeseries`` (the timeseries table and its metadata)
    adds the per-step figures of :func:`mcjax.report.plots.steps.step_plots`. ``summary``: the
    page's :class:`mcjax.analysis.summary.Summary` of ``df`` (built once here when not given)."""
    report_dir = Path(out_dir) / "report"
    written: list[PlotFile] = []
    skipped: list[Skipped] = []
    if summary is None and isinstance(df, pd.DataFrame) and not df.empty and "filter" in df.columns:
        summary = summarize_dataset(df, metadata, axes)  # once, for the figures and the per-step ones
    steps = step_plots(*timeseries, df, metadata, summary=summary) if timeseries is not None else ()
    for item in itertools.chain(plots(df, metadata, axes, summary=summary), steps):
        if isinstance(item, Skipped):
            skipped.append(item)
            continue
        report_dir.mkdir(parents=True, exist_ok=True)
        fig = item.figure
        if note:
            fig.supxlabel(note, color="#b00000", fontsize="small")  # constrained layout makes room
        path = report_dir / item.name
        fig.savefig(path, format="png", dpi=DPI)
        fig.clear()
        written.append(PlotFile(path, item.caption))
    return written, skipped


def make_plots(df: pd.DataFrame, metadata: Mapping[str, Any] | Schema, out_dir: str | os.PathLike,
               axes: str | Sequence[str] | None = None, note: str | None = None) -> list[Path]:
    """The paths of :func:`write_plots`."""
    return [p.path for p in write_plots(df, metadata, out_dir, axes, note)[0]]
