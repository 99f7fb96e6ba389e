"""The ``mcjax`` command line: ``mcjax sweep``, ``mcjax run``, ``mcjax list``.

click gives us typed options, ``--help`` for every subcommand and clean usage errors;
tqdm draws the progress bar.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import sys
import time
from pathlib import Path

import click

from mcjax import enable_float64


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


def _print_summary(df, axes) -> None:
    from mcjax.sweep import summary_table

    table = summary_table(df, axes)
    click.echo(table.to_string(index=False, float_format=lambda v: f"{v:.4g}"))


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
    --resume completes exactly the missing chunks. Prints a summary per point and filter
    (runs, divergences, mean RMSE over all and over non-divergent runs, smallest lambda2).
    """
    from mcjax import results
    from mcjax.engine import chunk_plan
    from mcjax.sweep import SpecError, load_spec, points, run_sweep

    if resume and force:
        _fail("--resume and --force exclude each other")
    try:
        s = load_spec(spec, seeds=seeds, chunk_size=chunk_size, overrides=_parse_set(sets))
    except SpecError as exc:
        _fail(str(exc))
    out_dir = out_dir or Path("results") / spec.stem
    plan = chunk_plan(s.n_runs, s.chunk_size)
    size = plan[0][1] - plan[0][0]
    click.echo(f"scenario {s.scenario.NAME}: {s.n_points} point(s) x {s.seeds} seed(s) = {s.n_runs} runs, "
               f"{len(plan)} chunk(s) of {size}, filters {', '.join(s.config.filters)}")
    if dry_run:
        click.echo(points(s).to_string(index=False))
        for i, (a, b) in enumerate(plan):
            click.echo(f"chunk {i}: runs {a}..{b - 1}")
        return
    identity = json.loads(json.dumps({"spec": s.source, "seeds": s.seeds, "base_seed": s.base_seed,
                                      "chunk_size": size, "n_runs": s.n_runs}, default=str))
    state = out_dir / "sweep.json"
    todo = None
    if resume:
        if not state.exists():
            _fail(f"nothing to resume in {out_dir}: no sweep.json (start the sweep without --resume)")
        saved = json.loads(state.read_text())
        if saved != identity:
            diff = sorted(k for k in identity if saved.get(k) != identity.get(k))
            _fail(f"{out_dir} holds a different sweep ({', '.join(diff)} differ); --resume needs the same "
                  f"spec, seeds and chunk size")
        results.clean_staging(out_dir)
        todo = _missing_chunks(s, plan, out_dir)
        click.echo(f"resuming: {len(plan) - len(todo)} of {len(plan)} chunk(s) already written")
    elif out_dir.exists() and any(out_dir.iterdir()):
        if not force:
            _fail(f"output folder {out_dir} is not empty; pass --resume to finish it, --force to replace it, "
                  f"or choose another --out")
        shutil.rmtree(out_dir)
    if not resume:
        out_dir.mkdir(parents=True, exist_ok=True)
        state.write_text(json.dumps(identity, indent=1))
    enable_float64()
    from tqdm import tqdm

    meta = {"spec": s.source, "config": dataclasses.asdict(s.config), "scenario": s.scenario.NAME,
            "seeds": s.seeds, "base_seed": s.base_seed, "chunk_size": size, **results.environment_metadata()}
    remaining = s.n_runs if todo is None else sum(plan[i][1] - plan[i][0] for i in todo)
    t0 = time.perf_counter()
    try:
        with tqdm(total=remaining, unit="run", desc="sweep", disable=None) as bar:
            run_sweep(s, out_dir, chunks=todo, progress=bar.update, metadata=meta)
    except KeyboardInterrupt:
        n_done = len(plan) - len(_missing_chunks(s, plan, out_dir))
        click.echo(f"\ninterrupted: {n_done} of {len(plan)} chunk(s) written to {out_dir}; "
                   f"finish with: mcjax sweep {spec} --out {out_dir} --resume", err=True)
        sys.exit(130)
    elapsed = time.perf_counter() - t0
    df = results.read_table(out_dir, "runs")
    click.echo(f"{len(df)} rows in {out_dir / 'runs'}; {remaining} runs in {elapsed:.1f} s "
               f"({remaining / max(elapsed, 1e-9):.1f} runs/s incl. compilation)")
    _print_summary(df, s.axes)


def _missing_chunks(spec, plan, out_dir) -> list[int]:
    """Chunks not completely on disk: some part (of ``runs/``, or ``timeseries/`` when the spec
    asks for it) is missing. Re-running one rewrites its parts under the same names."""
    from mcjax import results
    from mcjax.sweep import chunk_parts

    tables = ["runs"] + (["timeseries"] if spec.timeseries else [])
    have = {t: set(results.existing_parts(out_dir, t)) for t in tables}
    return [i for i, (a, b) in enumerate(plan)
            if not all(set(chunk_parts(spec, i, a, b)) <= have[t] for t in tables)]


@main.command()
@click.argument("config", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--seeds", type=click.IntRange(min=1), default=None,
              help="Monte-Carlo seeds [default: the config's `seeds` (the paper's run count), else 20].")
@click.option("--set", "sets", multiple=True, metavar="KEY=VALUE",
              help="Override a value, e.g. --set params.comm_radius=80e3. Repeatable.")
def run(config, seeds, sets):
    """Run one parameter point of CONFIG (configs/*.toml) and print a summary table."""
    import tempfile

    from mcjax.sweep import SpecError, load_spec, run_sweep

    with tempfile.TemporaryDirectory() as tmp:
        spec_path = Path(tmp) / "point.toml"
        spec_path.write_text(f"base = {json.dumps(str(config.resolve()))}\n")
        try:
            s = load_spec(spec_path, seeds=seeds, overrides=_parse_set(sets))
        except SpecError as exc:
            _fail(str(exc))
    enable_float64()
    df = run_sweep(s)
    _print_summary(df, [])


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
    """List the scenarios; with SCENARIO, every Params field (unit, default, allowed values)
    and every Config field (default, allowed values)."""
    from mcjax import scenarios

    if scenario is None:
        for name, mod in scenarios.SCENARIOS.items():
            click.echo(f"{name:18s} {mod.PAPER}")
        click.echo("details: mcjax list SCENARIO")
        return
    try:
        mod = scenarios.get(scenario)
    except ValueError as exc:
        _fail(str(exc))
    click.echo(f"{mod.NAME}: {mod.PAPER}\n\nParams (sweepable, no recompilation):")
    defaults = mod.default_params(mod.Config())
    ranges = getattr(mod, "PARAM_RANGES", {})
    for field in mod.Params._fields:
        value = getattr(defaults, field)
        shown = value.tolist() if value.size <= 6 else f"array{value.shape}"
        allowed = ranges.get(field, (None, None, "any"))[2]
        click.echo(f"  {field:18s} [{mod.PARAM_UNITS.get(field, '')}] default {shown}; allowed {allowed}")
    allowed_values = getattr(mod, "CONFIG_ALLOWED", {})
    click.echo("\nConfig (fixes shapes / the program; changing it recompiles):")
    for f in dataclasses.fields(mod.Config):
        allowed = allowed_values.get(f.name, "any")
        click.echo(f"  {f.name:20s} default {f.default!r}; allowed {allowed}")


if __name__ == "__main__":
    main()
