"""``mcjax league`` without the CLI: every scenario × point of a league file run through the study
pipeline into one output folder, the timing pass, and the league table written beside them.

The folder holds ``league.json`` (the league file as read and the seeds: what ``--resume``
compares), one sweep folder per scenario and point (``OUT/<scenario>/<point>/``, each what ``mcjax
sweep`` writes: its lock, ``sweep.json``, Parquet parts — so resuming, locks, Dask and the program
store work as for a sweep), ``timing.json`` (the timing pass, kept when resumed) and, once every
sweep is whole, ``league.parquet``: the league table (:data:`mcjax.league.table.COLUMNS`), written
atomically. A league stopped and resumed computes the chunks still missing and gives the same
table (the cost columns are the timing pass's, measured once per folder).

Reports through callbacks (``message``, ``warn``, ``progress``, ``should_stop``) and raises the
pipeline's exceptions (:class:`~mcjax.league.spec.LeagueError` before anything runs,
:class:`~mcjax.study.store.OutputError`, :class:`~mcjax.study.execute.ChunkError`)::

    from mcjax.league.runner import run_league
    result = run_league("benchmarks/league/consensus.toml", seeds=20, out_dir="results/league_consensus")
    result.table[["scenario", "point", "filter", "rank", "rmse"]]
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path
from typing import Callable, NamedTuple

import pandas as pd

from mcjax.base import provenance
from mcjax.league import table as league_table
from mcjax.league.folder import LEAGUE_FILE, TABLE_FILE, read_league, read_timing, write_table, write_timing
from mcjax.league.spec import League, LeagueError, describe, identity, load_league
from mcjax.league import timing as league_timing
from mcjax.study.execute import ChunkError, Executor
from mcjax.study.runner import NamedSweep, SweepProgress, run_named_sweeps
from mcjax.study.store import RESULTS_DIR, OutputError, hold_run_folder


class LeagueResult(NamedTuple):
    """What :func:`run_league` did: the checked ``league``, its ``out_dir``, the league ``table``
    (None when stopped) and whether ``should_stop()`` stopped it."""

    league: League
    out_dir: Path
    table: pd.DataFrame | None
    stopped: bool

    @property
    def meta(self) -> dict:
        """The league table's metadata as written (title, runs per cell, the timing pass's method and
        machine, provenance); the league's title and runs alone when it was stopped."""
        if self.table is None:
            return {"title": self.league.title, "seeds": self.league.seeds}
        return read_league(self.out_dir)[1]


__all__ = ["ChunkError", "LeagueError", "LeagueResult", "OutputError", "build_table", "cells", "default_out_dir",
           "load_league", "resume_hint", "run_league", "stages"]


def default_out_dir(league_file: str | Path) -> Path:
    """``results/league_<name>``, the name from the league file's stem; ``results/<name>`` when the name
    starts with "league" already (``league_tiny.toml``: ``results/league_tiny``, not ``league_league_tiny``)."""
    name = re.sub(r"[^A-Za-z0-9._-]+", "_", Path(league_file).stem).strip("._-") or "league"
    return RESULTS_DIR / (name if name.lower().startswith("league") else f"league_{name}")


def cells(league: League) -> list[str]:
    """``"<scenario>/<point>"`` of every cell, in the order they run (the progress callback's names)."""
    return [f"{key}/{point}" for key, point in league.studies]


def stages(league: League) -> dict[str, str]:
    """Every name the progress callback reports, with what it counts: each cell's chunks, then each
    scenario's timing repeats (``"timing <scenario>"``)."""
    return {**{c: "chunk" for c in cells(league)}, **{s: "repeat" for s in league_timing.stages(league)}}


def resume_hint(league_file: str | Path, out_dir: str | Path | None, seeds: int | None) -> str:
    """What a stopped league prints: the command that finishes it."""
    return (f"interrupted: the chunks written stay in {out_dir}; finish with: mcjax league "
            f"{shlex.quote(str(league_file))} --out {shlex.quote(str(out_dir))} --resume"
            + (f" --seeds {seeds}" if seeds else ""))


def _columns(study) -> list[str]:
    role = league_table.roles(study.scenario.outputs(study.config))
    return ["point_id", "seed_index", "filter", *(role[r] for r in ("error", "divergence", "floor", "nees")
                                                 if r in role)]


def run_league(league_file: str | Path | League, *, out_dir: str | Path | None = None, seeds: int | None = None,
               resume: bool = False, force: bool = False, executor: Executor | None = None,
               message: Callable[[str], None] | None = None, warn: Callable[[str], None] | None = None,
               progress: Callable[[str, SweepProgress], None] | None = None,
               should_stop: Callable[[], bool] | None = None) -> LeagueResult:
    """Run ``league_file`` (module docstring): read and check it whole
    (:func:`mcjax.league.spec.load_league`, ``seeds`` runs per cell; or a :class:`League` already
    read), make ``out_dir`` ready (default ``results/league_<name>``; a fresh league needs it empty
    or missing, ``force`` replaces a previous league, ``resume`` needs the same file and seeds), run
    every scenario × point (``progress("<scenario>/<point>", SweepProgress)``), the timing pass
    (``progress("timing <scenario>", …)``, :mod:`mcjax.league.timing`), then write ``league.parquet``."""
    say, stop = message or (lambda _: None), should_stop or (lambda: False)
    league = league_file if isinstance(league_file, League) else load_league(league_file, seeds=seeds)
    out = Path(default_out_dir(league.path) if out_dir is None else out_dir)
    ident = {**identity(league), "league_file": str(league.path.resolve())}
    with hold_run_folder(out, ident, identity_file=LEAGUE_FILE, kind="league", compare=("league", "seeds"),
                         other="another league file", resume=resume, force=force, keep=[league.path.resolve()],
                         warn=warn):
        say(describe(league))
        # the timing pass's compilations on the core the sweeps leave idle
        warmup = league_timing.Warmup(league, read_timing(out), stop) if league.timing_runs else None
        ran = run_named_sweeps([NamedSweep(f"{key}/{point}", out / key / point, study, columns=_columns(study))
                                for (key, point), study in league.studies.items()],
                               resume=resume, executor=executor, message=say, warn=warn, progress=progress,
                               should_stop=stop)
        if ran is None:
            return LeagueResult(league, out, None, True)
        rows = {(key, point): ran[f"{key}/{point}"] for key, point in league.studies}
        timing: dict = {}
        if league.timing_runs:
            timing, stopped = league_timing.timing_pass(league, read_timing(out),
                                                        save=lambda t: write_timing(out, t), message=say,
                                                        progress=progress, should_stop=stop, warmup=warmup)
            if stopped:
                return LeagueResult(league, out, None, True)
        table = build_table(league, rows, timing)
        write_table(out / TABLE_FILE, table, {"title": league.title, "league_file": str(league.path.resolve()),
                                              "seeds": league.seeds, "points": league.points,
                                              "machine": timing.get("machine", ""),
                                              "timing_runs": league.timing_runs,
                                              "timing": {k: timing[k] for k in ("repeats", "repeat_runs", "load")
                                                         if k in timing},
                                              **provenance.environment_metadata()})
    return LeagueResult(league, out, table, False)


def build_table(league: League, rows: dict, timing: dict) -> pd.DataFrame:
    """The league table of every cell's runs (``rows``: (scenario, point) → the sweep's rows) and
    the timing pass's costs; each filter shown by its record's name, as the datasets show it (a file the
    league file names ``"my_ekf.py:MY_EKF"`` is ``my_ekf``)."""
    out = []
    for (key, point), study in league.studies.items():
        entry = league.scenarios[key]
        r = rows[key, point].copy()
        r["filter"] = [league.filter_name(str(f)) for f in r["filter"]]
        costs = league_timing.costs(timing, key)
        out += league_table.cell_rows(key, entry.scenario, point, r,
                                      league_table.roles(study.scenario.outputs(study.config)), entry.filters,
                                      league.filters, entry.notes, costs, timing.get("machine", ""))
    from mcjax.tracking.filters.registry import shown_name  # resolved already, when the league file was read

    table = league_table.frame(out)
    table["filter"] = [shown_name(league.config_names.get(f, f)) for f in table["filter"]]  # a record's name
    return table
