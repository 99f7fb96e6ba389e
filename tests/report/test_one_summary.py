"""One summary per report page: ``report(OUT)`` builds one :class:`mcjax.analysis.summary.Summary`
and its table, findings, quality sentences, figures and page read it -- the summarizing function
runs once per page -- and what they read of it is what each would compute alone.

The synthetic datasets are written here (pandas + :func:`mcjax.base.parquet.write_part`): no JAX.
"""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest

from mcjax.analysis import findings as findings_module
from mcjax.analysis import summary as summary_module
from mcjax.analysis import tables
from mcjax.analysis.summary import Summary, summarize_dataset
from mcjax.base import parquet
from mcjax.report import build, html_page
from mcjax.report.build import report, summary_text

FILTERS = ("kf", "local")


def metadata(grid: dict) -> dict:
    outputs = {
        "rmse": {"unit": "m", "description": "rmse over the run", "per_filter": True, "role": "error"},
        "diverged": {"unit": "", "description": "diverged", "per_filter": True, "role": "divergence"},
        "lambda2_mean": {"unit": "", "description": "mean connectivity", "per_filter": False,
                         "role": "connectivity_mean"},
        "disconnected_steps": {"unit": "", "description": "disconnected steps", "per_filter": False,
                               "role": "disconnected_steps"},
    }
    params = {name: {"unit": "m", "description": name, "per_agent": False, "allowed": ">= 0"} for name in grid}
    return {"scenario": "toy", "title": "toy: synthetic", "filters": list(FILTERS), "outputs": outputs,
            "params": params, "spec": {"base": "configs/x.toml", "grid": dict(grid)}}


def runs(grid: dict, seeds: int = 6, seed: int = 0) -> pd.DataFrame:
    """One row per (point, seed, filter), shaped like a sweep's runs table."""
    rng = np.random.default_rng(seed)
    names = list(grid)
    rows = []
    for pid, values in enumerate(itertools.product(*grid.values())):
        p = dict(zip(names, values))
        for s in range(seeds):
            l2 = max(0.0, rng.normal(1.0, 0.5))
            steps = int(rng.poisson(1))
            for fi, f in enumerate(FILTERS):
                div = bool(rng.random() < 0.2)
                r = (3 + 2 * fi) * (1 + 1e-4 * float(values[0])) * (1 + rng.normal(0, 0.1)) * (30 if div else 1)
                rows.append(dict(scenario="toy", point_id=pid, seed_index=s, filter=f, **p, rmse=r, diverged=div,
                                 lambda2_mean=l2, disconnected_steps=steps))
    return pd.DataFrame(rows)


def write(out, df: pd.DataFrame, meta: dict):
    for pid, part in df.groupby("point_id"):
        parquet.write_part(out, "runs", part, "part-000000", meta, partition={"point_id": int(pid)})
    return out


ONE_AXIS = {"comm_radius": [1000.0, 5000.0, 9000.0]}
TWO_AXES = {"comm_radius": [1000.0, 9000.0], "eps": [0.1, 0.5]}


def counting(monkeypatch):
    """Count the calls of tables.summarize and of summarize_dataset wherever they are looked up."""
    calls = {"summarize": 0, "summarize_dataset": 0}
    summarize, build_once = tables.summarize, summary_module.summarize_dataset

    def count_summarize(*args, **kwargs):
        calls["summarize"] += 1
        return summarize(*args, **kwargs)

    def count_build(*args, **kwargs):
        calls["summarize_dataset"] += 1
        return build_once(*args, **kwargs)

    monkeypatch.setattr(tables, "summarize", count_summarize)
    for module in (summary_module, build):
        monkeypatch.setattr(module, "summarize_dataset", count_build)
    import mcjax.report.plots.catalog as catalog
    if hasattr(catalog, "summarize"):  # (looked up there by name before the one summary)
        monkeypatch.setattr(catalog, "summarize", count_summarize)
    return calls


@pytest.mark.parametrize("grid", [ONE_AXIS, TWO_AXES], ids=["one_axis", "two_axes"])
def test_report_builds_one_summary(tmp_path, monkeypatch, grid):
    df, meta = runs(grid), metadata(grid)
    out = write(tmp_path / "out", df, meta)
    calls = counting(monkeypatch)
    table, paths = report(out)
    assert calls == {"summarize": 1, "summarize_dataset": 1}
    assert paths[-1].name == "index.html" and len(paths) > 1  # the figures and the page were written
    page = paths[-1].read_text(encoding="utf-8")
    assert "What this shows" in page


@pytest.mark.parametrize("fmt", tables.FORMATS)
def test_page_table_is_summary_text(tmp_path, fmt):
    df, meta = runs(TWO_AXES), metadata(TWO_AXES)
    out = write(tmp_path / "out", df, meta)
    table, _ = report(out, fmt, plots=False)
    read = parquet.read_table(out)
    assert table == summary_text(read, parquet.read_metadata(out), fmt)
    assert table == summary_text(read, meta, fmt, summary=summarize_dataset(read, meta))


def test_summary_holds_what_the_callers_computed():
    grid = {"comm_radius": [1000.0, 9000.0], "eps": [0.1, 0.5], "sigma": [2.0]}  # sigma: one value
    df, meta = runs(grid, seeds=5), metadata(grid)
    one = summarize_dataset(df, meta)
    assert isinstance(one, Summary)
    assert one.axes == ("comm_radius", "eps", "sigma") and one.plot_axes == ("comm_radius", "eps")
    assert one.schema == tables.schema(meta, df.columns)
    pd.testing.assert_frame_equal(one.table, tables.summarize(df, meta, list(one.axes)))
    for keys in ([], ["eps"], ["comm_radius"], ["eps", "comm_radius"], ["sigma", "eps"], ["comm_radius", "eps"]):
        pd.testing.assert_frame_equal(one.by(keys), tables.summarize(df, meta, keys))
        assert one.by(keys) is one.by(keys)  # kept
    for a, other in (("comm_radius", "eps"), ("eps", "comm_radius")):
        for value, rows in df.groupby(other):
            pd.testing.assert_frame_equal(one.at([a], ((other, value),)), tables.summarize(rows, meta, [a]))


@pytest.mark.parametrize("grid", [ONE_AXIS, TWO_AXES, {"comm_radius": [1000.0]}], ids=["one", "two", "point"])
def test_given_summary_changes_nothing(tmp_path, grid):
    df, meta = runs(grid), metadata(grid)
    one = summarize_dataset(df, meta)
    assert findings_module.findings(df, meta, summary=one) == findings_module.findings(df, meta)
    plain = html_page.page(tmp_path, df, meta, [], now=pd.Timestamp("2026-01-01", tz="UTC").to_pydatetime())
    shared = html_page.page(tmp_path, df, meta, [], now=pd.Timestamp("2026-01-01", tz="UTC").to_pydatetime(),
                            summary=one)
    assert shared == plain


def test_notebook_rows_read_their_summary(monkeypatch):
    from mcjax.notebook import SweepRows

    df, meta = runs(ONE_AXIS), metadata(ONE_AXIS)
    one = summarize_dataset(df, meta)
    res = SweepRows(df, meta, one.table, one.axes, None, one)
    calls = counting(monkeypatch)
    assert res.table() == summary_text(df, meta)
    assert res.findings() == [f.text for f in findings_module.findings(df, meta)]
    calls.update(summarize=0, summarize_dataset=0)
    res.table("markdown"), res.findings()
    assert calls == {"summarize": 0, "summarize_dataset": 0}  # read from the summary it was built with
