"""Tests of mcjax.report (entry points) on synthetic datasets written as a sweep writes them,
and the rule that the report layer names no scenario, filter or unit."""

from __future__ import annotations

import io
import re
import subprocess
import sys
from pathlib import Path

import matplotlib
import pandas as pd
import pytest
from tests.analysis.test_tables import FILTERS, make_metadata, synthetic_runs, write_dataset
from tests.report.test_plots import check_png

from mcjax import report as rp
from mcjax.base import parquet

from mcjax.analysis import tables
PACKAGE = Path(rp.__file__).parents[1]
REPORT_MODULES = ("report/build.py", "report/html_page.py", "analysis/statistics.py", "analysis/tables.py",
                  *sorted(str(p.relative_to(PACKAGE)) for p in (PACKAGE / "report" / "plots").glob("*.py")))


def _pyplot_state():
    import matplotlib.pyplot as plt

    return matplotlib.get_backend(), list(plt.get_fignums())


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    root = tmp_path_factory.mktemp("report")
    one = {"comm_radius": [50.0, 70.0, 100.0]}
    two = {"comm_radius": [50.0, 100.0], "eps": [0.001, 0.01, 0.1, 1.0]}
    single = {"turn_rate": [0.0, 0.1]}
    wind = {"sigma_wind": [0.5, 2.0]}
    return {
        "one": write_dataset(root / "one", synthetic_runs(one, seeds=6), make_metadata(one)),
        "two": write_dataset(root / "two", synthetic_runs(two, seeds=3), make_metadata(two)),
        "zero": write_dataset(root / "zero", synthetic_runs({}, seeds=6), make_metadata({})),
        # (a) one agent: no communication graph, so no connectivity columns; error in m
        "single": write_dataset(root / "single", synthetic_runs(single, seeds=4, filters=("ekf", "ukf"), graph=False),
                                make_metadata(single, graph=False, filters=("ekf", "ukf"), scenario="solo")),
        # (b) an error metric in m/s
        "wind": write_dataset(root / "wind", synthetic_runs(wind, seeds=4, error="wind_rmse"),
                              make_metadata(wind, error="wind_rmse", error_unit="m/s", scenario="wind")),
    }


def _table_lines(text: str) -> list[str]:
    """The table of a text/markdown report (after the legend and its blank line)."""
    lines = text.splitlines()
    return lines[lines.index("") + 1:]


@pytest.mark.xdist_group("test_report")  # one worker builds the module fixture once
def test_report_one_axis(datasets):
    before = _pyplot_state()
    table, paths = rp.report(datasets["one"], "markdown")
    assert paths.pop().name == "index.html"  # the page comes last, after the plots
    assert _pyplot_state() == before  # no backend switch, no open pyplot figures
    rows = _table_lines(table)
    assert rows[0].startswith("| comm_radius | filter | n | rmse_mean |")
    assert len(rows) == 2 + 3 * len(FILTERS)
    assert "- rmse: m — rmse over the run" in table.splitlines()
    assert "- comm_radius: m — communication radius" in table.splitlines()
    assert sorted(p.name for p in paths) == sorted([
        "rmse_vs_comm_radius.png", "rmse_nondiverged_vs_comm_radius.png",
        "divergence_vs_comm_radius.png", "connectivity_vs_comm_radius.png"])
    for p in paths:
        assert p.parent == datasets["one"] / "report"
        check_png(p)


@pytest.mark.xdist_group("test_report")  # one worker builds the module fixture once
def test_report_two_axes(datasets):
    table, paths = rp.report(datasets["two"], "csv")
    assert paths.pop().name == "index.html"  # the page comes last, after the plots
    s = pd.read_csv(io.StringIO(table))
    assert list(s.columns[:3]) == ["comm_radius", "eps", "filter"]
    assert len(s) == 2 * 4 * len(FILTERS) and set(s["n"]) == {3}
    names = {p.name for p in paths}
    assert {"rmse_vs_eps.png", "divergence_vs_eps.png", "connectivity_vs_eps.png",
            "rmse_vs_comm_radius.png", "heatmap_divergence_comm_radius__eps.png",
            "heatmap_rmse_comm_radius__eps.png", "heatmap_rmse_nondiverged_comm_radius__eps.png"} <= names
    assert len(names) == len(paths) == 2 * 4 + 3


@pytest.mark.xdist_group("test_report")  # one worker builds the module fixture once
def test_report_zero_axes(datasets):
    table, paths = rp.report(datasets["zero"])
    assert paths.pop().name == "index.html"  # the page comes last, after the plots
    assert _table_lines(table)[0].split()[:3] == ["filter", "n", "rmse_mean"]
    assert [p.name for p in paths] == ["summary_bars.png"]
    check_png(paths[0])
    table2, none = rp.report(datasets["zero"], "text", plots=False)
    assert table2 == table and none == []


@pytest.mark.xdist_group("test_report")  # one worker builds the module fixture once
def test_report_single_agent_without_graph(datasets):
    """(a): the report works without connectivity columns; no connectivity statistics or plot."""
    table, paths = rp.report(datasets["single"])
    assert paths.pop().name == "index.html"  # the page comes last, after the plots
    assert "rmse: m — rmse over the run" in table and "turn_rate: deg/s (stored as rad/s) — target turn rate" in table
    header = _table_lines(table)[0].split()
    assert header[:4] == ["turn_rate", "filter", "n", "rmse_mean"]
    assert not any("lambda2" in h or "disconnected" in h for h in header)
    assert sorted(p.name for p in paths) == ["divergence_vs_turn_rate.png", "rmse_nondiverged_vs_turn_rate.png",
                                             "rmse_vs_turn_rate.png"]
    check_png(paths[0])


@pytest.mark.xdist_group("test_report")  # one worker builds the module fixture once
def test_report_error_in_m_per_s(datasets):
    """(b): the legend lines name m/s for the error metric, never [m]."""
    table, paths = rp.report(datasets["wind"], "text", plots=False)
    legend = table.splitlines()[:table.splitlines().index("")]
    assert legend[0] == "scenario: wind — wind: a synthetic scenario"
    assert "wind_rmse: m/s — wind_rmse over the run" in legend
    assert "sigma_wind: m/s — wind noise" in legend
    assert "[m]" not in table and "rmse: m " not in table
    assert _table_lines(table)[0].split()[:4] == ["sigma_wind", "filter", "n", "wind_rmse_mean"]


@pytest.mark.xdist_group("test_report")  # one worker builds the module fixture once
def test_summary_text_matches_report(datasets):
    out = datasets["two"]
    df, meta = parquet.read_table(out), parquet.read_metadata(out)
    for fmt in tables.FORMATS:
        assert rp.summary_text(df, meta, fmt) == rp.report(out, fmt, plots=False)[0]
    # in memory, straight from the sweep (point_id not a partition folder, no Parquet round trip)
    grid = {"eps": [0.1, 1.0]}
    text = rp.summary_text(synthetic_runs(grid, seeds=3), make_metadata(grid))
    rows = _table_lines(text)
    assert rows[0].split()[:3] == ["eps", "filter", "n"] and len(rows) == 1 + 2 * len(FILTERS)
    with pytest.raises(ValueError, match="empty"):
        rp.summary_text(synthetic_runs(grid).iloc[:0], make_metadata(grid))


@pytest.mark.xdist_group("test_report")  # one worker builds the module fixture once
def test_report_errors(tmp_path, datasets):
    with pytest.raises(ValueError, match="folder .*empty does not exist"):
        rp.report(tmp_path / "empty")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no runs found in .*empty"):
        rp.report(tmp_path / "empty")
    with pytest.raises(ValueError, match="fmt='html'"):
        rp.report(datasets["zero"], "html")
    with pytest.raises(ValueError, match="fmt='html'"):
        rp.summary_text(synthetic_runs({}), make_metadata({}), "html")


def test_dataset_from_older_mcjax(tmp_path):
    """Metadata without output declarations: a ValueError saying why and what to do."""
    df = synthetic_runs({"eps": [0.1, 1.0]}, seeds=2)
    old = tmp_path / "old"
    parquet.write_part(old, "runs", df, "part-000000", {"spec": {"grid": {"eps": [0.1, 1.0]}}})
    with pytest.raises(ValueError, match=r"cannot report on .*old.*older mcjax.*mcjax sweep .*--force"):
        rp.report(old)
    with pytest.raises(ValueError, match="older mcjax"):
        rp.summary_text(df, {"spec": {}})


def test_no_jax_import():
    code = ("import sys, mcjax.report as r, mcjax.report.plots, mcjax.report.html_page, mcjax.analysis.tables, mcjax.analysis.statistics; "
            "assert 'jax' not in sys.modules, 'imported jax'")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_report_layer_names_no_scenario_filter_or_unit():
    """Everything comes from the metadata: no scenario, filter or unit in the source."""
    words = re.compile(r"(?<![a-z])(cif|icf|imm|kcf|leader|uuv)(?![a-z])", re.IGNORECASE)
    literals = ("[m]", "m/s", "comm_radius")
    for name in REPORT_MODULES:
        text = (PACKAGE / name).read_text()
        assert not words.findall(text), (name, sorted(set(words.findall(text))))
        for lit in literals:
            assert lit not in text, (name, lit)
