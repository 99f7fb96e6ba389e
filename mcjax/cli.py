"""The ``mcjax`` command line: ``mcjax sweep``, ``mcjax run``, ``mcjax report``, ``mcjax list``.

click gives us typed options, ``--help`` for every subcommand and clean usage errors;
tqdm draws the progress bar.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import click


def _parse_set(values: tuple[str, ...]) -> dict:
    """``--set key=value`` pairs; values parsed as TOML scalars/arrays when possible."""
    import tomllib

    out = {}
    for item in values:
        if "=" not in item:
            raise click.BadParameter(f"{item!r}: expected key=value (e.g. params.comm_radius=80e3)", param_hint="--set")
        key, raw = item.split("=", 1)
        try:
            value = tomllib.loads(f"v = {raw}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw
        out[key.strip()] = value
    return out


def _fail(message: str) -> None:
    click.echo(f"error: {message}", err=True)
    sys.exit(2)


def _print_summary(df, spec) -> None:
    """The report's table of a sweep's rows (per point and filter), from the declarations."""
    from mcjax.report import summary_text

    # the declarations and the spec are all the table needs (no provenance, no git call)
    click.echo(summary_text(df, {**spec.scenario.metadata(spec.config), "spec": spec.source}))


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="mcjax")
def main() -> None:
    """mcjax — batched Monte-Carlo simulation of distributed cooperative target tracking.

    Run a sweep spec (sweeps/*.toml) into a Parquet dataset with `mcjax sweep`, run one
    parameter point for a quick look with `mcjax run`, list scenarios with `mcjax list`.
    """


@main.command()
@click.argument("spec", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Output folder of the Parquet dataset (default: results/<spec name>).")
@click.option("--seeds", type=click.IntRange(min=1), default=None, help="Monte-Carlo seeds per point (overrides the spec).")
@click.option("--chunk-size", type=click.IntRange(min=1), default=None,
              help="Runs per compiled batch; memory is bounded by it (overrides the spec).")
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Override a spec key, e.g. --set params.comm_radius=80e3 or --set config.n_steps=100. Repeatable.")
@click.option("--dry-run", is_flag=True, help="Print the points, run count and chunk plan; compile and write nothing.")
@click.option("--resume", is_flag=True,
              help="Finish an interrupted sweep in OUT: run only the chunks with no part file yet.")
@click.option("--force", is_flag=True, help="Delete an existing output folder first.")
def sweep(spec, out_dir, seeds, chunk_size, sets, dry_run, resume, force):
    """Run the sweep SPEC: every grid point x every seed, results to OUT/runs/*.parquet.

    Each chunk of runs is written as one Parquet part file (atomically: temporary name,
    then rename), so Ctrl-C or a killed process loses at most the chunk in flight, and
    --resume completes exactly the missing chunks. Prints the report's summary per point
    and filter (the scenario's error metric with its interval, divergences, graph statistics).
    """
    from mcjax import results
    from mcjax.engine import chunk_plan
    from mcjax.sweep import OutputError, SpecError, load_spec, missing_chunks, points, prepare_output, run_sweep

    try:
        s = load_spec(spec, seeds=seeds, chunk_size=chunk_size, overrides=_parse_set(sets))
    except SpecError as exc:
        _fail(str(exc))
    out_dir = out_dir or Path("results") / spec.stem
    plan = chunk_plan(s.n_runs, s.chunk_size)
    size = plan[0][1] - plan[0][0]
    click.echo(f"scenario {s.scenario.name}: {s.n_points} point(s) x {s.seeds} seed(s) = {s.n_runs} runs, "
               f"{len(plan)} chunk(s) of {size}, filters {', '.join(s.config.filters)}")
    if dry_run:
        click.echo(points(s).to_string(index=False))
        for i, (a, b) in enumerate(plan):
            click.echo(f"chunk {i}: runs {a}..{b - 1}")
        return
    try:
        todo = prepare_output(s, out_dir, resume=resume, force=force)
    except OutputError as exc:
        _fail(str(exc))
    if todo is not None:
        click.echo(f"resuming: {len(plan) - len(todo)} of {len(plan)} chunk(s) already written")
    from tqdm import tqdm

    remaining = s.n_runs if todo is None else sum(plan[i][1] - plan[i][0] for i in todo)
    t0 = time.perf_counter()
    try:
        with tqdm(total=remaining, unit="run", desc="sweep", disable=None) as bar:
            run_sweep(s, out_dir, chunks=todo, progress=bar.update)
    except KeyboardInterrupt:
        n_done = len(plan) - len(missing_chunks(s, out_dir))
        click.echo(f"\ninterrupted: {n_done} of {len(plan)} chunk(s) written to {out_dir}; "
                   f"finish with: mcjax sweep {spec} --out {out_dir} --resume", err=True)
        sys.exit(130)
    elapsed = time.perf_counter() - t0
    df = results.read_table(out_dir, "runs")
    click.echo(f"{len(df)} rows in {out_dir / 'runs'}; {remaining} runs in {elapsed:.1f} s "
               f"({remaining / max(elapsed, 1e-9):.1f} runs/s incl. compilation)")
    _print_summary(df, s)


@main.command()
@click.argument("config", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--seeds", type=click.IntRange(min=1), default=None,
              help="Monte-Carlo seeds [default: the config's `seeds` (the paper's run count), else 20].")
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Override a value, e.g. --set params.comm_radius=80e3. Repeatable.")
def run(config, seeds, sets):
    """Run one parameter point of CONFIG (configs/*.toml) and print a summary table
    (nothing is written to disk)."""
    from mcjax.sweep import SpecError, build_spec, run_sweep

    try:
        s = build_spec({"base": str(config.resolve())}, Path.cwd(), seeds=seeds, overrides=_parse_set(sets))
    except SpecError as exc:
        _fail(str(exc))
    df = run_sweep(s)
    _print_summary(df, s)


@main.command()
@click.argument("out_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--format", "fmt", type=click.Choice(["text", "csv", "markdown"]), default="text", show_default=True,
              help="Format of the printed summary table.")
@click.option("--no-plots", is_flag=True, help="Print the table only; write no PNG files.")
def report(out_dir, fmt, no_plots):
    """Summarise the sweep dataset in OUT_DIR and write plots to OUT_DIR/report/.

    The table groups runs by the swept params and filter: mean RMSE with its 95 % t-interval
    (all runs and non-divergent runs), divergence rate with its 95 % Wilson interval, lambda2
    statistics and disconnected steps. Plots: each metric against each swept axis (one line
    per filter), divergence rate with intervals, lambda2, and heatmaps for two-axis grids.
    """
    from mcjax.report import report as make_report

    try:
        table, plots = make_report(out_dir, fmt, plots=not no_plots)
    except ValueError as exc:
        _fail(str(exc))
    click.echo(table)
    for p in plots:
        click.echo(f"plot: {p}")


@main.command(name="list")
@click.argument("scenario", required=False)
def list_scenarios(scenario):
    """List the scenarios (built-in and installed plugins); with SCENARIO, every Params field
    (unit, default, allowed values, description), every Config field and every output."""
    from mcjax import scenarios

    if scenario is None:
        for name in scenarios.known():
            try:
                title = scenarios.get(name).title
            except Exception as exc:  # a broken plugin must not hide the others
                title = f"(cannot be loaded: {exc})"
            click.echo(f"{name:18s} {title}")
        click.echo("details: mcjax list SCENARIO")
        return
    try:
        sc = scenarios.get(scenario, base_dir=Path.cwd())
    except (ValueError, ImportError) as exc:
        _fail(str(exc))
    cfg = sc.Config()
    defaults = sc.default_params(cfg)
    click.echo(f"{sc.name}: {sc.title}\n\nParams (sweepable, no recompilation):")
    for name, p in sc.params_table.items():
        value = getattr(defaults, name)
        shown = value.tolist() if value.size <= 6 else f"array{value.shape}"
        unit = f" [{p.unit}]" if p.unit else ""
        agent = ", scalar or per agent" if p.per_agent else ""
        if p.shape is not None:
            agent += ", shape " + "x".join("n_agents" if d == "n" else str(d) for d in p.shape)
        click.echo(f"  {name}{unit}: {p.description}\n      default {shown}; allowed {p.allowed()}{agent}")
    click.echo("\nConfig (fixes shapes / the program; changing it recompiles):")
    for name, st in sc.settings.items():
        unit = f" [{st.unit}]" if st.unit else ""
        click.echo(f"  {name}{unit}: {st.description}\n      default {st.default!r}; allowed {st.allowed()}")
    click.echo("\nOutputs (one row per run and filter in OUT/runs):")
    for name, o in sc.outputs(cfg).items():
        unit = f" [{o.unit}]" if o.unit else ""
        role = f" (role: {o.role})" if o.role else ""
        click.echo(f"  {name}{unit}{'' if o.per_filter else ' per run'}: {o.description}{role}")


if __name__ == "__main__":
    main()
