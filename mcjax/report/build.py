"""Entry points of the report on a sweep's output folder (``OUT/runs/*.parquet``).

* :func:`report` -- reads ``OUT`` with :mod:`mcjax.base.parquet` and returns the formatted
  summary table plus the files written to ``OUT/report/``: the PNG plots, then
  ``index.html`` (what ``mcjax report`` prints).
* :func:`summary_text` -- the same table from an in-memory runs table and its metadata
  dict (what ``mcjax sweep`` and ``mcjax run`` print after running).

Everything -- the error metric, the divergence flag, graph statistics, filter order, units,
descriptions, swept axes -- comes from the dataset's metadata (the scenario's declarations
written by the sweep).  The pieces live in :mod:`mcjax.analysis.statistics` (intervals),
:mod:`mcjax.analysis.tables` (the summary table and its formats) and :mod:`mcjax.report.plots` (figures).

This module does not import JAX.
"""

from __future__ import annotations

import json
import os
import shlex
import tomllib
from pathlib import Path
from typing import Any, Callable, Mapping

import pandas as pd

from mcjax.analysis import tables
from mcjax.analysis.summary import Summary, summarize_dataset, summary_for
from mcjax.analysis.tables import FORMATS
from mcjax.base import parquet

__all__ = ["FORMATS", "summary_text", "report", "completeness", "datasets_in", "listing", "base_params_from_files"]

#: The sweep's identity file in its output folder (written by :mod:`mcjax.study.store`).
IDENTITY_FILE = "sweep.json"


def summary_text(df: pd.DataFrame, metadata: Mapping[str, Any], fmt: str = "text",
                 warning: str | None = None, *, summary: Summary | None = None, width: int | None = None) -> str:
    """The summary table of a runs table, grouped by the metadata's swept axes × filter.

    For ``"text"`` and ``"markdown"`` the table is preceded by the legend of
    :func:`mcjax.analysis.tables.legend_lines` (scenario, then one line per metric and swept axis
    with its unit and description, then how the statistics are computed) and shows an angle in
    degrees, as the plots and the page do (:func:`mcjax.analysis.tables.in_table_units`);
    ``"csv"`` is the bare table in the dataset's units. ``summary``: the page's :class:`mcjax.analysis.summary.Summary` of ``df`` (built
    here when not given). ``width``: a terminal's columns, which the text table then fits
    (:func:`mcjax.analysis.tables.format_table`); None: one block, however wide.

    Raises:
        ValueError: ``fmt`` is not one of :data:`FORMATS`; ``df`` is empty; the metadata
            declares no outputs (a dataset from an older mcjax) or does not fit ``df``.
    """
    tables.check_format(fmt)
    if not isinstance(df, pd.DataFrame):
        raise TypeError(f"df must be a pandas DataFrame, got {type(df).__name__}")
    if df.empty:
        raise ValueError("summary_text: the runs table is empty")
    one = summary_for(df, metadata, tables.swept_axes(metadata, df.columns), summary)
    if fmt == "csv":  # a program's table: the dataset's units, no header
        return tables.format_table(one.table, fmt)
    # an angle in degrees, as the plots and the page show it (rad/s read by no one), the legend saying so
    header = tables.legend_lines(one.schema, one.axes, table_units=True)
    return tables.format_table(tables.in_table_units(one.table, one.schema, one.axes), fmt,
                               ([f"WARNING: {warning}"] if warning else []) + header, width)


def _identity(out: Path) -> dict | None:
    """The folder's sweep.json: {} when there is none, None when it is damaged."""
    if not (out / IDENTITY_FILE).exists():
        return {}
    try:
        saved = json.loads((out / IDENTITY_FILE).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    return saved if isinstance(saved, dict) else None


def completeness(out_dir: str | os.PathLike, df: pd.DataFrame, metadata: Mapping[str, Any]) -> str | None:
    """None if the dataset holds every run its sweep planned, else one line saying how many
    are present and how to finish it. The plan is the parts' ``n_runs`` (or the folder's
    ``sweep.json`` for datasets written before parts recorded it); without either, None. A
    damaged ``sweep.json`` is said instead (the folder can then not be resumed)."""
    out = Path(out_dir)
    saved = _identity(out)
    if saved is None:
        return (f"{out / IDENTITY_FILE} is damaged, so this folder cannot be resumed (the table below is "
                f"complete as far as its parts go); start the sweep again with --force to repair it")
    planned = metadata.get("n_runs", saved.get("n_runs"))
    if not isinstance(planned, int) or isinstance(planned, bool) or not {"point_id", "seed_index"} <= set(df.columns):
        return None
    present = len(df[["point_id", "seed_index"]].drop_duplicates())
    if present >= planned:
        return None
    spec = saved.get("spec_file") if isinstance(saved.get("spec_file"), str) else "SPEC"
    return (f"incomplete dataset: {present} of {planned} planned runs present ({planned - present} missing); "
            f"finish it with `mcjax sweep {shlex.quote(spec)} --out {shlex.quote(str(out))} --resume`")


def base_params_from_files(out_dir: str | os.PathLike, metadata: Mapping[str, Any]) -> dict | None:
    """For a dataset that does not record its base Params (no ``base_params`` in its
    metadata): ``{"values": ..., "path": ...}``, the ``[params]`` table of its spec's base
    config file (found from ``sweep.json``'s spec file) as that file is now, with the spec's own
    ``[params]`` (and ``--set`` values) over it; None when the files do not say."""
    if isinstance(metadata.get("base_params"), Mapping):
        return None
    spec = metadata.get("spec") if isinstance(metadata.get("spec"), Mapping) else {}
    spec_file = (_identity(Path(out_dir)) or {}).get("spec_file")
    base = spec.get("base")
    if not isinstance(spec_file, str) or not isinstance(base, str):
        return None
    path = Path(os.path.normpath(Path(spec_file).parent / base))
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return None
    params = data.get("params") if isinstance(data.get("params"), dict) else {}
    own = spec.get("params") if isinstance(spec.get("params"), Mapping) else {}
    return {"values": {**params, **own}, "path": str(path)}


def datasets_in(folder: str | os.PathLike) -> list[Path]:
    """The dataset folders directly inside ``folder`` (each with a ``runs/`` folder holding
    Parquet parts), sorted by name: what ``results/`` holds after a few sweeps."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    return sorted(d for d in folder.iterdir()
                  if d.is_dir() and (d / "runs").is_dir() and next((d / "runs").rglob("*.parquet"), None))


def listing(folder: str | os.PathLike, inside: list[Path]) -> str:
    """What ``mcjax report FOLDER`` prints for a folder of datasets: one line per dataset with
    its scenario, runs and description, and the command that reports on it."""
    lines = [f"{folder} holds {len(inside)} dataset(s), not one; report on one of them:"]
    for d in inside:
        try:
            meta = parquet.read_metadata(d)
        except (OSError, ValueError):
            meta = {}
        spec = meta.get("spec") if isinstance(meta.get("spec"), Mapping) else {}
        what = [str(meta["scenario"])] if meta.get("scenario") else []
        if isinstance(meta.get("n_runs"), int):
            what.append(f"{meta['n_runs']} runs planned")
        if isinstance(spec.get("description"), str):
            what.append(spec["description"])
        lines.append(f"  mcjax report {shlex.quote(str(d))}" + (f"    # {'; '.join(what)}" if what else ""))
    return "\n".join(lines) + "\n"


def report(out_dir: str | os.PathLike, fmt: str = "text", *, plots: bool = True,
           warn: Callable[[str], None] | None = None, width: int | None = None) -> tuple[str, list[Path]]:
    """Summarise a sweep's output folder: ``(formatted table, plot paths)``.

    Reads ``OUT/runs`` (:func:`mcjax.base.parquet.read_table`) and its metadata
    (:func:`mcjax.base.parquet.read_metadata`), formats the table of :func:`summary_text` and,
    unless ``plots=False``, writes the figures of :func:`mcjax.report.plots.write_plots` to
    ``OUT/report/`` and then the self-contained page ``OUT/report/index.html``
    (:mod:`mcjax.report.html_page`: description, spec, provenance, tables, every plot with its
    caption), whose path is the last of the returned paths. The folder of ``mcjax check``
    (``check.json``) gets its verdict table as the text, each of its sweeps' reports, then the
    forest plot and the page that leads with the verdicts (:mod:`mcjax.report.claims_page`).
    The folder of a tune (``tune.json``,
    ``trace.parquet``) gets :mod:`mcjax.report.tune_page`'s table (a ``role`` column first) and page
    instead, and no plots; a folder of
    datasets (e.g. ``results/``) gets :func:`listing` as its text and no files. A dataset with
    fewer runs than its sweep planned (:func:`completeness`)
    gets a ``WARNING:`` line at the top of the table's header (``warn`` is told too: CSV has
    no header) and a note on every plot.

    Raises:
        ValueError: ``fmt`` is not one of :data:`FORMATS`; ``out_dir`` does not exist (the
            message names the sibling folder it may have meant) or holds no runs (the message
            names the folder); a part file is damaged
            (:class:`mcjax.base.parquet.DamagedPartError`, naming it); its metadata declares no
            outputs (written by an older mcjax; the message names the folder and says what to do).
    """
    tables.check_format(fmt)
    if not isinstance(out_dir, (str, os.PathLike)) or str(out_dir) == "":
        raise TypeError(f"out_dir must be a non-empty str or os.PathLike, got {out_dir!r}")
    out = Path(out_dir)
    if not out.exists():  # not "no runs found": there is no folder to find them in
        from mcjax.base.validation import near_path

        raise ValueError(f"folder {out_dir} does not exist{near_path(out_dir, folder=True)}")
    from mcjax.claims.folder import is_check_folder
    from mcjax.league.folder import is_league_folder

    if is_league_folder(out):  # the league table and its page
        from mcjax.report.league_page import report_league

        return report_league(out, fmt, plots=plots)
    if is_check_folder(out):  # the verdict table first, each sweep's report, then the verdicts' page
        from mcjax.report.claims_page import report_check_folder

        try:
            return report_check_folder(out, fmt, plots=plots, warn=warn, sweep_report=report)
        except FileNotFoundError as exc:
            raise ValueError(str(exc)) from None
    try:
        df = parquet.read_table(out)
    except parquet.DamagedPartError as exc:  # name the spec to resume with, when the folder says it
        spec = (_identity(out) or {}).get("spec_file")
        raise parquet.DamagedPartError(str(exc).replace("mcjax sweep SPEC", f"mcjax sweep {shlex.quote(spec)}")
                                       if isinstance(spec, str) else str(exc)) from None
    if df.empty:
        inside = datasets_in(out)
        if inside:
            return listing(out, inside), []
        raise ValueError(f"no runs found in {str(out)!r}: expected Parquet part files in "
                         f"{str(out / 'runs')!r} (is this the output folder of `mcjax sweep`?)")
    metadata = parquet.read_metadata(out)
    try:
        tables.schema(metadata, df.columns)
    except ValueError as exc:
        raise ValueError(f"cannot report on {str(out)!r}: {exc}") from None
    incomplete = completeness(out, df, metadata)
    if incomplete and warn is not None:
        warn(incomplete)
    from mcjax.report import tune_page

    tune = tune_page.is_tune_folder(out)
    # a sweep's one summary: its table, findings, quality sentences, figures and page all read it
    one = None if tune else summarize_dataset(df, metadata)
    table = (tune_page.summary_table(out, df, metadata, fmt, warning=incomplete) if tune
             else summary_text(df, metadata, fmt, warning=incomplete, summary=one, width=width))
    if not plots:
        return table, []
    if tune:  # a two-point zip: the tune's own page, no sweep plots
        return table, [tune_page.write_page(out, df, metadata, warning=incomplete)]
    from mcjax.report.html_page import write_page
    from mcjax.report.plots import write_plots  # matplotlib only when plotting

    note = incomplete and incomplete.split(";")[0].replace("incomplete", "INCOMPLETE", 1)
    series = None
    if parquet.existing_parts(out, "timeseries"):  # the per-step figures (the floor, NEES against its band)
        series = (parquet.read_table(out, "timeseries"), parquet.read_metadata(out, "timeseries"))
    written, skipped = write_plots(df, metadata, out, note=note, timeseries=series, summary=one)
    files = base_params_from_files(out, metadata)
    page = write_page(out, df, {**metadata, "base_params_file": files} if files else metadata, written, skipped,
                      warning=incomplete, summary=one)
    return table, [p.path for p in written] + [page]
