"""The league table: one row per scenario × point × filter (:data:`COLUMNS`), from each cell's runs,
and the table as text, Markdown or CSV with the best of each column marked.

Per row (every interval 95 %):

* ``rmse`` — the mean of the scenario's error output (role ``error``: ``rmse`` in m, a wind error in
  m/s; ``error_output`` and ``unit`` name it) over the finite runs, Student-t interval;
* ``rank`` — :func:`mcjax.league.rank.paired_ranks` within the scenario × point; ``vs_best`` the
  paired difference of the error to the rank-1 leader's, with its interval;
* ``floor_multiple`` — the RMS error as a multiple of the error floor's (role ``floor``: the
  posterior Cramér–Rao bound with ``bound = "on"``), :func:`~mcjax.analysis.statistics.floor_multiple`;
* ``divergence_rate`` — runs flagged diverged (role ``divergence``; a NaN flag counts) out of
  ``runs``, Wilson interval;
* ``anees`` — the average NEES (role ``nees``, ``consistency = "on"``) against the χ² band of
  ``nees_dof`` dof and its number of finite runs, and ``consistency``: its verdict;
* ``cost_per_run_s`` — seconds per run of the scenario with that filter alone (``cost_note``), from
  the timing pass on ``machine`` (:mod:`mcjax.league.timing`): the median of its timed repeats, and
  ``cost_low``, ``cost_high`` the lowest and highest repeat (the measurement's spread).

A column the scenario does not declare (no floor, no NEES) is NaN. A league filter a scenario does
not run has ``status`` "not run" and ``note`` says why. Pure functions of tables; no JAX.
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from mcjax.analysis import tables, wording
from mcjax.analysis.statistics import chi2_band, consistency, floor_multiple, mean_ci, wilson_interval
from mcjax.league.rank import paired_difference, paired_ranks

#: The columns of the league table, in order.
COLUMNS = ("scenario", "scenario_name", "point", "filter", "status", "note", "runs", "error_output", "unit",
           "rank", "rmse", "rmse_low", "rmse_high", "vs_best", "vs_best_low", "vs_best_high",
           "floor_multiple", "floor_low", "floor_high", "diverged", "divergence_rate", "divergence_low",
           "divergence_high", "anees", "nees_dof", "anees_band_low", "anees_band_high", "consistency",
           "cost_per_run_s", "cost_low", "cost_high", "cost_note", "machine")
NAN = math.nan


def roles(outputs: Mapping) -> dict:
    """``{role: column}`` of the roles the league reads (error, divergence, floor, nees) from a
    scenario's ``outputs(cfg)``, with ``unit`` and ``dof`` (of the NEES)."""
    out = {"unit": "", "dof": 0}
    for name, o in outputs.items():
        if o.role in ("error", "divergence", "floor", "nees") and o.role not in out:
            out[o.role] = name
            if o.role == "error":
                out["unit"] = o.unit
            if o.role == "nees":
                out["dof"] = int(getattr(o, "dof", 0) or 0)
    return out


def _series(rows: pd.DataFrame, col: str | None) -> pd.Series:
    if col is None or col not in rows.columns:
        return pd.Series(np.full(len(rows), np.nan), index=rows["seed_index"].to_numpy())
    return pd.Series(pd.to_numeric(rows[col], errors="coerce").to_numpy(float), index=rows["seed_index"].to_numpy())


def cell_rows(scenario: str, scenario_name: str, point: str, rows: pd.DataFrame, role: Mapping,
              filters: Sequence[str], all_filters: Sequence[str], notes: Mapping[str, str],
              costs: Mapping[str, tuple] | None = None, machine: str = "") -> list[dict]:
    """The league rows of one scenario × point: ``rows`` holds its runs (``filter`` with the league's
    names, ``seed_index`` and the output columns), ``role`` is :func:`roles`' mapping, ``filters``
    the filters run there and ``all_filters`` the league's (the others get a "not run" row with their
    ``notes``); ``costs``: filter → (seconds per run, note)."""
    costs = costs or {}
    err = role.get("error")
    by = {f: rows[rows["filter"] == f].sort_values("seed_index") for f in filters}
    errors = {f: _series(g, err) for f, g in by.items()}
    ranks = paired_ranks(errors)
    leaders = [f for f in filters if ranks[f] == 1]
    best = min(leaders, key=lambda f: np.nanmean(errors[f].to_numpy()), default=None)
    out = []
    for f in all_filters:
        row = dict.fromkeys(COLUMNS, NAN)
        row.update(scenario=scenario, scenario_name=scenario_name, point=point, filter=f, error_output=err or "",
                   unit=role.get("unit", ""), note="", consistency="", cost_note="", machine=machine, runs=0,
                   diverged=0, nees_dof=int(role.get("dof", 0)), rank=None)
        if f not in by:
            row.update(status="not run", note=notes.get(f, "not run"))
            out.append(row)
            continue
        g, e = by[f], errors[f]
        row.update(status="run", runs=len(g), rank=ranks[f])
        row["rmse"], row["rmse_low"], row["rmse_high"] = mean_ci(e.to_numpy())
        if best is not None:
            d = paired_difference(e, errors[best])
            row["vs_best"], row["vs_best_low"], row["vs_best_high"] = d
        if "floor" in role:
            row["floor_multiple"], row["floor_low"], row["floor_high"] = floor_multiple(
                e.to_numpy(), _series(g, role["floor"]).to_numpy())
        if "divergence" in role:
            flags = np.nan_to_num(_series(g, role["divergence"]).to_numpy(), nan=1.0) != 0
            row["diverged"] = int(flags.sum())
            row["divergence_rate"] = flags.mean() if len(flags) else NAN
            row["divergence_low"], row["divergence_high"] = wilson_interval(int(flags.sum()), len(flags))
        if "nees" in role and role.get("dof", 0) >= 1:
            v = _series(g, role["nees"]).to_numpy()
            v = v[np.isfinite(v)]
            if v.size:
                band = chi2_band(int(role["dof"]), v.size)
                row.update(anees=float(v.mean()), anees_band_low=band.low, anees_band_high=band.high,
                           consistency=consistency(float(v.mean()), band))
        if f in costs:
            row["cost_per_run_s"], row["cost_low"], row["cost_high"], row["cost_note"] = costs[f]
        out.append(row)
    return out


def frame(rows: list[dict]) -> pd.DataFrame:
    """The league table of :func:`cell_rows`' rows, with its column kinds."""
    df = pd.DataFrame(rows, columns=list(COLUMNS))
    df["rank"] = df["rank"].astype("Int64")
    for c in ("runs", "diverged", "nees_dof"):
        df[c] = df[c].astype("int64")
    return df


# ------------------------------------------------------------------ the table as a reader sees it

#: What a blank cell of a filter that ran says, by column.
NO_RANK = "no finite run"
NO_FLOOR = "no floor"
NO_NEES = "not computed"
NOT_TIMED = "not timed"
#: The note of a cell's fastest filter when no cost is starred.
WITHIN_SPREAD = "cost differences within the measurement's spread"


def _num(v: float) -> str:
    return "–" if v is None or not math.isfinite(v) else tables.format_number(float(v), 3)


def _ci(m: float, lo: float, hi: float, unit: str = "") -> str:
    return "–" if not math.isfinite(m) else wording.quote(float(m), float(lo), float(hi), unit)


def _best(values: pd.Series, key=lambda v: v) -> set:
    v = pd.to_numeric(values, errors="coerce").astype(float)
    v = v[np.isfinite(v)]
    if v.empty:
        return set()
    k = v.map(key)
    return set(k.index[k == k.min()])


def fastest(cell: pd.DataFrame) -> tuple[object, bool]:
    """``(index of the cell's fastest filter, clear)``: the lowest cost per run, and whether its range over
    the timed repeats lies below every other filter's (a cost difference beyond the measurement's
    spread); ``(None, False)`` with no cost."""
    cost = pd.to_numeric(cell["cost_per_run_s"], errors="coerce").astype(float)
    cost = cost[np.isfinite(cost)]
    if cost.empty:
        return None, False
    best = cost.idxmin()
    high = float(cell.loc[best, "cost_high"])
    others = pd.to_numeric(cell.loc[cost.index.drop(best), "cost_low"], errors="coerce").astype(float)
    clear = math.isfinite(high) and bool((others > high).all()) and not others.isna().any()
    return best, clear


def _anees(r) -> str:
    """``"1.04, below its band [1.22, 2.97]: under-confident"``: the ANEES against its band, in words."""
    if not math.isfinite(r["anees"]):
        return NO_NEES
    where = {"consistent": "inside", "under-confident": "below", "over-confident": "above"}.get(r["consistency"], "")
    band = f"[{_num(r['anees_band_low'])}, {_num(r['anees_band_high'])}]"
    return f"{_num(r['anees'])}, {where} its band {band}: {r['consistency']}" if where else _num(r["anees"])


def _cost(r) -> str:
    if not math.isfinite(r["cost_per_run_s"]):
        return NOT_TIMED
    ms = [1e3 * float(r[c]) for c in ("cost_per_run_s", "cost_low", "cost_high")]
    return f"{_num(ms[0])} [{_num(ms[1])}, {_num(ms[2])}]" if all(map(math.isfinite, ms[1:])) else _num(ms[0])


def display_table(table: pd.DataFrame) -> pd.DataFrame:
    """The league table for reading: per scenario × point its filters by rank, each statistic with its
    interval and unit, every blank cell saying why (:func:`legend` says what each word means), ``*``
    on the best of each column of the cell (lowest error, floor multiple and divergence rate; ANEES
    nearest its dof; the cost only where the fastest's range lies below every other's — else the
    fastest's note says the differences are within the measurement's spread)."""
    parts = []
    table = table.assign(**{c: NAN for c in ("cost_low", "cost_high") if c not in table})  # a league before 2026-12-07
    for (_, _), cell in table.groupby(["scenario", "point"], sort=False):
        cell = cell.assign(_r=cell["rank"].astype("float").fillna(np.inf)).sort_values(["_r", "rmse"], kind="stable")
        marks = {c: _best(cell[c]) for c in ("rmse", "floor_multiple", "divergence_rate")}
        marks["anees"] = _best(cell["anees"] / cell["nees_dof"].where(cell["nees_dof"] > 0), key=lambda v: abs(v - 1))
        quick, clear = fastest(cell)
        marks["cost"] = {quick} if clear else set()

        def star(col, i, text, marks=marks):
            return text + (" *" if i in marks[col] else "")

        for i, r in cell.iterrows():
            row = {"scenario": r["scenario"], "point": r["point"], "filter": r["filter"]}
            if r["status"] != "run":
                parts.append({**row, **dict.fromkeys(SHOWN[3:-1], "–"), "note": r["note"]})
                continue
            finite = math.isfinite(r["rmse"])
            note = [] if r["cost_note"] in ("", "alone") else [f"timed {r['cost_note']}"
                                                             if r["cost_note"].startswith("with ") else r["cost_note"]]
            if i == quick and not clear and math.isfinite(r["cost_high"]) and \
                    len(cell[np.isfinite(cell["cost_per_run_s"].astype(float))]) > 1:
                note.append(WITHIN_SPREAD)
            parts.append({
                **row, "rank": str(int(r["rank"])) if not pd.isna(r["rank"]) else NO_RANK,
                "error [95 %]": star("rmse", i, _ci(r["rmse"], r["rmse_low"], r["rmse_high"], r["unit"]))
                if finite else NO_RANK,
                "x floor [95 %]": star("floor_multiple", i, _ci(r["floor_multiple"], r["floor_low"], r["floor_high"]))
                if math.isfinite(r["floor_multiple"]) else NO_FLOOR,
                "diverged [95 %]": star("divergence_rate", i, wording.percent(r["divergence_rate"], r["divergence_low"],
                                                                              r["divergence_high"]))
                if math.isfinite(r["divergence_rate"]) else "not declared",
                "ANEES": star("anees", i, _anees(r)) if math.isfinite(r["anees"]) else NO_NEES,
                "ms/run [range]": star("cost", i, _cost(r)) if math.isfinite(r["cost_per_run_s"]) else NOT_TIMED,
                "note": "; ".join(note)})
    return pd.DataFrame(parts, columns=list(SHOWN))


#: The columns of :func:`display_table`.
SHOWN = ("scenario", "point", "filter", "rank", "error [95 %]", "x floor [95 %]", "diverged [95 %]", "ANEES",
         "ms/run [range]", "note")


def cost_method(meta: Mapping) -> str:
    """How the cost columns were measured, in one sentence (from the league table's metadata)."""
    if not meta.get("timing_runs") and not meta.get("machine"):
        return (f"ms/run: {NOT_TIMED} (the league file's timing_runs = 0: no timing pass)")
    t = meta.get("timing") or {}
    repeats, runs, load = t.get("repeats"), t.get("repeat_runs"), t.get("load")
    how = (f"the median of {repeats} timed repeats of {runs} run(s) each (one batch), after one untimed repeat "
           f"that compiles (compilation excluded), with the lowest and highest repeat in brackets; a run costs less "
           f"in a larger batch, so compare costs within one league" if repeats and runs else
           "compilation excluded")
    return (f"ms/run: milliseconds per run of the filter alone — the scenario at the league's first point built "
            f"with that filter as its only filter, so no other filter's work is timed (a filter the scenario runs "
            f"only beside another is timed with it: the note says so) — {how}; measured in one process on "
            f"{meta.get('machine') or 'this machine'}"
            + (f", load average {load} when the timing began" if load is not None else ""))


def legend(table: pd.DataFrame, meta: Mapping) -> list[str]:
    """What the league table's columns, words and marks mean, one line each (the printed table's
    header, the page's legend)."""
    run = table[table["status"] == "run"]
    units = "; ".join(f"{s}: {e or 'error'}" + (f" in {u}" if u else " (no unit)")
                      for s, e, u in run[["scenario", "error_output", "unit"]].drop_duplicates("scenario")
                      .itertuples(index=False))
    no_floor = sorted(set(run.loc[~np.isfinite(run["floor_multiple"].astype(float)), "scenario"]))
    no_nees = sorted(set(run.loc[~np.isfinite(run["anees"].astype(float)), "scenario"]))
    lines = [
        f"{meta.get('title', 'league')}: {table['scenario'].nunique()} scenario(s) x {table['point'].nunique()} "
        f"point(s) x {table['filter'].nunique()} filter(s), {meta.get('seeds', '?')} runs per cell, the same seeds "
        "for every filter of a cell",
        "rank: lowest mean error first; a filter whose paired-by-seed 95 % interval of its difference to the rank's "
        f"leader contains 0 shares its rank (it is not shown to be worse); {NO_RANK}: no rank and no error",
        f"error: each scenario's error output, the mean over its finite runs with its 95 % Student-t interval, in "
        f"its unit ({units or 'none ran'})",
        "x floor: the RMS error as a multiple of the error floor's (the posterior Cramér-Rao bound), 95 % "
        f"delta-method interval; {NO_FLOOR}: the scenario computes no floor at these settings (it needs "
        "bound = \"on\" and noise with Fisher information)" + (f" — here {', '.join(no_floor)}" if no_floor else ""),
        "diverged: the runs flagged diverged, in percent, 95 % Wilson interval",
        "ANEES: the average NEES over the finite runs against the 95 % band an average of that many runs falls in "
        "when the filter is consistent (chi-square, its middle the error's dimension): inside the band consistent, "
        "below it under-confident (errors smaller than the filter's covariance says), above it over-confident; "
        f"{NO_NEES}: no NEES at these settings (it needs consistency = \"on\")"
        + (f" — here {', '.join(no_nees)}" if no_nees else ""),
        cost_method(meta),
        "*: the best of each column in a scenario x point (lowest error, x floor and divergence; ANEES nearest the "
        "middle of its band); on ms/run only where the fastest's range lies below every other filter's, else its "
        f"note says \"{WITHIN_SPREAD}\"",
        "–: the filter did not run in this scenario (the note says why)",
    ]
    return lines


def league_text(table: pd.DataFrame, meta: Mapping, fmt: str = "text", width: int | None = None) -> str:
    """The league table with its legend (:func:`legend`) as header lines; ``width``: a terminal's columns
    (text cut into blocks of columns and its header wrapped, :func:`mcjax.analysis.tables.format_table`)."""
    tables.check_format(fmt)
    if fmt == "csv":
        return table.to_csv(index=False)
    display = display_table(table)
    display["scenario"] = [s if i == 0 or s != display["scenario"].iloc[i - 1] else ""
                           for i, s in enumerate(display["scenario"])] if fmt == "text" else display["scenario"]
    return tables.format_table(display, fmt, legend(table, meta), width=width if fmt == "text" else None)
