"""The report's summary table: runs grouped by swept axes × filter into statistics, and the
table as text, CSV or Markdown.

Everything here is read from the dataset's metadata (the scenario's declarations, see
:mod:`mcjax.contract`); nothing names a scenario, a filter or a unit. What the metadata says
about the columns is :mod:`mcjax.analysis.schema`'s; its names below are re-exported here:

* :func:`schema` -- the :class:`Schema` of a metadata dict: which column holds the error
  metric, the divergence flag, the graph statistics (by their declared *role*), the filter
  display order, the output and parameter declarations.  A dataset without output
  declarations (written by an older mcjax) is a ValueError.
* :func:`swept_axes` -- the swept parameter columns (keys of the spec's ``grid`` then
  ``zip`` tables that are columns).
* :func:`unit`, :func:`label` -- a column's declared unit and its ``"name [unit]"`` label;
  :func:`display`, :func:`axis_label` -- the unit a parameter is plotted in (km, deg, ...).
* :func:`ordered_filters` -- filter values in display order.
* :func:`summary_columns`, :func:`summarize` -- one row per (swept axes..., filter) with the
  statistics of :mod:`mcjax.analysis.statistics`.
* :func:`legend_lines` -- one line per metric the table shows and per axis: its unit and description;
  :func:`in_table_units` -- the axes in the tables' units (an angle in degrees, :func:`table_unit`).
* :func:`format_table`, :func:`format_cells`, :func:`format_number` -- rendering (one number
  format for every table and plot).

Summary columns, with ``<err>`` the error column's name (e.g. ``rmse``), in this order:

* ``n`` -- runs in the group;
* ``<err>_mean``, ``<err>_ci_low``, ``<err>_ci_high`` -- mean over the runs with a finite
  error and its 95 % Student-t interval;
* with a divergence flag: ``n_ok`` (runs not flagged), ``<err>_ok_mean``,
  ``<err>_ok_ci_low``, ``<err>_ok_ci_high`` (the same over those runs), ``diverged``
  (flagged runs);
* ``nonfinite`` -- runs with a non-finite error (the ``nonfinite`` role's column when
  declared, else counted from the error column);
* with a divergence flag: ``div_rate`` (``diverged / n``), ``div_ci_low``, ``div_ci_high``
  (95 % Wilson interval);
* with graph statistics, named after their columns: ``<connectivity_mean column>`` (mean
  over runs), ``<connectivity_min column>`` (minimum over runs),
  ``<disconnected_steps column>_mean`` (mean over runs).

This module imports neither JAX nor matplotlib.
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd

from mcjax.analysis.schema import (  # noqa: F401
    OPTIONAL_ROLES,
    Schema,
    axis_label,
    declaration,
    display,
    filter_rank,
    in_table_units,
    label,  # (re-exported: the report's modules read them here)
    ordered_filters,
    resolve_axes,
    scaled,
    schema,
    swept_axes,
    table_unit,
    unit,
)
from mcjax.analysis.statistics import CONFIDENCE, mean_ci, wilson_interval

__all__ = [
    "FORMATS",
    "KEY_COLUMNS",
    "Schema",
    "schema",
    "swept_axes",
    "unit",
    "label",
    "display",
    "axis_label",
    "ordered_filters",
    "prepare",
    "resolve_axes",
    "summary_columns",
    "summarize",
    "legend_lines",
    "TABLE_ROLES",
    "scaled",
    "in_table_units",
    "table_unit",
    "check_format",
    "format_number",
    "format_cells",
    "format_table",
]

#: Output formats accepted by :func:`format_table`.
FORMATS = ("text", "csv", "markdown")
#: Key columns of a runs table (besides the swept axes).
KEY_COLUMNS = ("scenario", "point_id", "seed_index", "filter")

def _hashable(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        return tuple(_hashable(v) for v in value)
    return value


def prepare(df: pd.DataFrame, axes: Sequence[str]) -> pd.DataFrame:
    """``df`` with list/array-valued axis cells (per-agent parameters) as hashable tuples
    (the same object when there are none)."""
    data = df
    for a in axes:
        col = df[a]
        if col.dtype == object and col.map(lambda v: isinstance(v, (list, tuple, np.ndarray))).any():
            if data is df:
                data = df.copy()
            data[a] = col.map(_hashable)
    return data


def _as_bool(s: pd.Series) -> np.ndarray:
    return pd.array(s, dtype="boolean").fillna(False).to_numpy(dtype=bool)


def _finite_stat(fn, values: pd.Series) -> float:
    x = values.to_numpy(dtype=float)
    x = x[np.isfinite(x)]
    return float(fn(x)) if x.size else math.nan


def summary_columns(metadata: Mapping[str, Any] | Schema) -> list[str]:
    """Statistics columns of :func:`summarize` (after the axes and ``filter``), in order."""
    sch = schema(metadata)
    e = sch.error
    cols = ["n", f"{e}_mean", f"{e}_ci_low", f"{e}_ci_high"]
    if sch.divergence:
        cols += ["n_ok", f"{e}_ok_mean", f"{e}_ok_ci_low", f"{e}_ok_ci_high", "diverged"]
    cols.append("nonfinite")
    if sch.divergence:
        cols += ["div_rate", "div_ci_low", "div_ci_high"]
    if sch.connectivity_mean:
        cols.append(sch.connectivity_mean)
    if sch.connectivity_min:
        cols.append(sch.connectivity_min)
    if sch.disconnected_steps:
        cols.append(f"{sch.disconnected_steps}_mean")
    return cols


def _group_stats(g: pd.DataFrame, sch: Schema) -> list[Any]:
    err = g[sch.error].to_numpy(dtype=float)
    n = len(g)
    row: list[Any] = [n, *mean_ci(err)]
    if sch.divergence:
        div = _as_bool(g[sch.divergence])
        k = int(div.sum())
        row += [n - k, *mean_ci(err[~div]), k]
    nonfinite = (int(_as_bool(g[sch.nonfinite]).sum()) if sch.nonfinite
                 else int((~np.isfinite(err)).sum()))
    row.append(nonfinite)
    if sch.divergence:
        row += [k / n, *wilson_interval(k, n)]
    if sch.connectivity_mean:
        row.append(_finite_stat(np.mean, g[sch.connectivity_mean]))
    if sch.connectivity_min:
        row.append(_finite_stat(np.min, g[sch.connectivity_min]))
    if sch.disconnected_steps:
        row.append(_finite_stat(np.mean, g[sch.disconnected_steps]))
    return row


def summarize(df: pd.DataFrame, metadata: Mapping[str, Any] | Schema,
              axes: str | Sequence[str] | None = None) -> pd.DataFrame:
    """Summary of a runs table: one row per combination of ``axes`` and ``filter``.

    Args:
        df: runs table (one row per run and filter) with ``filter``, the axes and the
            columns named by the metadata's roles.
        metadata: the dataset's metadata (or its :class:`Schema`).
        axes: columns to group by; ``None`` (default): the swept axes of the metadata's spec
            (:func:`swept_axes`); ``[]`` pools every run of a filter.  List-valued cells
            (per-agent values) are grouped as tuples.  Runs at values of axes not listed
            are pooled.

    Returns:
        DataFrame with columns ``[*axes, "filter", *summary_columns(metadata)]`` (see the
        module docstring), sorted by the axes and then by filter (the metadata's order
        first), with a fresh index.
    """
    if not isinstance(df, pd.DataFrame):
        raise TypeError(f"summarize: df must be a pandas DataFrame, got {type(df).__name__}")
    sch = schema(metadata)
    if df.empty:
        axes = swept_axes(sch, df.columns) if axes is None else ([axes] if isinstance(axes, str) else list(axes))
        return pd.DataFrame(columns=[*axes, "filter", *summary_columns(sch)])
    schema(sch, df.columns)
    axes = resolve_axes(sch, df.columns, axes)
    if "filter" not in df.columns:
        raise ValueError(f"summarize: no 'filter' column in the runs table; it has {list(df.columns)}")
    keys = [*axes, "filter"]
    columns = [*keys, *summary_columns(sch)]
    data = prepare(df, axes)
    rows = []
    for key, g in data.groupby(keys, sort=False, dropna=False):
        key = key if isinstance(key, tuple) else (key,)
        rows.append([*key, *_group_stats(g, sch)])
    out = pd.DataFrame(rows, columns=columns)
    out["_rank"] = out["filter"].map(filter_rank(list(sch.filters)))
    out = out.sort_values([*axes, "_rank"], kind="stable").drop(columns="_rank")
    return out.reset_index(drop=True)


def _unit_text(u: str) -> str:
    return u if u else "no unit"


#: The roles whose column a summary table shows (a statistic of it: :func:`summary_columns`); the
#: others (NEES, NIS, the floor) have tables of their own, and the legend does not name them.
TABLE_ROLES = ("divergence", "nonfinite", "connectivity_mean", "connectivity_min", "disconnected_steps")


def legend_lines(metadata: Mapping[str, Any] | Schema, axes: Sequence[str] = (), *,
                 table_units: bool = False) -> list[str]:
    """Lines to print above a summary table: the scenario, then one line per metric the table
    shows (``"rmse: <unit> — <description>"``, :data:`TABLE_ROLES`) and per axis, then how the
    statistics columns are computed. ``table_units``: the table shows its axes in the tables' units
    (:func:`in_table_units`: an angle in degrees), which the axes' lines then name (``"turn_rate:
    deg/s (stored as rad/s)"``)."""
    sch = schema(metadata)
    lines = []
    if sch.scenario:
        lines.append(f"scenario: {sch.scenario}" + (f" — {sch.title}" if sch.title else ""))
    metrics = [sch.error, *(getattr(sch, r) for r in TABLE_ROLES)]
    for name in [m for m in metrics if m is not None] + list(axes):
        decl = declaration(name, sch)
        desc = str(decl.get("description") or "").strip()
        stored = _unit_text(unit(name, sch))
        shown = _unit_text(table_unit(name, sch)[0]) if table_units and name in axes else stored
        text = shown if shown == stored else f"{shown} (stored as {stored})"
        lines.append(f"{name}: {text}" + (f" — {desc}" if desc else ""))
    pct = f"{100 * CONFIDENCE:g} %"
    e = sch.error
    text = (f"statistics: n runs per row; {e}_mean over the runs with a finite {e}, "
            f"{e}_ci_low/high its {pct} Student-t interval")
    if sch.divergence:
        text += (f"; {e}_ok_*: the same over the runs with {sch.divergence} false; "
                 f"div_rate = diverged / n, div_ci_low/high its {pct} Wilson interval")
    lines.append(text)
    return lines


def check_format(fmt: Any) -> str:
    """``fmt`` if it is one of :data:`FORMATS`, else a ValueError naming it and the allowed values."""
    if not isinstance(fmt, str) or fmt not in FORMATS:
        raise ValueError(f"fmt={fmt!r} is not a supported format; allowed values: "
                         + ", ".join(repr(f) for f in FORMATS))
    return fmt


def format_number(value: Any, digits: int = 4) -> str:
    """A cell as text: integers as such, floats to ``digits`` significant digits
    (positional in [1e-4, 10^max(digits, 7)), else scientific), tuples element-wise."""
    if value is None or value is pd.NA:
        return "nan"
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        v = float(value)
        if not math.isfinite(v):
            return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
        if v == 0:
            return "0"
        if 1e-4 <= abs(v) < 10.0 ** max(digits, 7):
            return np.format_float_positional(v, precision=digits, unique=False,
                                              fractional=False, trim="-")
        return f"{v:.{digits - 1}e}"
    if isinstance(value, (tuple, list, np.ndarray)):
        return "(" + ", ".join(format_number(v, digits) for v in value) + ")"
    return str(value)


#: Significant digits of a table's key columns (up to ``filter``) and of its statistics.
KEY_DIGITS, STAT_DIGITS = 6, 4


def format_cells(summary: pd.DataFrame) -> tuple[list[str], list[list[str]], list[bool]]:
    """``(headers, rows of cell texts, numeric column flags)`` of a table, every cell by
    :func:`format_number`: :data:`KEY_DIGITS` significant digits up to the ``filter``
    column, :data:`STAT_DIGITS` after. The one number format of the sweep's printed
    summary, ``mcjax report``'s text and Markdown tables and the HTML report."""
    columns = list(summary.columns)
    n_keys = columns.index("filter") + 1 if "filter" in columns else 0
    headers = [str(c) for c in columns]
    rows = [[format_number(v, KEY_DIGITS if i < n_keys else STAT_DIGITS) for i, v in enumerate(row)]
            for row in summary.itertuples(index=False, name=None)]
    numeric = [pd.api.types.is_numeric_dtype(summary[c]) and not pd.api.types.is_bool_dtype(summary[c])
               for c in columns]
    return headers, rows, numeric


def terminal_width() -> int | None:
    """The terminal's width in columns: ``COLUMNS`` when set, else the terminal's when standard output
    (``sys.stdout``, as a caller may have replaced it) is one; None otherwise (a file, a pipe, a test's
    captured output: the tables are printed whole)."""
    import os
    import shutil
    import sys

    env = os.environ.get("COLUMNS", "").strip()
    if env.isdigit() and int(env) > 0:
        return int(env)
    try:
        tty = sys.stdout is not None and sys.stdout.isatty()
    except (AttributeError, ValueError, OSError):
        tty = False
    columns = shutil.get_terminal_size(fallback=(0, 0)).columns if tty else 0
    return columns if columns > 0 else None


def format_table(summary: pd.DataFrame, fmt: str = "text", header: Sequence[str] = (), width: int | None = None) -> str:
    """Render a :func:`summarize` table (any DataFrame works) as a string.

    ``fmt``:

    * ``"text"``: the ``header`` lines, a blank line, then aligned plain-text columns
      (numbers right-aligned; 6 significant digits up to the ``filter`` column, 4 after); with a
      ``width`` (a terminal's columns) a table wider than it is cut into blocks of columns that fit,
      each block repeating the key columns (the swept axes and ``filter``), and the header lines wrapped;
    * ``"csv"``: ``DataFrame.to_csv`` without index, full precision, no header lines;
    * ``"markdown"``: the ``header`` lines as a bullet list, a blank line, then a GitHub
      pipe table with the same number formatting as ``"text"``.

    Raises:
        ValueError: ``fmt`` is not one of :data:`FORMATS` (the message names ``fmt`` and
            the allowed values).
        TypeError: ``summary`` is not a DataFrame.
    """
    check_format(fmt)
    if not isinstance(summary, pd.DataFrame):
        raise TypeError(f"summary must be a pandas DataFrame, got {type(summary).__name__}")
    if fmt == "csv":
        return summary.to_csv(index=False)
    headers, rows, numeric = format_cells(summary)
    if fmt == "markdown":
        def esc(s: str) -> str:
            return s.replace("|", "\\|")

        lines = [f"- {h}" for h in header] + ([""] if header else [])
        lines += ["| " + " | ".join(esc(h) for h in headers) + " |",
                  "|" + "|".join("---:" if num else ":---" for num in numeric) + "|"]
        lines += ["| " + " | ".join(esc(c) for c in row) + " |" for row in rows]
        return "\n".join(lines) + "\n"
    widths = [max([len(h), *(len(r[i]) for r in rows)]) for i, h in enumerate(headers)]

    def line(cells: list[str]) -> str:
        return "  ".join(c.rjust(w) if num else c.ljust(w)
                         for c, w, num in zip(cells, widths, numeric)).rstrip()

    lines = list(header) + ([""] if header else [])
    if width is None or len(line(headers)) <= width:
        return "\n".join([*lines, line(headers), *(line(r) for r in rows)]) + "\n"
    import textwrap

    lines = [w for h in header for w in (textwrap.wrap(h, width, subsequent_indent="  ") or [""])]
    lines += [""] if header else []
    keys = list(range(headers.index("filter") + 1)) if "filter" in headers else [0]
    rest = [i for i in range(len(headers)) if i not in keys]
    blocks, block = [], []
    for i in rest:  # as many columns as fit beside the key columns (at least one per block)
        if block and sum(widths[j] + 2 for j in keys + block + [i]) - 2 > width:
            blocks.append(block)
            block = []
        block.append(i)
    blocks.append(block)
    for n, block in enumerate(blocks):
        cols = keys + block

        def cut(cells: list[str]) -> str:
            return "  ".join(cells[i].rjust(widths[i]) if numeric[i] else cells[i].ljust(widths[i]) for i in cols).rstrip()

        lines += ([""] if n else []) + [cut(headers), *(cut(r) for r in rows)]
    return "\n".join(lines) + "\n"
