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
  the timing pass on ``machine``.

A column the scenario does not declare (no floor, no NEES) is NaN. A league filter a scenario does
not run has ``status`` "not run" and ``note`` says why. Pure functions of tables; no JAX.
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np
import pandas as pd

from mcjax.analysis import tables
from mcjax.analysis.statistics import chi2_band, consistency, floor_multiple, mean_ci, wilson_interval
from mcjax.league.rank import paired_difference, paired_ranks

#: The columns of the league table, in order.
COLUMNS = ("scenario", "scenario_name", "point", "filter", "status", "note", "runs", "error_output", "unit",
           "rank", "rmse", "rmse_low", "rmse_high", "vs_best", "vs_best_low", "vs_best_high",
           "floor_multiple", "floor_low", "floor_high", "diverged", "divergence_rate", "divergence_low",
           "divergence_high", "anees", "nees_dof", "anees_band_low", "anees_band_high", "consistency",
           "cost_per_run_s", "cost_note", "machine")
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
            row["cost_per_run_s"], row["cost_note"] = costs[f]
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

def _num(v: float) -> str:
    return "–" if v is None or not math.isfinite(v) else tables.format_number(float(v), 3)


def _ci(m: float, lo: float, hi: float) -> str:
    return "–" if not math.isfinite(m) else f"{_num(m)} [{_num(lo)}, {_num(hi)}]"


def _best(values: pd.Series, key=lambda v: v) -> set:
    v = pd.to_numeric(values, errors="coerce").astype(float)
    v = v[np.isfinite(v)]
    if v.empty:
        return set()
    k = v.map(key)
    return set(k.index[k == k.min()])


def display_table(table: pd.DataFrame) -> pd.DataFrame:
    """The league table for reading: per scenario × point its filters by rank, each statistic with
    its interval, ``*`` on the best of each column of the cell (lowest error, floor multiple,
    divergence rate and cost; ANEES nearest its dof)."""
    parts = []
    for (_, _), cell in table.groupby(["scenario", "point"], sort=False):
        cell = cell.assign(_r=cell["rank"].astype("float").fillna(np.inf)).sort_values(["_r", "rmse"], kind="stable")
        marks = {c: _best(cell[c]) for c in ("rmse", "floor_multiple", "divergence_rate", "cost_per_run_s")}
        marks["anees"] = _best(cell["anees"] / cell["nees_dof"].where(cell["nees_dof"] > 0), key=lambda v: abs(v - 1))

        def star(col, i, text, marks=marks):
            return text + (" *" if i in marks[col] and text != "–" else "")

        for i, r in cell.iterrows():
            run = r["status"] == "run"
            band = f" in [{_num(r['anees_band_low'])}, {_num(r['anees_band_high'])}]" if math.isfinite(
                r["anees_band_low"]) else ""
            parts.append({
                "scenario": r["scenario"], "point": r["point"], "filter": r["filter"],
                "rank": str(int(r["rank"])) if run and not pd.isna(r["rank"]) else "–",
                f"{r['error_output'] or 'error'} [95 %]": star("rmse", i, _ci(r["rmse"], r["rmse_low"], r["rmse_high"])),
                "x floor [95 %]": star("floor_multiple", i, _ci(r["floor_multiple"], r["floor_low"], r["floor_high"])),
                "diverged [95 %]": star("divergence_rate", i, _ci(r["divergence_rate"], r["divergence_low"],
                                                                  r["divergence_high"])) if run else "–",
                "ANEES": star("anees", i, f"{_num(r['anees'])}{band} {r['consistency']}".strip())
                if math.isfinite(r["anees"]) else "–",
                "s/run": star("cost_per_run_s", i, _num(r["cost_per_run_s"])),
                "note": r["note"] if not run else (r["cost_note"] or ""),
            })
    return pd.DataFrame(parts)


def league_text(table: pd.DataFrame, meta: Mapping, fmt: str = "text") -> str:
    """The league table with its header lines (title, runs, the ranking rule, the machine)."""
    tables.check_format(fmt)
    if fmt == "csv":
        return table.to_csv(index=False)
    machine = meta.get("machine") or "no timing pass"
    header = [f"{meta.get('title', 'league')}: {table['scenario'].nunique()} scenario(s) x "
              f"{table['point'].nunique()} point(s) x {table['filter'].nunique()} filter(s), "
              f"{meta.get('seeds', '?')} runs per cell, the same seeds for every filter",
              "rank: lowest mean error first; a filter whose paired-by-seed 95 % interval of its difference to the "
              "rank's leader contains 0 shares its rank; * marks the best of each column in a scenario x point",
              "intervals 95 %: error and x floor Student-t (x floor: delta method), diverged Wilson; ANEES against "
              "its chi-square band",
              f"s/run: seconds per run with that filter alone, on {machine}"]
    display = display_table(table)
    display["scenario"] = [s if i == 0 or s != display["scenario"].iloc[i - 1] else ""
                           for i, s in enumerate(display["scenario"])] if fmt == "text" else display["scenario"]
    return tables.format_table(display, fmt, header)
