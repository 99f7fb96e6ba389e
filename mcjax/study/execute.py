"""Who computes a study's chunks, and publishing them: an :class:`Executor` computes the
chunks somewhere and hands their rows back; :func:`run_sweep` writes each chunk's parts as it
arrives (:func:`publish_chunk`), so the files, the resume bookkeeping and the provenance are
the same whoever computed the rows. :class:`LocalExecutor` computes in this process (the
default); :class:`mcjax.study.dask.DaskExecutor` on the workers of a Dask cluster.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterator, NamedTuple, Protocol

import pandas as pd

from mcjax.base import parquet
from mcjax.study.plan import Study
from mcjax.study.rows import chunk_keys, part_metadata, run_rows, timeseries_rows
from mcjax.study.sensitivity import declarations


class ChunkRows(NamedTuple):
    """What one chunk of a sweep produced, ready to be published as part files: its index in
    the chunk plan, its runs ``start … stop−1``, its tidy rows (:func:`run_rows`) and, when
    the spec asks for them, its per-step rows (:func:`timeseries_rows`; else None)."""

    index: int
    start: int
    stop: int
    runs: pd.DataFrame
    timeseries: pd.DataFrame | None


class ChunkError(RuntimeError):
    """A chunk failed while it was computed (on a Dask worker), or could not be written; the
    message, one line, names the chunk, the points it covers and the error."""


class WriteError(ChunkError):
    """Writing a chunk's parts failed (a full disk, a lost mount: any OSError). No partial part
    is visible (each part is written whole or not at all); the chunks written before stay, and
    ``--resume`` re-runs this one. The message, one line, names the chunk, the file and the
    error, and says how to finish."""


def chunk_rows(study: Study, chunks: list[int] | None = None) -> Iterator[ChunkRows]:
    """Compute every chunk (or only ``chunks``) of a sweep in this process, in plan order, and
    yield each one's rows. The batch program is compiled once per process and Config
    (:func:`mcjax.engine.run_chunks`), so later calls for other chunks reuse it."""
    from mcjax import engine

    for idx, start, stop, out in engine.run_chunks(study.scenario, study.config, study.params, study.seeds,
                                                   base_seed=study.base_seed, chunk_size=study.chunk_size,
                                                   chunks=None if chunks is None else set(chunks),
                                                   timeseries=study.timeseries, sensitivity=study.sensitivity):
        series = None
        if study.timeseries:
            out, series = out
        rows = run_rows(study.scenario, study.config, out, chunk_keys(study, start, stop - start),
                        declarations(study.scenario, study.config, study.sensitivity))
        yield ChunkRows(idx, start, stop, rows, None if series is None else timeseries_rows(study, start, series))


class Executor(Protocol):
    """Computes the chunks of a sweep somewhere and hands their rows back to the caller, which
    publishes them (:func:`run_sweep`). Implementations: :class:`LocalExecutor` (this process,
    the default) and :class:`mcjax.study.dask.DaskExecutor` (the workers of a Dask cluster)."""

    def map_chunks(self, study: Study, chunks: list[int],
                   should_stop: Callable[[], bool]) -> Iterator[ChunkRows]:
        """Yield the rows of every chunk of ``chunks`` once, in any order, as each completes.
        Stop early (leaving the rest undone) when ``should_stop()`` turns True, or when the
        caller closes the iterator. A failed chunk raises (the Dask executor raises
        :class:`ChunkError`)."""
        ...


class LocalExecutor:
    """Computes the chunks in this process, one after the other, in plan order (the default;
    a chunk's batches are spread over this machine's CPU devices by the engine)."""

    def map_chunks(self, study: Study, chunks: list[int],
                   should_stop: Callable[[], bool]) -> Iterator[ChunkRows]:
        if not should_stop():
            yield from chunk_rows(study, chunks)


def publish_chunk(out_dir: str | Path, rows: ChunkRows, metadata: dict) -> None:
    """Write a chunk's rows as its part files (one per point it touches, in ``runs/`` and, with
    per-step rows, ``timeseries/``), each atomically (:func:`mcjax.base.parquet.write_part`:
    staging file, fsync, rename). The chunk counts as done once all its parts exist."""
    tables = [("runs", rows.runs)] + ([("timeseries", rows.timeseries)] if rows.timeseries is not None else [])
    for name, frame in tables:
        for pid, part in frame.groupby("point_id", sort=True):  # hive layout: OUT/<table>/point_id=P/
            parquet.write_part(out_dir, name, part, f"part-{rows.index:06d}", metadata,
                               partition={"point_id": int(pid)})


def run_sweep(study: Study, out_dir: str | Path | None = None, *, chunks: list[int] | None = None,
              progress: Callable[[int], None] | None = None,
              should_stop: Callable[[], bool] | None = None, executor: Executor | None = None,
              keep: bool = True) -> pd.DataFrame:
    """Run every chunk (or only ``chunks``) of a sweep with ``executor`` (default: this
    process, :class:`LocalExecutor`); write each chunk as its part files as soon as it
    completes, into ``out_dir`` (default: the study's own ``out_dir``; None for both: nothing
    is written) — this process writes every file, whoever computed the rows; return the rows of the chunks run, in chunk order
    (``keep=False``: none are kept, an empty frame is returned — a million-run sweep's rows stay
    on disk only). ``progress(runs)`` is told
    after each chunk is written. ``should_stop()`` is asked before the first chunk and after
    each one: True stops the sweep there (the chunks done stay written). No empty staging
    folder is left behind. A part that cannot be written (an OSError: a full disk) stops the
    sweep with :class:`WriteError`."""
    out_dir = study.out_dir if out_dir is None else out_dir
    plan = study.plan
    todo = list(range(len(plan))) if chunks is None else [i for i in chunks if 0 <= i < len(plan)]
    stop = should_stop or (lambda: False)
    metadata = None
    done = {}
    work = (executor or LocalExecutor()).map_chunks(study, todo, stop)
    try:
        for rows in work:
            if out_dir is not None:
                if metadata is None:
                    metadata = part_metadata(study, study.chunk_runs)
                try:
                    publish_chunk(out_dir, rows, metadata)
                except OSError as exc:
                    where = f" ({exc.filename})" if exc.filename else ""
                    raise WriteError(f"writing the parts of chunk {rows.index} failed: {exc.strerror or exc}{where}; "
                                     f"no partial part is left; once there is room, finish with --resume") from None
            if keep:
                done[rows.index] = rows.runs
            if progress is not None:
                progress(rows.stop - rows.start)
            if stop():
                break
    finally:
        close = getattr(work, "close", None)
        if close is not None:
            close()  # a remote executor cancels what is still queued or running
        if out_dir is not None:
            parquet.remove_empty_staging(out_dir)
    return pd.concat([done[i] for i in sorted(done)], ignore_index=True) if done else pd.DataFrame()

