"""What the report's figures share: the records (:class:`Plot`, :class:`Skipped`,
:class:`PlotFile`), the constants of the honest-plot rules, the x axis of a swept parameter
(:class:`XAxis`, :func:`x_axis`), filter colours, and small drawing helpers (a figure on its
own Agg canvas, tick labels and interval bars in the tables' formats).

This module does not import JAX.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterable, Mapping, NamedTuple, Sequence

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, NullFormatter

from mcjax.analysis.statistics import CONFIDENCE
from mcjax.analysis.tables import Schema, format_number, ordered_filters

__all__ = ["PALETTE", "MIN_RUNS", "MAX_PANELS", "SAME_RTOL", "PCT", "LOG_Y_DECADES", "DPI", "percent_ticks", "Plot", "Skipped", "PlotFile", "XAxis",
           "x_axis", "spans_decades", "number_ticks", "maybe_log_y", "with_unit", "filter_colors", "new_figure",
           "n_range", "errorbar", "one_row_per_run", "Stat"]

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
#: A plotted mean gets a log axis (y axis, heatmap colours) when its values span more than
#: this many decades.
LOG_Y_DECADES = 1.0
#: Resolution of the written PNG files: twice the figures' layout resolution (100 dpi), so a
#: page showing them at their layout size is sharp on high-density screens.
DPI = 200
#: The confidence level as the captions say it ("95 %").
PCT = f"{100 * CONFIDENCE:g} %"


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
    return XAxis(name, values, numeric, numeric and spans_decades(pos.values()), pos, unit, factor)


def spans_decades(values: Iterable[float], decades: float = 2.0) -> bool:
    """Whether the finite ``values`` are all positive and span more than ``decades``
    decades (the rule for a log scale)."""
    v = np.asarray([x for x in values if x is not None], dtype=float)
    v = v[np.isfinite(v)]
    return bool(v.size and np.all(v > 0) and v.max() / v.min() > 10.0**decades)


def number_ticks(axis) -> None:
    """Tick labels of ``axis`` in the tables' number format (:func:`mcjax.analysis.tables.format_number`)."""
    axis.set_major_formatter(FuncFormatter(lambda v, _: format_number(float(v), 4)))


def maybe_log_y(ax, values: Iterable[float]) -> None:
    """A log y scale when the plotted means ``values`` span more than a decade (:data:`LOG_Y_DECADES`:
    735 m beside 11 m would flatten every value but the largest on a linear axis); tick labels in
    the tables' number format."""
    if spans_decades(values, LOG_Y_DECADES):
        ax.set_yscale("log")
        ax.yaxis.set_minor_formatter(NullFormatter())
    number_ticks(ax.yaxis)


def percent_ticks(axis) -> None:
    """Tick labels of a rate's ``axis`` (fractions) in percent: ``"20 %"``."""
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{100 * float(v):.4g} %"))


def with_unit(text: str, u: str) -> str:
    """``"text [unit]"``, or ``text`` without a unit."""
    return f"{text} [{u}]" if u else text


def filter_colors(values: Iterable[Any], order: Sequence[str]) -> dict[Any, str]:
    """Colour of each distinct filter value: :data:`PALETTE` by position in ``order``
    (the metadata's ``filters``), then the unknown values alphabetically."""
    order = list(order)
    known = {f: i for i, f in enumerate(order)}
    extra = sorted({str(v) for v in values} - set(order))
    index = {**known, **{f: len(order) + i for i, f in enumerate(extra)}}
    return {v: PALETTE[index[str(v)] % len(PALETTE)] for v in pd.unique(pd.Series(list(values), dtype=object))}


def new_figure(figsize: tuple[float, float]) -> Figure:
    """A constrained-layout Figure on its own Agg canvas (no pyplot, no global backend)."""
    fig = Figure(figsize=figsize, dpi=100, layout="constrained")
    FigureCanvasAgg(fig)  # explicit Agg canvas: no pyplot, no global backend switch
    return fig


def n_range(n: np.ndarray, what: str) -> str:
    """``"n = N runs per WHAT"`` or ``"n = LO–HI runs per WHAT"`` of the counts ``n``."""
    n = np.asarray(n, dtype=int)
    if n.size == 0:
        return ""
    lo, hi = int(n.min()), int(n.max())
    return f"n = {lo} runs per {what}" if lo == hi else f"n = {lo}–{hi} runs per {what}"


def errorbar(mean, lo, hi) -> np.ndarray:
    """The ``(2, k)`` error-bar lengths of an interval around ``mean`` (0 where undefined)."""
    mean, lo, hi = (np.asarray(v, dtype=float) for v in (mean, lo, hi))
    return np.clip(np.vstack([np.nan_to_num(mean - lo), np.nan_to_num(hi - mean)]), 0, None)


def one_row_per_run(df: pd.DataFrame, sch: Schema, axes: Sequence[str]) -> pd.DataFrame:
    """One row per run (for per-run outputs, which repeat across filters)."""
    if {"point_id", "seed_index"} <= set(df.columns):
        return df.drop_duplicates(subset=["point_id", "seed_index"])
    if "seed_index" in df.columns:
        return df.drop_duplicates(subset=["seed_index", *axes])
    return df[df["filter"] == ordered_filters(df["filter"], sch.filters)[0]]


class Stat(NamedTuple):
    """What a line or heatmap figure draws: a summary column, its interval, the runs each
    point rests on, and whether it is a rate."""

    column: str      # summary column drawn
    low: str         # its interval
    high: str
    count: str       # summary column with the runs each point rests on
    rate: bool       # a proportion (error bars) rather than a mean (shaded interval)
