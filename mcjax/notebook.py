"""mcjax from Python (a notebook, a script): a sweep or one config point in one call, the rows
with their summary and metadata back, nothing written unless asked::

    import mcjax.notebook as mc

    res = mc.sweep("sweeps/comm_radius.toml", seeds=50, set={"params.sigma_range": 20.0})
    res.rows          # one row per run and filter: the same rows `mcjax sweep` writes
    res.summary       # per point and filter: means with their 95 % intervals, divergence rates
    res.table()       # the summary table `mcjax sweep` prints
    res.findings()    # "What this shows": sentences backed by their intervals
    res.figures()     # the report's figures as matplotlib Figures (a cell shows each)

    one = mc.run("configs/sun2011.toml", seeds=20)        # one point of a config, as `mcjax run`

A spec may also be a dict (the TOML's tables; ``base`` relative to ``base_dir``). ``out="DIR"``
writes the dataset as ``mcjax sweep --out DIR`` would (then ``mcjax report DIR`` works on it);
``progress=True`` draws a bar (tqdm's notebook form in Jupyter, a text bar in a terminal).
Errors are the pipeline's: :class:`SpecError` (``mc.SpecError``, the class of :mod:`mcjax.study`,
defined in :mod:`mcjax.base.validation`) names the key path and the allowed values, one line per
mistake, and the keyword arguments as written here (``seeds``, ``chunk_size``, ``set['params.x']``).
``res.rows`` has the dataset's column order (``point_id``, the folder name, last), whether or not
it was written.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

import pandas as pd

from mcjax import configure
from mcjax.base.validation import SpecError

if TYPE_CHECKING:
    from mcjax.analysis.summary import Summary

__all__ = ["SpecError", "SweepRows", "sweep", "run"]


@dataclass(frozen=True, eq=False)  # frames inside: compared by identity
class SweepRows:
    """A sweep's runs in memory: ``rows`` (one per run and filter, every output), ``metadata`` (the
    declarations, spec and provenance a dataset carries), ``summary`` (per swept point and filter,
    :func:`mcjax.analysis.tables.summarize`), ``axes`` (the swept parameters) and ``out_dir`` (where the
    dataset was written, or None). ``built``: the :class:`mcjax.analysis.summary.Summary` ``summary``
    is the table of; the table, findings and figures read it (built once when not given)."""

    rows: pd.DataFrame
    metadata: Mapping[str, Any]
    summary: pd.DataFrame
    axes: tuple[str, ...]
    out_dir: Path | None = None
    built: Summary | None = field(default=None, repr=False)

    @cached_property
    def _one(self) -> Summary:
        from mcjax.analysis.summary import summarize_dataset

        return self.built if self.built is not None else summarize_dataset(self.rows, self.metadata)

    def table(self, fmt: str = "text") -> str:
        """The summary table as ``mcjax sweep`` prints it (``fmt``: text, markdown or csv)."""
        from mcjax.report import summary_text

        return summary_text(self.rows, self.metadata, fmt, summary=self._one)

    def findings(self) -> list[str]:
        """The sentences of the report's "What this shows" (:func:`mcjax.analysis.findings.findings`)."""
        from mcjax.analysis.findings import findings

        return [f.text for f in findings(self.rows, self.metadata, summary=self._one)]

    def figures(self) -> list:
        """The report's figures of these rows: :class:`mcjax.report.plots.Plot` records (``name``,
        ``figure`` — a matplotlib Figure a notebook cell displays —, ``caption``)."""
        from mcjax.report.plots import Plot, plots

        return [p for p in plots(self.rows, self.metadata, summary=self._one) if isinstance(p, Plot)]


def _bar(total: int, progress: bool):
    if not progress:
        return None
    from tqdm.auto import tqdm  # the notebook widget in Jupyter, a text bar in a terminal

    return tqdm(total=total, unit="run", desc="runs")


def _execute(study, out: str | Path | None, force: bool, progress: bool, spec_file=None) -> SweepRows:
    from mcjax.analysis.summary import summarize_dataset
    from mcjax.base import parquet
    from mcjax.study import part_metadata, run_sweep, run_sweep_folder

    configure()
    bar = _bar(study.n_runs, progress)
    try:
        if out is None:  # nothing written
            rows = run_sweep(study, None, progress=None if bar is None else bar.update)
            metadata = part_metadata(study, study.chunk_runs)
        else:  # as `mcjax sweep --out`: the folder's lock, identity file and parts; the rows read back
            run_sweep_folder(study, spec_file=spec_file, out_dir=out, force=force,
                             progress=None if bar is None else (lambda p: bar.update(p.runs_done - bar.n)))
            rows, metadata = parquet.read_table(out), parquet.read_metadata(out)
    finally:
        if bar is not None:
            bar.close()
    rows = _dataset_order(rows)
    one = summarize_dataset(rows, metadata)  # the one summary its table, findings and figures read
    return SweepRows(rows, metadata, one.table, one.axes, None if out is None else Path(out), one)


def _dataset_order(rows: pd.DataFrame) -> pd.DataFrame:
    """``rows`` with the columns in the dataset's order, as pandas, DuckDB and polars read ``OUT/runs``:
    the part files' columns, then ``point_id`` (the folder name, ``runs/point_id=P/``). The rows in
    memory have it second, :func:`mcjax.base.parquet.read_table` first."""
    if "point_id" not in rows.columns:
        return rows
    return rows[[c for c in rows.columns if c != "point_id"] + ["point_id"]]


def sweep(spec: str | Path | Mapping[str, Any], *, seeds: int | None = None, set: Mapping[str, Any] | None = None,
          chunk_size: int | None = None, base_dir: str | Path = ".", out: str | Path | None = None,
          force: bool = False, progress: bool = False) -> SweepRows:
    """Run a sweep spec — a TOML file's path or its tables as a dict (``base`` relative to
    ``base_dir``) — and return its :class:`SweepRows`. ``seeds``, ``chunk_size`` and ``set`` (key
    path → value, as ``--set``) override the spec's. ``out``: also write the dataset there (an
    empty or missing folder; ``force`` replaces a previous sweep), as ``mcjax sweep --out``.
    The rows are the ones ``mcjax sweep`` writes for the same spec and overrides, bit for bit."""
    from mcjax.study import build_spec, load_spec
    from mcjax.study.spec import KEYWORDS

    if isinstance(spec, Mapping):
        study = build_spec(dict(spec), Path(base_dir), seeds=seeds, chunk_size=chunk_size, overrides=dict(set or {}),
                           out_dir=out, given_as=KEYWORDS)
    else:
        study = load_spec(spec, seeds=seeds, chunk_size=chunk_size, overrides=dict(set or {}), out_dir=out,
                          given_as=KEYWORDS)
    return _execute(study, out, force, progress, None if isinstance(spec, Mapping) else spec)


def run(config: str | Path, *, seeds: int | None = None, set: Mapping[str, Any] | None = None,
        progress: bool = False) -> SweepRows:
    """Run one point of a config file (``configs/*.toml``) as ``mcjax run`` does — its ``seeds``
    (the paper's run count) unless given, ``set`` overrides — and return its :class:`SweepRows`
    (nothing written)."""
    from mcjax.study import build_spec
    from mcjax.study.spec import KEYWORDS

    study = build_spec({"base": str(Path(config).resolve())}, Path.cwd(), seeds=seeds, overrides=dict(set or {}),
                       given_as=KEYWORDS)
    return _execute(study, None, False, progress)
