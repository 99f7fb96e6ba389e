"""The commands that judge: ``mcjax check`` (a paper's claims file -> a verdict per claim) and ``mcjax league``
(filters ranked across scenarios and fault points). They register on :func:`mcjax.cli.commands.main`."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

import click

from mcjax.base.interrupt import ACK, ACK_DASK, ctrl_c, exit_now, finish, own_process
from mcjax.cli.commands import main
from mcjax.cli.executor import executor_options, open_executor
from mcjax.cli.guards import chunk_failed, fail, refuse_clashing_filters
from mcjax.cli.progress import Bars


def dask_options(command):
    """``--executor``, ``--scheduler`` and ``--workers``, the same on both commands (checked together by
    :func:`mcjax.cli.executor.executor_options`)."""
    command = click.option("--workers", default=None, type=int, metavar="N",
                           help="With --executor dask: start a cluster of N worker processes on this machine.")(command)
    command = click.option("--scheduler", default=None, metavar="ADDRESS",
                           help="With --executor dask: a running cluster.")(command)
    return click.option("--executor", type=click.Choice(["local", "dask"]), default="local", show_default=True,
                        help="Where the chunks are computed: this process, or a Dask cluster "
                             "(pip install -e \".[dask]\").")(command)


def _integer(option: str, text: str | None, what: str) -> int | None:
    """An option's integer (None when not given); one line, exit 2, when it is not one."""
    if text is None:
        return None
    try:
        value = int(text.strip())
    except ValueError:
        fail(f"{option}: must be {what}; got {text!r}")
    return value


@main.command(short_help="Check a claims file: its sweeps, then a verdict per claim.")
@click.argument("claims", type=click.Path(path_type=Path))
@click.option("--seeds", type=click.IntRange(min=1), default=None,
              help="Runs per point of every sweep [default: the claims file's `seeds`, else each sweep's].")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Output folder [default: results/check_<claims file name>].")
@click.option("--resume", is_flag=True,
              help="Finish an interrupted check in --out (the same file, --seeds, --base-seed and --replicate).")
@click.option("--force", is_flag=True, help="Replace an existing output folder that holds a previous check.")
@click.option("--strict", is_flag=True,
              help="Exit 1 when any claim fails, at the level printed (default: exit 0 whatever the verdicts).")
@click.option("--format", "fmt", type=click.Choice(["text", "markdown", "csv"]), default="text", show_default=True,
              help="Format of the printed verdict table (markdown: for docs).")
@click.option("--markdown", is_flag=True, help="The same as --format markdown.")
@click.option("--family", "family", default=None, metavar="METHOD",
              help="How the file's claims, one family, are held to a family-wise error of 5 %: holm (Holm's "
                   "step-down) or bonferroni (simultaneous intervals) [default: the claims file's `family`, else "
                   "holm].")
@click.option("--per-claim", is_flag=True,
              help="Print each claim's verdict from its own 95 % interval alone (no family-wise level).")
@click.option("--base-seed", "base_seed", default=None, metavar="N",
              help="Run every sweep of the file from base seed N (another seed range), as if each sweep said "
                   "base_seed = N.")
@click.option("--replicate", default=None, metavar="K",
              help="Run the check on K >= 2 disjoint seed ranges (OUT/range_<r>/: range 0 the file's seeds, range r "
                   "every base seed + r x 1,000,000) and mark each claim whose verdicts differ.")
@dask_options
def check(claims, seeds, out_dir, resume, force, strict, fmt, markdown, family, per_claim, base_seed, replicate,
          executor, scheduler, workers):
    """Check the claims file CLAIMS (benchmarks/claims/*.toml): run the sweeps it names through
    the study pipeline into OUT/<sweep>/ (resume, locks, Dask and the program store as for
    `mcjax sweep`; claims that share a sweep share its runs), then give every claim a verdict
    from its intervals — holds (the interval lies on the claimed side), fails (on the other),
    undecided (it straddles; with roughly the runs that would decide it). The file's claims are
    one family: the verdict is stated at a family-wise error of 5 % (Holm's step-down over the
    claims' one-sided tests: each claim judged on its intervals at the level that gives it),
    beside each claim's verdict from its own 95 % interval alone — written to OUT/claims.parquet
    and printed beside the paper's figures. `mcjax report OUT` shows it again with each sweep's
    figures.

    A malformed claims file or option exits 2 with one line naming the claim and the field, or
    the option, before anything runs. The first Ctrl-C stops after the chunk in flight (exit 130) and prints
    the command that resumes.
    """
    refuse_clashing_filters()
    state = {"out": out_dir, "started": False, "words": ""}
    fmt = "markdown" if markdown else fmt
    base_seed = _integer("--base-seed", base_seed, "an integer in [0, 4294967295]")
    replicate = _integer("--replicate", replicate, "an integer >= 2 (the number of seed ranges)")
    if replicate is not None and replicate < 2:
        fail(f"--replicate: must be an integer >= 2 (the number of seed ranges); got {replicate}")
    again = "".join(f" {o} {shlex.quote(str(v))}" for o, v in (("--seeds", seeds), ("--base-seed", base_seed),
                                                               ("--replicate", replicate), ("--family", family)) if v)

    def hint() -> str:
        if not state["started"]:
            return "interrupted before the check started; nothing was written"
        return (f"interrupted: the chunks written stay in {state['out']}; finish with: mcjax check "
                f"{shlex.quote(str(claims))} --out {shlex.quote(str(state['out']))} --resume"
                + again + state["words"])

    with ctrl_c(hint, ACK_DASK if executor == "dask" else ACK) as stop:
        remote = executor_options(executor, scheduler, workers)
        state["words"] = remote.words
        from mcjax.claims import runner
        from mcjax.claims.report import claim_units, terminal_width, verdict_text
        from mcjax.claims.spec import ClaimsError, load_claims
        from mcjax.study import ChunkError, OutputError

        try:  # the whole file, and the options against it, checked before any folder is touched
            checked = load_claims(claims, seeds=seeds, base_seed=base_seed)
            runner.family_method(checked, family)
        except ClaimsError as exc:
            fail(str(exc))
        state["out"] = out_dir = out_dir or runner.default_out_dir(claims)
        stages = [f"range_{r}/{name}" for r in range(replicate) for name in checked.sweeps] if replicate else \
            list(checked.sweeps)
        bars = Bars(**{stage: "chunk" for stage in stages})

        def progress(name, at) -> None:
            state["started"] = True
            bars.show(name, at.chunks_done, at.chunks)

        with open_executor(remote) as ex, bars:
            try:
                result = runner.run_check(checked, out_dir=out_dir, replicate=replicate, family=family, resume=resume,
                                          force=force, executor=ex, message=bars.echo,
                                          warn=lambda line: click.echo(line, err=True), progress=progress,
                                          should_stop=stop.is_set)
            except (OutputError, ClaimsError) as exc:
                fail(str(exc))
            except ChunkError as exc:
                chunk_failed(f"{exc}; the chunks written stay in {out_dir} (finish with --resume)")
        if result.stopped:
            click.echo(hint(), err=True)
            exit_now(130)
        click.echo(verdict_text(result.table, {**result.meta, "claims_file": str(claims)}, fmt, per_claim=per_claim,
                                units=claim_units(result.table, out_dir),
                                width=terminal_width() if fmt == "text" else None))
        click.echo(f"verdicts: {out_dir / runner.TABLE_FILE}")
        failed = strict and bool((result.table["verdict" if per_claim else "family_verdict"] == "fails").any())
        if own_process():  # leave now, so no Ctrl-C can land in the teardown (mcjax.base.interrupt.finish)
            exit_now(130 if stop.is_set() else int(failed))
        if failed:
            sys.exit(1)


@main.command(short_help="Rank filters across scenarios and fault points (a league file).")
@click.argument("league_file", metavar="LEAGUE", type=click.Path(path_type=Path))
@click.option("--seeds", type=click.IntRange(min=1), default=None,
              help="Runs per scenario x point [default: the league file's `seeds`].")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Output folder [default: results/league_<league file name>, or results/<name> when the "
                   "name starts with league].")
@click.option("--resume", is_flag=True, help="Finish an interrupted league in --out (the same file and --seeds).")
@click.option("--force", is_flag=True, help="Replace an existing output folder that holds a previous league.")
@click.option("--format", "fmt", type=click.Choice(["text", "markdown", "csv"]), default="text", show_default=True,
              help="Format of the printed league table (markdown: for docs).")
@click.option("--markdown", is_flag=True, help="The same as --format markdown.")
@dask_options
def league(league_file, seeds, out_dir, resume, force, fmt, markdown, executor, scheduler, workers):
    """Rank the filters of LEAGUE (benchmarks/league/*.toml) across its scenarios and fault points: each
    scenario x point is a sweep in OUT/<scenario>/<point>/ (resume, locks, Dask and the program store as for
    `mcjax sweep`; every filter of a scenario runs on the same seeds), then one row per scenario x point x
    filter — the error with its interval and its rank (filters whose paired interval against the best
    overlaps zero share its rank), the error as a multiple of the floor, the divergence rate, the ANEES
    against its band, the cost per run of each filter alone measured on this machine (a timing pass of
    three repeats, its runs at most --seeds) — written to OUT/league.parquet and printed
    (docs/claims.md, "The league").

    A bad league file exits 2 with one line naming the key, before anything runs; a plugin filter the
    file names but this Python lacks, with the command that installs it. The first Ctrl-C stops after
    the chunk in flight, or at once in the timing pass (exit 130), and prints the command that resumes.
    """
    refuse_clashing_filters()
    from mcjax.analysis.tables import terminal_width
    from mcjax.league import runner as lr
    from mcjax.league import table

    fmt = "markdown" if markdown else fmt

    def hint() -> str:
        return lr.resume_hint(league_file, out_dir, seeds)

    with ctrl_c(hint, ACK_DASK if executor == "dask" else ACK) as stop:
        try:
            checked = lr.load_league(league_file, seeds=seeds)  # the whole file, before any folder is touched
        except lr.LeagueError as exc:
            fail(str(exc))
        out_dir = out_dir or lr.default_out_dir(league_file)
        bars = Bars(**lr.stages(checked))
        with open_executor(executor_options(executor, scheduler, workers)) as ex, bars:
            try:
                result = lr.run_league(checked, out_dir=out_dir, resume=resume, force=force, executor=ex,
                                       message=bars.echo, warn=lambda line: click.echo(line, err=True),
                                       progress=lambda k, at: bars.show(k, at.chunks_done, at.chunks),
                                       should_stop=stop.is_set)
            except (lr.OutputError, lr.LeagueError) as exc:
                fail(str(exc))
            except lr.ChunkError as exc:
                chunk_failed(f"{exc}; the chunks written stay in {out_dir} (finish with --resume)")
        if result.stopped:
            click.echo(hint(), err=True)
            exit_now(130)
        click.echo(table.league_text(result.table, result.meta, fmt, width=terminal_width()))
        finish(stop)
