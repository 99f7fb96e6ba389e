"""The sweep runner: a sweep spec into its output folder, as ``mcjax sweep`` does it — the saved
values of a resumed sweep, the folder made ready (lock, identity file, ``--resume``, ``--force``),
every chunk still to run written as its parts, and the summary's columns read back.

It reports through callbacks (``message``, ``warn``, ``progress``, ``should_stop``) and raises
the pipeline's exceptions (:class:`SpecError`, :class:`OutputError`, :class:`ChunkError`): no
printing, no exit. ``mcjax sweep`` turns them into its lines and exit codes; a Python caller
gets a :class:`SweepResult`::

    from mcjax.study.runner import load_sweep, run_sweep_folder
    study = load_sweep("sweeps/default.toml", seeds=10)
    result = run_sweep_folder(study, spec_file="sweeps/default.toml")
    result.rows            # the summary's columns of every run, read back from the parts
"""

from __future__ import annotations

import contextlib
import time
from pathlib import Path
from typing import Any, Callable, Iterable, NamedTuple

import pandas as pd

from mcjax import configure, scenarios
from mcjax.base import parquet
from mcjax.study.execute import Executor, run_sweep
from mcjax.study.plan import Study
from mcjax.study.rows import shown_filters
from mcjax.study.spec import load_spec
from mcjax.study.store import IDENTITY_FILE, default_out_dir, prepare_output, read_identity


class SweepProgress(NamedTuple):
    """Where a sweep stands in its output folder: ``chunks_done`` of the plan's ``chunks`` are
    written, holding ``runs_done`` of the study's ``runs``."""

    chunks_done: int
    chunks: int
    runs_done: int
    runs: int


class SweepResult(NamedTuple):
    """What :func:`run_sweep_folder` did: the ``study`` run into ``out_dir``; ``chunks_run``
    chunks holding ``runs_run`` runs computed by this call in ``seconds`` (compilation included);
    ``stopped``: ``should_stop()`` turned True (the chunks written stay, for ``--resume``);
    ``rows``: the runs read back from the folder (None when stopped)."""

    study: Study
    out_dir: Path
    chunks_run: int
    runs_run: int
    seconds: float
    stopped: bool
    rows: pd.DataFrame | None


def _ignore(*_: Any) -> None:
    return None


def load_sweep(spec_file: str | Path, *, out_dir: str | Path | None = None, seeds: int | None = None,
               chunk_size: int | None = None, overrides: dict[str, Any] | None = None,
               resume: bool = False) -> Study:
    """Read and validate the sweep spec ``spec_file`` into its :class:`Study` (output folder
    ``out_dir``, default ``results/<spec name>``). ``seeds``, ``chunk_size`` and ``overrides``
    (``--set`` values, key path → value) override the spec's; with ``resume``, those left out
    (None) are the ones the interrupted sweep in ``out_dir`` saved in its ``sweep.json``.
    Raises :class:`OutputError` (no or a damaged ``sweep.json`` to resume) or :class:`SpecError`."""
    out_dir = default_out_dir(spec_file) if out_dir is None else out_dir
    if resume:  # what the interrupted sweep was given, unless given again
        saved = read_identity(out_dir)
        seeds = seeds if seeds is not None else saved["seeds"]
        chunk_size = chunk_size if chunk_size is not None else saved["chunk_size"]
        overrides = overrides if overrides is not None else saved.get("set", {})
    return load_spec(spec_file, seeds=seeds, chunk_size=chunk_size, overrides=overrides or {}, out_dir=out_dir)


def sweep_headline(study: Study) -> str:
    """One line: the scenario, points × seeds = runs, the chunk plan and the filters."""
    return (f"scenario {scenarios.describe(study.scenario)}: {study.n_points} point(s) x {study.seeds} seed(s) = "
            f"{study.n_runs} runs, {len(study.plan)} chunk(s) of {study.chunk_runs}, filters "
            f"{', '.join(shown_filters(study.scenario, study.config))}")


def summary_columns(study: Study) -> list[str]:
    """The columns the summary table reads (keys, axes, outputs with a role): what a big sweep loads back."""
    return ["point_id", "filter", *study.axes,
            *(k for k, o in study.scenario.outputs(study.config).items() if o.role is not None)]


class NamedSweep(NamedTuple):
    """One of several sweeps a command runs in turn (:func:`run_named_sweeps`): its ``name`` (its rows'
    key, and what ``progress`` is told), its ``folder``, the ``study``, the ``spec_file`` it was read
    from (None: written inline or built), the ``columns`` of its runs to read back, and its ``label``
    in the messages (default: the name)."""

    name: str
    folder: Path
    study: Study
    spec_file: Path | None = None
    columns: list[str] | None = None
    label: str | None = None


def run_named_sweeps(sweeps: Iterable[NamedSweep], *, resume: bool = False, executor: Executor | None = None,
                     message: Callable[[str], None] | None = None, warn: Callable[[str], None] | None = None,
                     progress: Callable[[str, SweepProgress], None] | None = None,
                     should_stop: Callable[[], bool] | None = None) -> dict[str, pd.DataFrame] | None:
    """Run ``sweeps`` in turn, each into its own folder (:func:`run_sweep_folder`), as ``mcjax check``
    and ``mcjax league`` do: with ``resume``, a folder that already holds its sweep is resumed (one
    that does not is started); ``message`` says each name before and its runs and seconds after,
    ``progress(name, SweepProgress)``. Returns each sweep's rows by name, or None when
    ``should_stop()`` stopped one (the chunks written stay, for ``--resume``)."""
    say = message or _ignore
    rows: dict[str, pd.DataFrame] = {}
    for sweep in sweeps:
        label = sweep.label or sweep.name
        say(f"{label}:")
        result = run_sweep_folder(sweep.study, spec_file=sweep.spec_file, out_dir=sweep.folder,
                                  resume=resume and (sweep.folder / IDENTITY_FILE).is_file(), executor=executor,
                                  columns=sweep.columns, message=say, warn=warn,
                                  progress=(lambda at, name=sweep.name: progress(name, at)) if progress else None,
                                  should_stop=should_stop)
        if result.stopped:
            return None
        if result.runs_run:
            say(f"{label}: {result.runs_run} runs in {result.seconds:.1f} s (compilation included)")
        rows[sweep.name] = result.rows
    return rows


def run_sweep_folder(study: Study, *, spec_file: str | Path | None = None, out_dir: str | Path | None = None,
                     resume: bool = False, force: bool = False, executor: Executor | None = None,
                     columns: list[str] | None = None,
                     message: Callable[[str], None] | None = None, warn: Callable[[str], None] | None = None,
                     progress: Callable[[SweepProgress], None] | None = None,
                     should_stop: Callable[[], bool] | None = None) -> SweepResult:
    """Run ``study`` into ``out_dir`` (default: the study's own) as ``mcjax sweep`` does.

    Takes the folder's lock for the run and makes the folder ready
    (:func:`mcjax.study.store.prepare_output`: a fresh sweep needs it empty or missing,
    ``force`` replaces a previous sweep, ``resume`` finds the chunks still to run; the spec file
    and its base config must not be inside it), then computes every chunk still to run with
    ``executor`` (default: this process) and writes each as its parts
    (:func:`mcjax.study.execute.run_sweep`); at the end reads ``columns`` (default: the
    summary's, :func:`summary_columns`) of every run back from the folder.

    ``message(line)``: the headline and, resuming, how many chunks were written before;
    ``warn(line)``: each damaged or missing part a resume found, and a folder reused because it
    held only a sweep that wrote nothing; ``progress(SweepProgress)``:
    once when the folder is ready (what it held already) and after each chunk written (the
    runs add up to the study's ``n_runs``); ``should_stop()``: asked before the first chunk and
    after each, True stops the sweep there (``stopped`` in the result; the parts written are
    whole). Raises :class:`OutputError` (the folder cannot be used as asked, before anything is
    written) or :class:`ChunkError` (a chunk failed or could not be written; the chunks written
    before stay)."""
    configure()  # JAX's process settings, before anything computes (mcjax.configure)
    say, tell, stop = message or _ignore, progress or _ignore, should_stop or (lambda: False)
    out_dir = Path(study.out_dir if out_dir is None else out_dir)
    keep = [] if spec_file is None else [Path(spec_file), (Path(spec_file).parent / study.source["base"]).resolve()]
    with contextlib.ExitStack() as held:  # the folder's lock
        todo = prepare_output(study, out_dir, resume=resume, force=force, keep=keep, spec_file=spec_file,
                              note=warn or _ignore, hold=held)
        say(sweep_headline(study))
        chunks = len(study.plan)
        before = 0 if todo is None else chunks - len(todo)
        if todo is not None:
            say(f"resuming: {before} of {chunks} chunk(s) already written")
        remaining = study.runs_in(todo)
        done = SweepProgress(before, chunks, study.n_runs - remaining, study.n_runs)
        tell(done)
        t0 = time.perf_counter()

        def chunk_written(runs: int) -> None:
            nonlocal done
            done = done._replace(chunks_done=done.chunks_done + 1, runs_done=done.runs_done + runs)
            tell(done)

        run_sweep(study, out_dir, chunks=todo, progress=chunk_written, should_stop=stop, executor=executor,
                  keep=False)
    run = (done.chunks_done - before, done.runs_done - (study.n_runs - remaining))
    if stop():
        return SweepResult(study, out_dir, *run, time.perf_counter() - t0, True, None)
    elapsed = time.perf_counter() - t0
    rows = parquet.read_table(out_dir, "runs", summary_columns(study) if columns is None else columns)
    return SweepResult(study, out_dir, *run, elapsed, False, rows)
