"""Tests of mcjax.analysis.tables: metadata schema, grouping into the summary table (against a pandas
groupby computed here), legend lines with units, text/csv/markdown formats.

Also holds the synthetic-dataset builders used by tests/report/test_plots.py and tests/report/test_build.py.
"""

from __future__ import annotations

import io
import itertools
import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from mcjax.base import parquet

from mcjax.analysis import tables
FILTERS = ("kf", "local", "ekf")

# --------------------------------------------------------------------------------------
# synthetic datasets (shared with tests/report/test_plots.py and tests/report/test_build.py)
# --------------------------------------------------------------------------------------

GRAPH_OUTPUTS = {
    "lambda2_mean": {"unit": "", "description": "time-mean algebraic connectivity", "per_filter": False,
                     "role": "connectivity_mean"},
    "lambda2_min": {"unit": "", "description": "minimum algebraic connectivity", "per_filter": False,
                    "role": "connectivity_min"},
    "disconnected_steps": {"unit": "", "description": "steps with a disconnected graph",
                           "per_filter": False, "role": "disconnected_steps"},
}
PARAMS = {
    "comm_radius": {"unit": "m", "description": "communication radius", "per_agent": True, "allowed": ">= 0"},
    "eps": {"unit": "", "description": "consensus rate", "per_agent": False, "allowed": ">= 0"},
    "sigma_wind": {"unit": "m/s", "description": "wind noise", "per_agent": False, "allowed": ">= 0"},
    "comm_range": {"unit": "km", "description": "radio range", "per_agent": False, "allowed": ">= 0"},
    "turn_rate": {"unit": "rad/s", "description": "target turn rate", "per_agent": False, "allowed": "any"},
}


def make_metadata(grid=None, zipped=None, *, error="rmse", error_unit="m", divergence=True,
                  nonfinite=True, graph=True, filters=FILTERS, scenario="toy") -> dict:
    """Metadata as the sweep writes it (see mcjax.contract.Scenario.metadata)."""
    outputs = {error: {"unit": error_unit, "description": f"{error} over the run", "per_filter": True,
                       "role": "error"},
               "mean_error": {"unit": error_unit, "description": "mean error", "per_filter": True,
                              "role": None}}
    if divergence:
        outputs["diverged"] = {"unit": "", "description": "error above the divergence threshold",
                               "per_filter": True, "role": "divergence"}
    if nonfinite:
        outputs["nonfinite"] = {"unit": "", "description": "a non-finite estimate", "per_filter": True,
                                "role": "nonfinite"}
    if graph:
        outputs.update(GRAPH_OUTPUTS)
    spec = {"base": "configs/x.toml", "grid": dict(grid or {})}
    if zipped:
        spec["zip"] = dict(zipped)
    return {"scenario": scenario, "title": f"{scenario}: a synthetic scenario", "filters": list(filters),
            "outputs": outputs, "params": PARAMS, "spec": spec, "config": {"n_agents": 3}}


def synthetic_runs(grid: dict, seeds: int = 8, filters=FILTERS, seed: int = 0, *, error="rmse",
                   divergence=True, nonfinite=True, graph=True, n_nonfinite: int = 0) -> pd.DataFrame:
    """A runs table shaped like a sweep's: one row per (point, seed, filter).  The first
    ``n_nonfinite`` rows get a NaN error (flagged nonfinite and diverged)."""
    rng = np.random.default_rng(seed)
    names = list(grid)
    points = list(itertools.product(*(grid[n] for n in names))) if names else [()]
    rows = []
    for pid, values in enumerate(points):
        p = dict(zip(names, values))
        level = float(np.mean(next(iter(p.values())))) if p else 1.0
        for s in range(seeds):
            l2 = max(0.0, rng.normal(1.0, 0.5))
            for fi, f in enumerate(filters):
                div = bool(rng.random() < 0.15 + 0.1 * fi)
                r = (3 + fi) * (1 + 0.1 * level) * (1 + rng.normal(0, 0.1)) * (40 if div else 1)
                row = dict(scenario="toy", point_id=pid, seed_index=s, filter=f, **p, **{error: r},
                           mean_error=0.8 * r)
                if divergence:
                    row["diverged"] = div
                if nonfinite:
                    row["nonfinite"] = False
                if graph:
                    row.update(lambda2_mean=l2, lambda2_min=0.5 * l2, disconnected_steps=int(rng.poisson(2)))
                rows.append(row)
    df = pd.DataFrame(rows)
    for i in range(n_nonfinite):
        df.loc[i, error] = np.nan
        if divergence:
            df.loc[i, "diverged"] = True
        if nonfinite:
            df.loc[i, "nonfinite"] = True
    return df


def write_dataset(out_dir, df: pd.DataFrame, metadata: dict):
    """Write ``df`` as a sweep does: one hive partition per point."""
    for pid, part in df.groupby("point_id"):
        parquet.write_part(out_dir, "runs", part, "part-000000", metadata, partition={"point_id": int(pid)})
    return out_dir


def known_table() -> pd.DataFrame:
    """Two points x two filters x 4 seeds with hand-chosen values."""
    rows = []
    data = {  # (comm_radius, filter) -> rmse per seed, diverged per seed
        (50e3, "kf"): ([10.0, 12.0, 14.0, 1000.0], [False, False, False, True]),
        (50e3, "local"): ([20.0, 22.0, 2000.0, np.nan], [False, False, True, True]),
        (100e3, "kf"): ([5.0, 5.0, 5.0, 5.0], [False] * 4),
        (100e3, "local"): ([8.0, 9.0, 10.0, 11.0], [False] * 4),
    }
    l2 = {50e3: ([0.1, 0.2, 0.3, 0.4], [0.0, 0.05, 0.1, 0.2], [3, 1, 0, 0]),
          100e3: ([1.0, 1.0, 2.0, 2.0], [0.5, 0.6, 0.7, 0.8], [0, 0, 0, 0])}
    for (radius, f), (rmse, div) in data.items():
        lm, lmin, disc = l2[radius]
        for s in range(4):
            rows.append(dict(point_id=0 if radius == 50e3 else 1, seed_index=s, filter=f,
                             comm_radius=radius, rmse=rmse[s], diverged=div[s],
                             nonfinite=not np.isfinite(rmse[s]), lambda2_mean=lm[s],
                             lambda2_min=lmin[s], disconnected_steps=disc[s]))
    return pd.DataFrame(rows)


KNOWN_META = make_metadata({"comm_radius": [50e3, 100e3]}, filters=("kf", "local"))


# --------------------------------------------------------------------------------------
# schema and labels
# --------------------------------------------------------------------------------------


def test_schema_reads_roles_from_metadata():
    sch = tables.schema(make_metadata(error="wind_rmse"))
    assert sch.error == "wind_rmse" and sch.divergence == "diverged" and sch.nonfinite == "nonfinite"
    assert sch.connectivity == ("lambda2_mean", "lambda2_min", "disconnected_steps")
    assert sch.filters == FILTERS and sch.scenario == "toy"
    bare = tables.schema(make_metadata(divergence=False, nonfinite=False, graph=False))
    assert bare.divergence is None and bare.nonfinite is None and bare.connectivity == ()
    assert tables.schema(sch) is sch


def test_schema_errors():
    with pytest.raises(ValueError, match="older mcjax.*mcjax sweep"):
        tables.schema({"spec": {"grid": {}}})
    meta = make_metadata()
    meta["outputs"]["mean_error"]["role"] = "error"
    with pytest.raises(ValueError, match="both declare role 'error'"):
        tables.schema(meta)
    meta["outputs"]["mean_error"]["role"] = None
    meta["outputs"]["rmse"]["role"] = None
    with pytest.raises(ValueError, match="no output declares role 'error'"):
        tables.schema(meta)
    with pytest.raises(ValueError, match="lambda2_mean"):
        tables.schema(make_metadata(), ["filter", "rmse", "diverged", "nonfinite"])
    with pytest.raises(TypeError):
        tables.schema(None)


def test_swept_axes_from_metadata():
    cols = ["comm_radius", "eps", "sigma_wind", "filter"]
    meta = {"spec": {"grid": {"comm_radius": [1, 2]},
                     "zip": {"eps": [1, 2], "sigma_wind": [3, 4], "absent": [5, 6]}}}
    assert tables.swept_axes(meta, cols) == ["comm_radius", "eps", "sigma_wind"]
    assert tables.swept_axes({"spec": {"base": "x"}}, cols) == []
    assert tables.swept_axes({}, cols) == []
    assert tables.swept_axes(tables.schema(make_metadata(meta["spec"]["grid"], meta["spec"]["zip"])),
                             cols) == ["comm_radius", "eps", "sigma_wind"]


def test_labels_come_from_declared_units():
    meta = make_metadata(error="wind_rmse", error_unit="m/s")
    assert tables.label("wind_rmse", meta) == "wind_rmse [m/s]"
    assert tables.label("comm_range", meta) == "comm_range [km]"
    assert tables.label("eps", meta) == "eps"              # empty unit: no brackets
    assert tables.label("diverged", meta) == "diverged"
    assert tables.label("undeclared", meta) == "undeclared"
    assert tables.unit("turn_rate", tables.schema(meta)) == "rad/s"


def test_ordered_filters():
    assert tables.ordered_filters(["zz", "local", "kf", "aa", "local"], ("kf", "local", "ekf")) == \
        ["kf", "local", "aa", "zz"]
    assert tables.ordered_filters(["b", "a"], ()) == ["a", "b"]


# --------------------------------------------------------------------------------------
# summarize
# --------------------------------------------------------------------------------------


def test_summarize_known_values():
    s = tables.summarize(known_table(), KNOWN_META)
    assert list(s.columns) == ["comm_radius", "filter", *tables.summary_columns(KNOWN_META)]
    assert list(s.columns[2:]) == [
        "n", "rmse_mean", "rmse_ci_low", "rmse_ci_high", "n_ok", "rmse_ok_mean", "rmse_ok_ci_low",
        "rmse_ok_ci_high", "diverged", "nonfinite", "div_rate", "div_ci_low", "div_ci_high",
        "lambda2_mean", "lambda2_min", "disconnected_steps_mean"]
    assert list(zip(s["comm_radius"], s["filter"])) == [(50e3, "kf"), (50e3, "local"),
                                                        (100e3, "kf"), (100e3, "local")]
    assert s["n"].tolist() == [4, 4, 4, 4]
    assert s["diverged"].tolist() == [1, 2, 0, 0]
    assert s["n_ok"].tolist() == [3, 2, 4, 4]
    assert s["nonfinite"].tolist() == [0, 1, 0, 0]
    assert s["div_rate"].tolist() == [0.25, 0.5, 0.0, 0.0]
    ci = stats.binomtest(2, 4).proportion_ci(method="wilson")
    assert (s.loc[1, "div_ci_low"], s.loc[1, "div_ci_high"]) == pytest.approx((ci.low, ci.high), abs=1e-12)
    # rmse_mean: finite values only (the NaN of the non-finite run is left out)
    assert s["rmse_mean"].tolist() == pytest.approx([259.0, 2042.0 / 3, 5.0, 9.5])
    assert s["rmse_ok_mean"].tolist() == pytest.approx([12.0, 21.0, 5.0, 9.5])
    # 10, 12, 14: sd 2, se 2/sqrt(3), t(0.975, 2) = 4.302653 (textbook table)
    half = 4.302653 * 2 / math.sqrt(3)
    assert (s.loc[0, "rmse_ok_ci_low"], s.loc[0, "rmse_ok_ci_high"]) == pytest.approx((12 - half, 12 + half), rel=1e-6)
    assert s.loc[2, "rmse_ci_low"] == s.loc[2, "rmse_ci_high"] == 5.0  # constant: zero width
    assert s["lambda2_mean"].tolist() == pytest.approx([0.25, 0.25, 1.5, 1.5])
    assert s["lambda2_min"].tolist() == pytest.approx([0.0, 0.0, 0.5, 0.5])
    assert s["disconnected_steps_mean"].tolist() == pytest.approx([1.0, 1.0, 0.0, 0.0])


def _reference_summary(df: pd.DataFrame, keys: list[str]) -> pd.DataFrame:
    """The summary statistics straight from pandas + scipy, group by group."""
    rows = []
    for key, g in df.groupby(keys):
        key = key if isinstance(key, tuple) else (key,)
        finite = g["rmse"][np.isfinite(g["rmse"])]
        ok = g.loc[~g["diverged"].astype(bool), "rmse"]
        k, n = int(g["diverged"].sum()), len(g)
        ci = stats.t.interval(0.95, len(finite) - 1, loc=finite.mean(), scale=stats.sem(finite))
        ci_ok = stats.t.interval(0.95, len(ok) - 1, loc=ok.mean(), scale=stats.sem(ok))
        w = stats.binomtest(k, n).proportion_ci(method="wilson")
        rows.append({**dict(zip(keys, key)), "n": n, "rmse_mean": finite.mean(), "rmse_ci_low": ci[0],
                     "rmse_ci_high": ci[1], "n_ok": len(ok), "rmse_ok_mean": ok.mean(),
                     "rmse_ok_ci_low": ci_ok[0], "rmse_ok_ci_high": ci_ok[1], "diverged": k,
                     "nonfinite": int(g["nonfinite"].sum()), "div_rate": g["diverged"].mean(),
                     "div_ci_low": w.low, "div_ci_high": w.high,
                     "lambda2_mean": g["lambda2_mean"].mean(), "lambda2_min": g["lambda2_min"].min(),
                     "disconnected_steps_mean": g["disconnected_steps"].mean()})
    return pd.DataFrame(rows)


@pytest.mark.parametrize("axes", [None, ["eps"], []])
def test_summarize_matches_pandas_groupby(axes):
    grid = {"comm_radius": [50.0, 80.0], "eps": [0.1, 1.0, 10.0]}
    df = synthetic_runs(grid, seeds=9, n_nonfinite=2)
    meta = make_metadata(grid)
    s = tables.summarize(df, meta, axes)
    keys = [*(list(grid) if axes is None else axes), "filter"]
    ref = _reference_summary(df, keys)
    assert len(s) == len(ref) == (math.prod(len(grid[a]) for a in keys[:-1]) * len(FILTERS))
    merged = s.merge(ref, on=keys, suffixes=("", "_ref"), validate="one_to_one")
    assert len(merged) == len(s)
    for col in ref.columns.drop(keys):
        np.testing.assert_allclose(merged[col].to_numpy(float), merged[f"{col}_ref"].to_numpy(float),
                                   rtol=1e-9, atol=1e-12, err_msg=col)
    assert s["nonfinite"].sum() == 2
    # sorted by axes, then filters in the metadata's order
    assert s["filter"].tolist()[:3] == list(FILTERS)


def test_summarize_without_divergence_or_graph():
    grid = {"turn_rate": [0.0, 0.1]}
    meta = make_metadata(grid, error="pos_err", divergence=False, nonfinite=False, graph=False)
    df = synthetic_runs(grid, seeds=5, error="pos_err", divergence=False, nonfinite=False, graph=False)
    df.loc[0, "pos_err"] = np.inf
    s = tables.summarize(df, meta)
    assert list(s.columns) == ["turn_rate", "filter", "n", "pos_err_mean", "pos_err_ci_low",
                               "pos_err_ci_high", "nonfinite"]
    ref = df[np.isfinite(df["pos_err"])].groupby(["turn_rate", "filter"])["pos_err"].mean()
    got = s.set_index(["turn_rate", "filter"])["pos_err_mean"]
    np.testing.assert_allclose(got.loc[ref.index].to_numpy(), ref.to_numpy(), rtol=1e-12)
    assert s["nonfinite"].sum() == 1  # counted from the error column


def test_summarize_pools_orders_filters_and_list_axes():
    grid = {"comm_radius": [60.0, 100.0], "eps": [10.0, 50.0]}
    df = synthetic_runs(grid, seeds=5, filters=("local", "zz_custom", "kf", "aa"))
    meta = make_metadata(grid)
    s = tables.summarize(df, meta, [])
    assert s["filter"].tolist() == ["kf", "local", "aa", "zz_custom"]
    assert s["n"].tolist() == [20] * 4
    one = tables.summarize(df, meta, "eps")
    assert len(one) == 2 * 4 and set(one["n"]) == {10}
    # per-agent (list-valued) axis cells group as tuples
    df["comm_radius"] = [np.array([r, r]) for r in df["comm_radius"]]
    two = tables.summarize(df, meta, ["comm_radius"])
    assert two["comm_radius"].tolist()[::4] == [(60.0, 60.0), (100.0, 100.0)]
    with pytest.raises(ValueError, match="sigma_wind"):
        tables.summarize(df, meta, ["sigma_wind"])


def test_summarize_empty_table():
    s = tables.summarize(known_table().iloc[:0], KNOWN_META)
    assert s.empty and list(s.columns) == ["comm_radius", "filter", *tables.summary_columns(KNOWN_META)]
    assert list(tables.summarize(pd.DataFrame(), KNOWN_META).columns)[:2] == ["filter", "n"]


# --------------------------------------------------------------------------------------
# legend and formats
# --------------------------------------------------------------------------------------


def test_legend_lines_name_units_and_descriptions():
    meta = make_metadata({"sigma_wind": [1.0]}, error="wind_rmse", error_unit="m/s")
    lines = tables.legend_lines(meta, ["sigma_wind"])
    assert lines[0] == "scenario: toy — toy: a synthetic scenario"
    assert "wind_rmse: m/s — wind_rmse over the run" in lines
    assert "diverged: no unit — error above the divergence threshold" in lines
    assert "sigma_wind: m/s — wind noise" in lines
    assert "lambda2_mean: no unit — time-mean algebraic connectivity" in lines
    assert "mean_error" not in "\n".join(lines)  # not in the table, so not in its legend
    assert any("Wilson" in line for line in lines)
    bare = tables.legend_lines(make_metadata(divergence=False, graph=False, nonfinite=False))
    assert not any("Wilson" in line or "diverged" in line for line in bare)


def test_formats():
    s = tables.summarize(known_table(), KNOWN_META)
    head = tables.legend_lines(KNOWN_META, ["comm_radius"])
    text = tables.format_table(s, "text", head)
    lines = text.splitlines()
    assert lines[:len(head)] == head and lines[len(head)] == ""
    table = lines[len(head) + 1:]
    assert len(table) == 1 + len(s)
    assert table[0].split() == list(s.columns)
    assert table[1].split()[:3] == ["50000", "kf", "4"]
    assert "259" in table[1]
    assert tables.format_table(s, "text").splitlines() == table

    csv = tables.format_table(s, "csv", head)  # no legend in CSV
    back = pd.read_csv(io.StringIO(csv))
    assert list(back.columns) == list(s.columns)
    np.testing.assert_allclose(back["rmse_mean"], s["rmse_mean"], rtol=1e-12)

    md = tables.format_table(s, "markdown", head).splitlines()
    assert md[:len(head)] == [f"- {h}" for h in head] and md[len(head)] == ""
    md = md[len(head) + 1:]
    assert len(md) == 2 + len(s)
    assert md[0] == "| " + " | ".join(s.columns) + " |"
    assert set(md[1].strip("|").split("|")) <= {"---:", ":---"}
    assert all(line.startswith("| ") and line.endswith(" |") and line.count("|") == len(s.columns) + 1
               for line in md[2:])
    assert md[1].split("|")[2] == ":---"  # filter column left-aligned

    assert tables.format_table(s.iloc[:0], "text").splitlines()[0].split() == list(s.columns)


@pytest.mark.parametrize("bad", ["html", "TEXT", "", None, 3])
def test_bad_format_raises(bad):
    s = tables.summarize(known_table(), KNOWN_META)
    with pytest.raises(ValueError, match=r"fmt=.*'text', 'csv', 'markdown'"):
        tables.format_table(s, bad)


def test_format_number():
    assert tables.format_number(259.0) == "259"
    assert tables.format_number(2042.0 / 3) == "680.7"
    assert tables.format_number(1.23456e-6) == "1.235e-06"
    assert tables.format_number(np.nan) == "nan" and tables.format_number(np.int64(7)) == "7"
    assert tables.format_number((50e3, 1.5), 6) == "(50000, 1.5)"


def test_a_text_table_wider_than_the_terminal_is_cut_into_blocks_that_fit():
    """With a width, the text table is cut into blocks of columns that fit, each repeating the key columns (the
    axes and filter), every cell kept once; without one (a pipe) it is the one block it always was."""
    import numpy as np
    import pandas as pd

    from mcjax.analysis.tables import format_table

    df = pd.DataFrame({"comm_radius": [5e4, 1e5], "filter": ["icf", "cif"],
                       **{f"col_{i}_long_name": np.arange(2) * 1.25 + i for i in range(12)}})
    whole = format_table(df, "text", ["legend " * 30])
    assert max(map(len, whole.splitlines())) > 200 and whole == format_table(df, "text", ["legend " * 30], None)
    cut = format_table(df, "text", ["legend " * 30], width=80)
    lines = cut.splitlines()
    assert max(map(len, lines)) <= 80
    heads = [line for line in lines if line.startswith("comm_radius  filter")]
    assert len(heads) == 4  # four blocks of three columns each
    assert [c for h in heads for c in h.split()[2:]] == [f"col_{i}_long_name" for i in range(12)]
    assert sum(line.split()[1] == "cif" for line in lines if line.strip().startswith("100000")) == 4
    assert format_table(df, "text", (), width=10_000) == format_table(df, "text")


def test_the_terminal_width_is_columns_or_a_terminals_and_none_for_a_pipe(monkeypatch):
    import io
    import sys

    from mcjax.analysis.tables import terminal_width

    monkeypatch.setenv("COLUMNS", "123")
    assert terminal_width() == 123
    monkeypatch.delenv("COLUMNS")
    monkeypatch.setattr(sys, "stdout", io.StringIO())
    assert terminal_width() is None
