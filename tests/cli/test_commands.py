"""The mcjax CLI driven through click's runner: sweeps to Parquet, dry runs, bad specs."""

import numpy as np
import pandas as pd
import pyarrow.dataset as ds
import pytest
from click.testing import CliRunner

from mcjax.base.parquet import read_metadata, read_table
from mcjax.cli import main

BASE = str((__import__("pathlib").Path(__file__).parents[2] / "configs" / "sun2011.toml").resolve())


def _spec(tmp_path, body):
    """A small open-loop spec; ``body``'s lines before its first [table] stay top-level."""
    top, sep, tables = body.partition("[")
    p = tmp_path / "spec.toml"
    p.write_text(f'base = "{BASE}"\nseeds = 3\nchunk_size = 4\n{top}[config]\nn_steps = 15\nwarmup_steps = 2\n'
                 'planner = "none"\n' + sep + tables)
    return p


# The sweeps of this file have 12 runs each (the compiled batch is the sweep's run count, up to
# the engine's batch size): one compiled program serves them all, the timeseries one apart.


def test_sweep_writes_tidy_parquet(tmp_path):
    spec = _spec(tmp_path, "[grid]\ncomm_radius = [60e3, 100e3]\n")
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out), "--seeds", "6"])
    assert r.exit_code == 0, r.output
    df = pd.read_parquet(out / "runs")
    assert len(df) == 2 * 6 * 5  # points x seeds x filters
    table = ds.dataset(out / "runs", partitioning="hive").to_table()  # hive: runs/point_id=P/
    assert table.num_rows == 60 and sorted(set(table.column("point_id").to_pylist())) == [0, 1]
    assert sorted(p.parent.name for p in (out / "runs").glob("*/*.parquet")) == ["point_id=0", "point_id=1"]
    assert set(df["comm_radius"]) == {60e3, 100e3}
    assert sorted(df.groupby(["point_id", "seed_index"]).size().unique()) == [5]
    meta = read_metadata(out)
    assert meta["config"]["n_steps"] == 15 and "jax" in meta and "git_revision" in meta
    assert "modified_icf" in r.output
    # a second run into the same folder refuses, writing nothing: the sweep is complete, so not --resume
    r2 = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out), "--seeds", "6"])
    assert r2.exit_code == 2 and "already holds this sweep, complete" in r2.output and "--resume" not in r2.output


def test_dry_run_compiles_and_writes_nothing(tmp_path):
    spec = _spec(tmp_path, "[grid]\ncomm_radius = [60e3, 80e3, 100e3]\n")
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out), "--dry-run"])
    assert r.exit_code == 0, r.output
    assert "3 point(s) x 3 seed(s) = 9 runs" in r.output and not out.exists()


def test_help_explains_options():
    r = CliRunner().invoke(main, ["sweep", "--help"])
    assert r.exit_code == 0
    for opt in ("--out", "--seeds", "--chunk-size", "--set", "--dry-run", "--force"):
        assert opt in r.output


def _sweep_cmd(spec, out, *extra):
    import sys
    return [sys.executable, "-m", "mcjax.cli", "sweep", str(spec), "--out", str(out), *extra]


def test_killed_sweep_resumes_to_identical_rows(tmp_path):
    import signal
    import subprocess
    import time

    spec = tmp_path / "spec.toml"
    spec.write_text(f'base = "{BASE}"\nseeds = 500\nchunk_size = 100\n[config]\nn_steps = 10\n'
                    f'warmup_steps = 2\nplanner = "none"\nfilters = ["cif", "modified_icf"]\n'
                    f'[grid]\ncomm_radius = [60e3, 80e3, 100e3]\n')
    out = tmp_path / "killed"
    proc = subprocess.Popen(_sweep_cmd(spec, out), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    while time.time() < deadline and not (out / "runs" / "point_id=0" / "part-000001.parquet").exists():
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    written = sorted(str(p) for p in (out / "runs").glob("*/*.parquet"))  # one chunk = one file here
    assert 2 <= len(written) < 15, written  # killed mid-way

    # the refusal and the uninterrupted reference sweep run in this process (a fresh Python
    # would import JAX again); the resume is a new process, as after a real kill
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out)])
    assert r.exit_code == 2 and "--resume" in r.output  # refuses without --resume
    r = subprocess.run(_sweep_cmd(spec, out, "--resume"), capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert f"{len(written)} of 15 chunk(s) already written" in r.stdout
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(tmp_path / "whole")])
    assert r.exit_code == 0, r.output
    resumed = pd.read_parquet(out / "runs").sort_values(["point_id", "seed_index", "filter"]).reset_index(drop=True)
    whole = pd.read_parquet(tmp_path / "whole" / "runs").sort_values(["point_id", "seed_index", "filter"]).reset_index(drop=True)
    assert len(resumed) == 3 * 500 * 2
    pd.testing.assert_frame_equal(resumed, whole, check_exact=True)
    assert not list((out / "_staging").glob("*")) if (out / "_staging").exists() else True


def test_timeseries_dataset(tmp_path):
    spec = _spec(tmp_path, 'timeseries = true\n[grid]\ncomm_radius = [60e3, 100e3]\n')
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out)])
    assert r.exit_code == 0, r.output
    ts = read_table(out, "timeseries")
    runs = read_table(out, "runs")
    assert len(ts) == 2 * 3 * 15 * 5  # points x seeds x steps x filters
    assert set(ts.columns) >= {"point_id", "seed_index", "t", "filter", "error_mean", "lambda2"}
    # the per-step series agree with the per-run summaries
    last = ts[ts["t"] == 14].set_index(["point_id", "seed_index", "filter"])["error_mean"]
    final = runs.set_index(["point_id", "seed_index", "filter"])["final_error"]
    np.testing.assert_allclose(last.sort_index().to_numpy(), final.sort_index().to_numpy(), rtol=1e-12)
    lam = ts.groupby(["point_id", "seed_index", "filter"])["lambda2"].min().sort_index()
    np.testing.assert_allclose(lam.to_numpy(), runs.set_index(["point_id", "seed_index", "filter"])
                               ["lambda2_min"].sort_index().to_numpy())


def test_resume_refuses_a_different_sweep(tmp_path):
    # 4 points x 3 seeds, as the report test's sweep (a one-point sweep, a batch of 3 runs,
    # compiled a program of its own)
    spec = _spec(tmp_path, "[grid]\ncomm_radius = [60e3, 100e3]\nsigma_bearing = [0.01, 0.02]\n")
    out = tmp_path / "out"
    assert CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out)]).exit_code == 0
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out), "--seeds", "4", "--resume"])
    assert r.exit_code == 2 and "different sweep" in r.output
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(tmp_path / "none"), "--resume"])
    assert r.exit_code == 2 and "nothing to resume" in r.output


def test_zip_and_range_axes(tmp_path):
    spec = _spec(tmp_path, "[grid]\nsigma_bearing = {linspace = [0.01, 0.03, 3]}\n"
                           "[zip]\nuav_speed = [600.0, 800.0]\nturn_rate_max = [0.1, 0.2]\n")
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(tmp_path / "o"), "--seeds", "2"])
    assert r.exit_code == 0, r.output
    df = pd.read_parquet(tmp_path / "o" / "runs")
    pts = df.drop_duplicates("point_id")[["sigma_bearing", "uav_speed", "turn_rate_max"]].to_numpy()
    assert len(pts) == 6
    assert {(round(a, 6), b, c) for a, b, c in pts} == {
        (s, v, t) for s in (0.01, 0.02, 0.03) for v, t in ((600.0, 0.1), (800.0, 0.2))}


@pytest.mark.parametrize("body, message", [
    ("[grid]\ncomm_radious = [1.0]\n", "did you mean 'comm_radius'"),
    ("[grid]\ncomm_radius = []\n", "grid.comm_radius: must be a non-empty list"),
    ("[params]\nsigma_range = \"ten\"\n", "params.sigma_range: must be a number"),
    ("[grid]\nfilters = [1.0]\n", "grid.filters: unknown key"),
    ("[grid]\ncomm_radius = [-5.0]\n", "grid.comm_radius: must be >= 0"),
    ("[zip]\nuav_speed = [1.0, 2.0]\nturn_rate_max = [0.1]\n", "zip: axes must have equal lengths"),
    ("[grid]\nsigma_range = {logspace = [0, 10, 3]}\n", "grid.sigma_range.logspace: start and stop must be > 0"),
    ("[grid]\nsigma_range = {linspace = [1, 10]}\n", "grid.sigma_range.linspace: must be [start, stop, count]"),
    ("[grid]\nhorizon = [3, 5, 12]\n", "grid.horizon: must be an integer in [1, max_horizon = "),  # the config's
    ("[params]\nhorizon = 2\n", "params.replan_every: must be an integer in [1, horizon]"),
    ("timeseries = 1\n", "timeseries: must be true or false"),
])
def test_bad_spec_exit_2_nothing_written(tmp_path, body, message):
    spec = _spec(tmp_path, body)
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2, r.output
    assert message in r.output and not (tmp_path / "o").exists()


def test_bad_config_value_exit_2(tmp_path):
    spec = tmp_path / "spec.toml"
    spec.write_text(f'base = "{BASE}"\n[config]\nfilters = ["cif", "ukf"]\n')
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2 and "config.filters: must be a non-empty list of distinct values from cif" in r.output and "(unknown: 'ukf')" in r.output and not (tmp_path / "o").exists()


def test_report_command_prints_table_and_writes_plots(tmp_path):
    import matplotlib.image as mpimg

    spec = _spec(tmp_path, "[grid]\ncomm_radius = [60e3, 100e3]\nsigma_bearing = [0.01, 0.02]\n")
    out = tmp_path / "out"
    assert CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out)]).exit_code == 0
    r = CliRunner().invoke(main, ["report", str(out), "--format", "markdown"])
    assert r.exit_code == 0, r.output
    assert "| comm_radius | sigma_bearing | filter |" in r.output
    plots = [line.split("plot: ", 1)[1] for line in r.output.splitlines() if line.startswith("plot: ")]
    assert any("heatmap" in p for p in plots) and any("divergence_vs_comm_radius" in p for p in plots)
    for p in plots:
        img = mpimg.imread(p)
        assert img.size > 0 and img.std() > 0
    r = CliRunner().invoke(main, ["report", str(tmp_path / "empty")])
    assert r.exit_code == 2


@pytest.mark.parametrize("cmd", [["--help"], ["run", "--help"], ["report", "--help"], ["list", "--help"]])
def test_every_command_has_help(cmd):
    r = CliRunner().invoke(main, cmd)
    assert r.exit_code == 0 and "Usage:" in r.output and len(r.output) > 200


# the shipped sweep specs (a spec with a [tune] table is for mcjax tune: tests/tune/test_tune.py)
SWEEPS = [p for p in sorted((__import__("pathlib").Path(__file__).parents[2] / "sweeps").glob("*.toml"))
          if "[tune]" not in p.read_text(encoding="utf-8")]


@pytest.mark.parametrize("spec", SWEEPS, ids=[p.stem for p in SWEEPS])
def test_shipped_sweeps_validate(tmp_path, spec):
    assert len(SWEEPS) >= 5
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(tmp_path / "o"), "--dry-run"])
    assert r.exit_code == 0, r.output
    assert "runs" in r.output and not (tmp_path / "o").exists()


def test_python_dash_m_mcjax_is_the_command_line():
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "mcjax", "list"], capture_output=True, text=True, timeout=120,
                       cwd=__import__("pathlib").Path(__file__).parents[2])
    assert r.returncode == 0, r.stderr
    assert r.stdout == CliRunner().invoke(main, ["list"]).output and "leader_follower" in r.stdout


@pytest.mark.parametrize("typed, meant", [("leader_folower", "leader_follower"), ("flockng", "flocking"),
                                          ("uuv-imm", "uuv_imm"), ("wind_formations", "wind_formation")])
def test_list_suggests_the_scenario_one_typo_away(typed, meant):
    r = CliRunner().invoke(main, ["list", typed])
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1, r.output
    assert f"did you mean {meant!r}? (`mcjax list {meant}`)" in r.output
    far = CliRunner().invoke(main, ["list", "kalman"])
    assert far.exit_code == 2 and "did you mean" not in far.output  # nothing close: no guess


def test_a_config_with_a_misspelt_scenario_gets_the_suggestion_too(tmp_path):
    config = tmp_path / "typo.toml"
    config.write_text('scenario = "leader_folower"\nseeds = 2\n')
    r = CliRunner().invoke(main, ["run", str(config)])
    assert r.exit_code == 2 and len(r.output.strip().splitlines()) == 1, r.output
    assert "did you mean 'leader_follower'?" in r.output


def test_list_with_a_config_marks_every_field_it_sets_to_the_default():
    """docs/cli.md: `(FILE: the same)` where the file sets a field to the default — Config fields
    too — and a value the file writes with fewer decimals (546.41 for 546.41016) is not a change."""
    import tomllib
    from pathlib import Path

    from mcjax import scenarios
    from mcjax.cli.listing import same_value

    path = Path(__file__).parents[2] / "configs" / "ren2017.toml"
    r = CliRunner().invoke(main, ["list", "uuv_imm", "--config", str(path)])
    assert r.exit_code == 0, r.output
    lines = r.output.splitlines()
    data = tomllib.loads(path.read_text())
    sc = scenarios.get("uuv_imm")
    for table, names in (("params", sc.params_table), ("config", sc.settings)):
        for name in names:
            value = lines[next(i for i, s in enumerate(lines) if s.startswith(f"  {name}:") or
                               s.startswith(f"  {name} ")) + 1]
            if name in data[table]:  # this config sets every field to the code's default
                assert "(ren2017.toml: the same" in value and "<-" not in value, (name, value)
            else:
                assert "ren2017.toml" not in value, (name, value)
    assert "(ren2017.toml: the same, rounded)" in lines[next(i for i, s in enumerate(lines)
                                                               if s.startswith("  uuv_positions")) + 1]
    # rounding is not a licence to hide a change
    assert same_value(546.41016, 546.41) == "rounded" and same_value([[1.0, 546.41016]], [[1, 546.41]]) == "rounded"
    assert same_value(3.04, 3.0) is None and same_value(249.0, 200.0) is None and same_value(0.001, 0.0) is None
    assert same_value(546.41016, 546.42) is None and same_value(("a", "b"), ("a", "b")) == "exact"
    assert same_value(1.0, 1) == "exact" and same_value([1.0, 2.0], [1.0]) is None
