"""The ``mcjax`` command line: ``mcjax sweep``, ``mcjax run``, ``mcjax check``, ``mcjax report``,
``mcjax tune``, ``mcjax list``
(``mcjax --help`` lists every command with one line each; ``docs/cli.md`` holds every
command's ``--help``).

click gives us typed options, ``--help`` for every subcommand and clean usage errors;
tqdm draws the progress bar.
"""

from __future__ import annotations

import shlex
import sys
import tomllib
from pathlib import Path

import click

from mcjax import configure
from mcjax.base.interrupt import ACK, ACK_DASK, ctrl_c, exit_now, finish
from mcjax.cli.executor import Remote, executor_options, open_executor
from mcjax.cli.guards import (
    check_environment,
    chunk_failed,
    fail,
    refuse_clashing_filters,
)
from mcjax.cli.progress import Bars


def _parse_set(values: tuple[str, ...]) -> dict:
    """``--set key=value`` pairs (see :func:`mcjax.base.validation.set_value`)."""
    from mcjax.base.validation import set_value
    out = {}
    for item in values:
        key, eq, raw = item.partition("=")
        if not eq or not key.strip():
            fail(f"--set {item!r}: must be KEY=VALUE, e.g. --set params.sensing_radius=100e3")
        out[key.strip()] = set_value(raw.strip())
    return out


def _read_kind(path: Path) -> dict | None:
    """The TOML of ``path`` if it reads (for telling a spec from a config), else None."""
    try:
        return tomllib.loads(path.read_bytes().decode("utf-8").removeprefix("\ufeff"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return None


def _print_summary(df, spec) -> None:
    """The report's table of a sweep's rows (per point and filter), from the declarations."""
    from mcjax.analysis.tables import terminal_width
    from mcjax.report import summary_text
    from mcjax.study.rows import shown_metadata

    # the declarations and the spec are all the table needs (no provenance, no git call); it fits the terminal
    click.echo(summary_text(df, {**shown_metadata(spec.scenario, spec.config), "spec": spec.source},
                            width=terminal_width()))


class Commands(click.Group):
    """The command group: a filter that breaks the filter contract, found when its step is first traced
    (:class:`mcjax.contract.filter.FilterError`), ends any command with its one line and exit 2."""

    def invoke(self, ctx):
        from mcjax.contract.filter import FilterError  # here, not at import: the contract loads numpy

        try:
            return super().invoke(ctx)
        except FilterError as exc:
            fail(str(exc))


@click.group(cls=Commands, context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(package_name="mcjax")
def main() -> None:
    """mcjax — batched Monte-Carlo simulation of distributed cooperative target tracking.

    Typical use: `mcjax run configs/sun2011.toml` for a quick look at one paper's set-up,
    `mcjax sweep sweeps/default.toml` to write a Parquet dataset, `mcjax report
    results/default` for its tables, plots and results/default/report/index.html.
    `mcjax COMMAND --help` tells more; docs/cli.md has every option.
    """
    check_environment()


@main.command(short_help="Run a sweep spec (sweeps/*.toml) into Parquet; print a summary.")
@click.argument("spec", type=click.Path(path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Output folder of the Parquet dataset (default: results/<spec name>).")
@click.option("--seeds", type=click.IntRange(min=1), default=None, help="Monte-Carlo seeds per point (overrides the spec).")
@click.option("--chunk-size", type=click.IntRange(min=1), default=None,
              help="Runs per compiled batch; memory is bounded by it (overrides the spec).")
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Override a spec key, e.g. --set params.sensing_radius=100e3, --set config.filters=[F1,F2] or "
                   "--set 'grid.comm_radius=[60e3, 80e3]' (an axis is changed in grid/zip: a params value for a swept "
                   "field is an error). Repeatable.")
@click.option("--dry-run", is_flag=True, help="Print the points, run count and chunk plan; compile and write nothing.")
@click.option("--resume", is_flag=True,
              help="Finish an interrupted sweep in OUT: check every part file and run only the chunks whose parts "
                   "are missing or damaged. Seeds, chunk size and --set values come from OUT/sweep.json.")
@click.option("--force", is_flag=True,
              help="Replace an existing output folder that holds a previous sweep (OUT/sweep.json).")
@click.option("--executor", type=click.Choice(["local", "dask"]), default="local", show_default=True,
              help="Who computes the chunks: this process, or the workers of a Dask cluster (docs/cluster.md; "
                   "needs pip install -e \".[dask]\"). Same results either way; --resume works across them.")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="With --executor dask: the scheduler of a running cluster, e.g. tcp://10.0.0.5:8786.")
@click.option("--workers", default=None, type=int, metavar="N",
              help="With --executor dask: start a cluster of N worker processes on this machine for the sweep.")
def sweep(spec, out_dir, seeds, chunk_size, sets, dry_run, resume, force, executor, scheduler, workers):
    """Run the sweep SPEC: every grid point x every seed, results to OUT/runs/*.parquet.

    Each chunk of runs is written as one Parquet part file (atomically: temporary name,
    then rename), so Ctrl-C or a killed process loses at most the chunk in flight, and
    --resume completes exactly the missing chunks. The first Ctrl-C stops after the chunk in
    flight, a second one at once (exit code 130); both print the command that resumes.
    Prints the report's summary per point and filter (the scenario's error metric with its
    interval, divergences, graph statistics).

    With --executor dask the chunks are computed by the workers of a Dask cluster (an
    existing one with --scheduler, or N local worker processes with --workers) and written
    here as they complete; the first Ctrl-C cancels the chunks in flight. A chunk that fails
    on a worker stops the sweep with a one-line error naming the chunk and its points (exit
    code 1); the chunks written stay, for --resume.
    """
    refuse_clashing_filters()
    state = {"done": 0, "plan": None, "out": out_dir, "words": ""}

    def hint() -> str:
        done = f"{state['done']} of {state['plan']} chunk(s)" if state["plan"] is not None else "no chunk"
        if state["plan"] is None:
            return "interrupted before the sweep started; nothing was written"
        return (f"interrupted: {done} written to {state['out']}; finish with: mcjax sweep "
                f"{shlex.quote(str(spec))} --out {shlex.quote(str(state['out']))} --resume{state['words']}")

    with ctrl_c(hint, ACK_DASK if executor == "dask" else ACK) as stop:
        remote = executor_options(executor, scheduler, workers)
        state["words"] = remote.words
        _sweep(spec, out_dir, seeds, chunk_size, sets, dry_run, resume, force, state, stop, hint, remote)


def _sweep(spec, out_dir, seeds, chunk_size, sets, dry_run, resume, force, state, stop, hint, remote=Remote()):
    from mcjax import study

    state["out"] = out_dir = out_dir or study.default_out_dir(spec)
    overrides = _parse_set(sets)
    try:
        s = study.load_sweep(spec, out_dir=out_dir, seeds=seeds, chunk_size=chunk_size,
                             overrides=overrides or None, resume=resume and not dry_run)
    except (study.OutputError, study.SpecError) as exc:
        fail(str(exc))
    if dry_run:
        from mcjax.analysis.tables import format_table

        click.echo(study.sweep_headline(s))
        click.echo(format_table(s.points), nl=False)  # numbers as in the summary (mcjax.analysis.tables)
        for i, (a, b) in enumerate(s.plan):
            click.echo(f"chunk {i}: runs {a}..{b - 1}")
        if stop.is_set():
            exit_now(130)
        return
    if stop.is_set():
        click.echo(hint(), err=True)
        exit_now(130)
    configure()  # JAX's process settings, before anything computes (mcjax.configure)
    failure = result = None
    bars = Bars(sweep="chunk")
    before = []  # the chunks written before (a resumed sweep's bar counts the chunks to run)

    def progress(at) -> None:
        state["plan"], state["done"] = at.chunks, at.chunks_done
        before[:] = before or [at.chunks_done]
        bars.show("sweep", at.chunks_done - before[0], at.chunks - before[0])

    # the cluster first: a scheduler that cannot be reached leaves the output folder untouched
    with open_executor(remote) as ex, bars:
        try:
            result = study.run_sweep_folder(s, spec_file=spec, out_dir=out_dir, resume=resume, force=force,
                                            executor=ex, message=bars.echo,
                                            warn=lambda line: click.echo(line, err=True), progress=progress,
                                            should_stop=stop.is_set)
        except study.OutputError as exc:
            fail(str(exc))
        except study.ChunkError as exc:
            failure = exc
    if failure is not None:
        chunk_failed(f"{failure}; {state['done']} of {state['plan']} chunk(s) written to {out_dir} (they stay)")
    if result.stopped:
        click.echo(hint(), err=True)
        exit_now(130)
    if result.runs_run:
        rate = result.runs_run / max(result.seconds, 1e-9)  # a few runs that took long: 0.048, not 0.0
        click.echo(f"{len(result.rows)} rows in {out_dir / 'runs'}; {result.runs_run} runs in {result.seconds:.1f} s "
                   f"({f'{rate:.1f}' if rate >= 0.95 else f'{rate:.2g}'} runs/s incl. compilation)")
    else:  # --resume of a sweep already whole: nothing ran, so no rate
        click.echo(f"{len(result.rows)} rows in {out_dir / 'runs'}; the sweep was already complete (nothing to run)")
    _print_summary(result.rows, s)
    finish(stop)


@main.command(short_help="Run one point of a config (configs/*.toml); print a summary.")
@click.argument("config", type=click.Path(path_type=Path))
@click.option("--seeds", type=click.IntRange(min=1), default=None,
              help="Monte-Carlo seeds [default: the config's `seeds` (the paper's run count), else 20].")
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Override a value, e.g. --set params.comm_radius=80e3 or --set config.filters=[F1,F2] "
                   "(names from `mcjax list`). "
                   "Repeatable.")
def run(config, seeds, sets):
    """Run one parameter point of CONFIG (configs/*.toml) and print a summary table
    (nothing is written to disk). The first Ctrl-C stops after the chunk in flight, a second
    one at once (exit code 130)."""
    refuse_clashing_filters()
    with ctrl_c(lambda: "nothing was written") as stop:
        overrides = _parse_set(sets)
        data = _read_kind(config)
        if data is not None and "base" in data:
            fail(f"{config} is a sweep spec (it names a base config), not a config file: run it with "
                  f"`mcjax sweep {shlex.quote(str(config))}`")
        from mcjax import engine, scenarios, study

        if not config.is_file():
            from mcjax.base.validation import near_path

            fail(f"config file not found: {config}{near_path(config)}" if not config.exists()
                 else f"{config} is a folder, not a file")
        try:
            # chunks of one batch per device: a Ctrl-C waits for little (the numbers do not depend on it)
            s = study.build_spec({"base": str(config.resolve())}, Path.cwd(), seeds=seeds, overrides=overrides,
                           chunk_size=engine.BATCH_SIZE * len(engine.devices()))
        except study.SpecError as exc:
            fail(str(exc))
        configure()
        from mcjax.study.rows import shown_filters

        click.echo(f"scenario {scenarios.describe(s.scenario)}: {s.n_points} point(s) x {s.seeds} seed(s) = "
                   f"{s.n_runs} runs, filters {', '.join(shown_filters(s.scenario, s.config))}")
        df = study.run_sweep(s, should_stop=stop.is_set)
        if stop.is_set():
            click.echo(f"interrupted: {len(df) // max(len(s.config.filters), 1)} of {s.n_runs} run(s) done, "
                       f"nothing written", err=True)
            exit_now(130)
        _print_summary(df, s)
        finish(stop)


@main.command(short_help="A sweep dataset's tables, plots and OUT_DIR/report/index.html.")
@click.argument("out_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--format", "fmt", type=click.Choice(["text", "csv", "markdown"]), default="text", show_default=True,
              help="Format of the printed summary table.")
@click.option("--markdown", is_flag=True, help="The same as --format markdown (a check folder's verdict table for docs).")
@click.option("--no-plots", is_flag=True, help="Print the table only; write no PNG or HTML files.")
def report(out_dir, fmt, markdown, no_plots):
    """Summarise the sweep dataset in OUT_DIR; write plots and one self-contained HTML page
    (OUT_DIR/report/index.html: findings with intervals, plots, tables, glossary, Params, spec,
    provenance). A tune's folder gets its own page (no sweep plots); a folder of datasets is listed.

    The table groups runs by the swept params and filter: mean error with its 95 % t-interval
    (all runs and non-divergent runs), divergence rate with its 95 % Wilson interval, lambda2
    statistics and disconnected steps. Plots: each metric against each swept axis (one line
    per filter, one panel per value of the other axes), divergence rate with intervals,
    lambda2, and heatmaps for two-axis grids; axes in display units (km, deg). A point
    resting on fewer than 5 runs is drawn hollow and not joined; where the number of runs
    varies, each point shows it.
    """
    from mcjax.analysis.tables import terminal_width
    from mcjax.report import report as make_report

    fmt = "markdown" if markdown else fmt
    warn = (lambda text: click.echo(f"warning: {text}", err=True)) if fmt == "csv" else None
    try:
        table, plots = make_report(out_dir, fmt, plots=not no_plots, warn=warn, width=terminal_width())
    except ValueError as exc:
        fail(str(exc))
    except KeyboardInterrupt:
        click.echo("interrupted", err=True)
        sys.exit(130)
    click.echo(table)
    for p in plots:
        click.echo(f"{'page' if p.suffix == '.html' else 'plot'}: {p}")


@main.command(short_help="Tune Params by gradient through the closed loop ([tune] table).")
@click.argument("spec", type=click.Path(path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Output folder (default: results/<spec name>): trace.parquet, trace.png, the held-out "
                   "evaluation in the sweep's format (runs/, sweep.json; `mcjax report OUT` reads it).")
@click.option("--resume", is_flag=True,
              help="Continue an interrupted tune in OUT from its last completed optimisation step (and finish "
                   "its evaluation).")
@click.option("--force", is_flag=True, help="Replace an existing output folder that holds a previous tune (OUT/tune.json).")
def tune(spec, out_dir, resume, force):
    """Tune the continuous Params named in SPEC's [tune] table by gradient through the closed loop.

    The training loss (a softly clipped tracking error plus a soft divergence indicator, on the
    scenario's step with its relaxation switch on, the same training seeds every step) is
    minimised with an optax optimiser; every step's loss, Params, gradient norm and wall time go to
    OUT/trace.parquet and OUT/trace.png, and the optimiser's state is saved atomically after
    every step, so a killed tune resumes (--resume) from its last completed step. Then the
    initial and the final Params are run on the held-out seeds with the exact simulation,
    written as a two-point sweep (point 0 = initial, point 1 = tuned; a column role says
    which) and summarised, the initial row first. The first Ctrl-C stops after the step in flight, a second one at once
    (exit code 130); both print the command that resumes. See docs/tune.md.
    """
    refuse_clashing_filters()
    state = {"out": out_dir, "started": False}

    def hint() -> str:
        if not state["started"]:
            return "interrupted before the tune started; nothing was written"
        return (f"interrupted: progress saved in {state['out']}; finish with: mcjax tune "
                f"{shlex.quote(str(spec))} --out {shlex.quote(str(state['out']))} --resume")

    with ctrl_c(hint) as stop:
        _tune(spec, out_dir, resume, force, state, stop, hint)


def _tune(spec_path, out_dir, resume, force, state, stop, hint):
    from mcjax import study
    from mcjax import tune as tuning

    state["out"] = out_dir = out_dir or study.default_out_dir(spec_path)
    with tuning.write_failures_end_the_command(out_dir), Bars(tune="step", evaluate="run") as bars:
        # a full disk: one line, exit 1 (write_failures_end_the_command)
        try:
            spec = tuning.load_tune_spec(spec_path)
        except study.SpecError as exc:
            fail(str(exc))

        def progress(at) -> None:
            loss = {} if at.row is None else {"loss": f"{at.row['loss']:.4g}", "grad": f"{at.row['grad_norm']:.3g}"}
            bars.show("tune" if at.stage == "train" else "evaluate", at.done, at.total, **loss)

        try:
            result = tuning.run_tune(spec, out_dir=out_dir, spec_file=spec_path, resume=resume, force=force,
                                     message=bars.echo, progress=progress, started=lambda: state.update(started=True),
                                     should_stop=stop.is_set)
        except (study.SpecError, study.OutputError) as exc:
            fail(str(exc))
        bars.close()
        if result.stopped:
            click.echo(hint(), err=True)
            exit_now(130)
        # the initial row first, a column role = initial / tuned
        click.echo(tuning.summary_text(result.runs, result.evaluation))
        if len(result.paired):
            click.echo("tuned - initial, paired by seed (mean and 95 % t-interval):\n"
                       + result.paired.to_string(index=False))
        click.echo(f"role = initial (point 0) / tuned (point 1); report: mcjax report {shlex.quote(str(out_dir))}")
        finish(stop)


@main.command(name="list", short_help="List the scenarios; with SCENARIO, its params, settings, outputs.")
@click.argument("scenario", required=False)
@click.option("--config", "config_file", type=click.Path(path_type=Path), default=None,
              help="A config file (configs/*.toml) of the scenario: show its values beside the defaults "
                   "(SCENARIO may then be left out).")
def list_scenarios(scenario, config_file):
    """List the scenarios (built-in and installed plugins); with SCENARIO, every Params field
    (unit, default, allowed values, description), every Config field and every output; with
    --config FILE, that file's values beside the defaults ("<-" marks the fields it changes)."""
    from mcjax import scenarios

    if scenario is None and config_file is None:
        for name in scenarios.known():
            try:
                title = scenarios.get(name).title
            except Exception as exc:  # a broken plugin must not hide the others
                title = f"(cannot be loaded: {exc})"
            click.echo(f"{name:18s} {title}")
        click.echo("details: mcjax list SCENARIO (add --config FILE for a config's values); the filters: mcjax list filters")
        return
    if scenario == "filters" and config_file is None:
        from mcjax.cli.listing import filters_text

        try:
            click.echo(filters_text())
        except (ValueError, ImportError) as exc:
            fail(str(exc))
        return
    file = None
    if config_file is not None:
        from mcjax.study import SpecError, read_config_file

        try:
            file = read_config_file(config_file)
        except SpecError as exc:
            fail(str(exc))
    from mcjax.cli.listing import scenario_text

    try:
        sc = scenarios.get(scenario, base_dir=Path.cwd()) if scenario is not None else file.scenario
    except (ValueError, ImportError) as exc:
        fail(str(exc))  # an unknown name's message suggests the nearest known one
    if file is not None and file.scenario.name != sc.name:
        fail(f"{config_file} is a config of scenario {file.scenario.name!r}, not {sc.name!r}: "
              f"`mcjax list {file.scenario.name} --config {shlex.quote(str(config_file))}`")
    click.echo(scenario_text(sc, file, config_file))
