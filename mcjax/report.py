"""Entry points of the report on a sweep's output folder (``OUT/runs/*.parquet``).

* :func:`report` -- reads ``OUT`` with :mod:`mcjax.results` and returns the formatted
  summary table plus the PNG plots written to ``OUT/report/`` (what ``mcjax report`` prints).
* :func:`summary_text` -- the same table from an in-memory runs table and its metadata
  dict (what ``mcjax sweep`` and ``mcjax run`` print after running).

Everything -- the error metric, the divergence flag, graph statistics, filter order, units,
descriptions, swept axes -- comes from the dataset's metadata (the scenario's declarations
written by the sweep).  The pieces live in :mod:`mcjax.statistics` (intervals),
:mod:`mcjax.tables` (the summary table and its formats) and :mod:`mcjax.plots` (figures).

This module does not import JAX.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping

import pandas as pd

from mcjax import results, tables
from mcjax.tables import FORMATS

__all__ = ["FORMATS", "summary_text", "report"]


def summary_text(df: pd.DataFrame, metadata: Mapping[str, Any], fmt: str = "text") -> str:
    """The summary table of a runs table, grouped by the metadata's swept axes × filter.

    For ``"text"`` and ``"markdown"`` the table is preceded by the legend of
    :func:`mcjax.tables.legend_lines` (scenario, then one line per metric and swept axis
    with its unit and description, then how the statistics are computed); ``"csv"`` is the
    bare table.

    Raises:
        ValueError: ``fmt`` is not one of :data:`FORMATS`; ``df`` is empty; the metadata
            declares no outputs (a dataset from an older mcjax) or does not fit ``df``.
    """
    tables.check_format(fmt)
    if not isinstance(df, pd.DataFrame):
        raise TypeError(f"df must be a pandas DataFrame, got {type(df).__name__}")
    if df.empty:
        raise ValueError("summary_text: the runs table is empty")
    sch = tables.schema(metadata, df.columns)
    axes = tables.swept_axes(metadata, df.columns)
    summary = tables.summarize(df, metadata, axes)
    return tables.format_table(summary, fmt, tables.legend_lines(sch, axes))


def report(out_dir: str | os.PathLike, fmt: str = "text", *,
           plots: bool = True) -> tuple[str, list[Path]]:
    """Summarise a sweep's output folder: ``(formatted table, plot paths)``.

    Reads ``OUT/runs`` (:func:`mcjax.results.read_table`) and its metadata
    (:func:`mcjax.results.read_metadata`), formats the table of :func:`summary_text` and,
    unless ``plots=False``, writes the figures of :func:`mcjax.plots.make_plots` to
    ``OUT/report/``.

    Raises:
        ValueError: ``fmt`` is not one of :data:`FORMATS`; ``out_dir`` holds no runs (the
            message names the folder); its metadata declares no outputs (written by an
            older mcjax; the message names the folder and says what to do).
    """
    tables.check_format(fmt)
    if not isinstance(out_dir, (str, os.PathLike)) or str(out_dir) == "":
        raise TypeError(f"out_dir must be a non-empty str or os.PathLike, got {out_dir!r}")
    out = Path(out_dir)
    df = results.read_table(out)
    if df.empty:
        raise ValueError(f"no runs found in {str(out)!r}: expected Parquet part files in "
                         f"{str(out / 'runs')!r} (is this the output folder of `mcjax sweep`?)")
    metadata = results.read_metadata(out)
    try:
        tables.schema(metadata, df.columns)
    except ValueError as exc:
        raise ValueError(f"cannot report on {str(out)!r}: {exc}") from None
    table = summary_text(df, metadata, fmt)
    if not plots:
        return table, []
    from mcjax.plots import make_plots  # matplotlib only when plotting

    return table, make_plots(df, metadata, out)
