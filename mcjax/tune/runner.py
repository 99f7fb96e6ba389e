"""The tune runner: a tune spec into its output folder, as ``mcjax tune`` does it — the folder
made ready (lock, ``tune.json``, ``--resume``, ``--force``), the optimisation from its last saved
step, the trace's plot, then the held-out evaluation of the initial and the tuned Params in the
sweep's format, read back with the paired differences.

It reports through callbacks (``message``, ``progress``, ``started``, ``should_stop``) and
raises the pipeline's exceptions (:class:`SpecError`, :class:`OutputError`; an ``OSError`` or
:class:`ChunkError` when a file cannot be written): no printing, no exit. ``mcjax tune`` turns
them into its lines and exit codes; a Python caller gets a :class:`TuneResult`::

    from mcjax.tune import load_tune_spec
    from mcjax.tune.runner import run_tune
    result = run_tune(load_tune_spec("sweeps/tune_sun2011.toml"), out_dir="results/tune")
    result.trace, result.runs, result.paired
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, NamedTuple

import pandas as pd

from mcjax import configure, scenarios
from mcjax.base import parquet
from mcjax.study.plan import Study
from mcjax.study.store import hold_output, prepare_evaluation
from mcjax.tune.optimise import (TRACE_FILE, evaluation_spec, final_values, finished, load_state, optimise,
                                 paired_differences, plot_trace, prepare_tune_output, run_evaluation)
from mcjax.tune.spec import TuneSpec


class TuneProgress(NamedTuple):
    """Where a tune stands: in ``stage`` ``"train"`` (loss evaluations: ``done`` of ``total``, the
    last one's trace ``row``) or ``"evaluate"`` (held-out runs: ``done`` of the ``total`` this
    call runs; ``row`` None)."""

    stage: str
    done: int
    total: int
    row: dict | None = None


class TuneResult(NamedTuple):
    """What :func:`run_tune` did: the tune ``spec``; ``stopped``: ``should_stop()`` turned True
    (what was saved stays, for ``--resume``; the fields below are None from where it stopped);
    the optimisation's ``trace`` (one row per loss evaluation); the held-out ``evaluation``
    sweep (point 0: initial Params, point 1: tuned), its ``runs`` read back and their ``paired``
    differences by seed (tuned − initial, of the outputs with an error or divergence role)."""

    spec: TuneSpec
    stopped: bool
    trace: pd.DataFrame | None = None
    evaluation: Study | None = None
    runs: pd.DataFrame | None = None
    paired: pd.DataFrame | None = None


def _ignore(*_: Any) -> None:
    return None


def tune_headline(spec: TuneSpec) -> str:
    """One line: the scenario, the tuned Params with their bounds, the optimiser, the loss."""
    names = ", ".join(f"{b.name} in ({b.low:g}, {b.high:g}) {b.scale}" for b in spec.bounds)
    return (f"scenario {scenarios.describe(spec.study.scenario)}: tuning {names} with {spec.optimizer} "
            f"(learning rate {spec.learning_rate:g}) for {spec.steps} step(s) on {spec.train_seeds} training seed(s); "
            f"loss on {spec.loss.filter}")


def run_tune(spec: TuneSpec, *, out_dir: str | Path, spec_file: str | Path | None = None, resume: bool = False,
             force: bool = False, message: Callable[[str], None] | None = None,
             progress: Callable[[TuneProgress], None] | None = None, started: Callable[[], None] | None = None,
             should_stop: Callable[[], bool] | None = None) -> TuneResult:
    """Run the tune ``spec`` (:func:`mcjax.tune.load_tune_spec`) into ``out_dir`` as ``mcjax
    tune`` does.

    Holds the folder's lock for the run; makes the folder ready
    (:func:`mcjax.tune.prepare_tune_output`: ``resume`` continues the tune saved there,
    ``force`` replaces a previous tune; ``spec_file`` and its base config must not be inside
    it); optimises from the last saved step (:func:`mcjax.tune.optimise`), plots the trace
    (``trace.png``); runs the held-out evaluation still to run (:func:`mcjax.tune.run_evaluation`)
    and reads its runs back.

    ``started()``: the folder is ready (from then on an interruption leaves a tune to resume);
    ``message(line)``: the headline, a resume's starting point, each tuned Param's initial and
    final value, the training loss, the evaluation's size; ``progress(TuneProgress)``: once
    when each stage starts and after each loss evaluation or evaluation chunk;
    ``should_stop()``: asked before the first step and after each step and chunk, True stops
    the tune (``stopped`` in the result). Raises :class:`OutputError` or :class:`SpecError`
    (the folder cannot be used, the evaluation cannot be built); an ``OSError`` or
    :class:`ChunkError` when a file cannot be written (see
    :func:`mcjax.tune.write_failures_end_the_command`)."""
    say, tell = message or _ignore, progress or _ignore
    stop = should_stop or (lambda: False)
    out_dir = Path(out_dir)
    keep = [] if spec_file is None else [Path(spec_file), (Path(spec_file).parent / spec.source["base"]).resolve()]
    with hold_output(out_dir):
        prepare_tune_output(spec, out_dir, resume=resume, force=force, spec_file=spec_file, keep=keep)
        (started or _ignore)()
        configure()
        if stop():
            return TuneResult(spec, True)
        say(tune_headline(spec))
        saved = load_state(out_dir, spec)
        done = 0 if saved is None else saved[0]
        total = spec.steps + 1
        if done:
            say(f"resuming: {min(done, total)} of {total} loss evaluation(s) already done")
        at = TuneProgress("train", min(done, total), total)
        tell(at)

        def step_done(row: dict) -> None:
            nonlocal at
            at = at._replace(done=at.done + 1, row=row)
            tell(at)

        trace = optimise(spec, out_dir, progress=step_done, should_stop=stop)
        if stop() and not finished(spec, trace):
            return TuneResult(spec, True, trace)
        plot_trace(spec, trace, out_dir / "trace.png")
        first, last = trace.iloc[0], trace.iloc[-1]
        for b in spec.bounds:
            say(f"{b.name}: {first[b.name]:.6g} -> {last[b.name]:.6g}")
        say(f"training loss: {first['loss']:.6g} -> {last['loss']:.6g} ({len(trace) - 1} step(s)); trace: "
            f"{out_dir / TRACE_FILE}, {out_dir / 'trace.png'}")
        ev = evaluation_spec(spec, final_values(spec, trace))
        todo = prepare_evaluation(ev, out_dir, spec_file=spec_file)
        remaining = ev.runs_in(todo)
        say(f"held-out evaluation (exact simulation): {ev.n_points} point(s) x {ev.seeds} seed(s) = "
            f"{ev.n_runs} runs" + ("" if todo is None else f", {remaining} still to run"))
        at = TuneProgress("evaluate", 0, remaining)
        tell(at)

        def chunk_done(runs: int) -> None:
            nonlocal at
            at = at._replace(done=at.done + runs)
            tell(at)

        run_evaluation(ev, out_dir, chunks=todo, progress=chunk_done, should_stop=stop)
        if stop():
            return TuneResult(spec, True, trace, ev)
        runs = parquet.read_table(out_dir, "runs")
    paired = paired_differences(runs, [k for k, o in ev.scenario.outputs(ev.config).items()
                                       if o.role in ("error", "divergence")])
    return TuneResult(spec, False, trace, ev, runs, paired)
