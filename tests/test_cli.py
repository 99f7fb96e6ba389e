"""The mcjax CLI driven through click's runner: sweeps to Parquet, dry runs, bad specs."""

import pandas as pd
import pyarrow.dataset as ds
import pytest
from click.testing import CliRunner

from mcjax.cli import main
from mcjax.results import read_metadata

BASE = str((__import__("pathlib").Path(__file__).parents[1] / "configs" / "sun2011.toml").resolve())


def _spec(tmp_path, body):
    p = tmp_path / "spec.toml"
    p.write_text(f'base = "{BASE}"\nseeds = 3\nchunk_size = 4\n[config]\nn_steps = 15\nwarmup_steps = 2\n' + body)
    return p


def test_sweep_writes_tidy_parquet(tmp_path):
    spec = _spec(tmp_path, "[grid]\ncomm_radius = [60e3, 100e3]\n")
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out)])
    assert r.exit_code == 0, r.output
    df = pd.read_parquet(out / "runs")
    assert len(df) == 2 * 3 * 5  # points x seeds x filters
    assert len(ds.dataset(out / "runs").to_table()) == 30
    assert set(df["comm_radius"]) == {60e3, 100e3}
    assert sorted(df.groupby(["point_id", "seed_index"]).size().unique()) == [5]
    meta = read_metadata(out)
    assert meta["config"]["n_steps"] == 15 and "jax" in meta and "git_revision" in meta
    assert "modified_icf" in r.output
    # a second run into the same folder refuses, writing nothing
    r2 = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out)])
    assert r2.exit_code == 2 and "not empty" in r2.output


def test_dry_run_compiles_and_writes_nothing(tmp_path):
    spec = _spec(tmp_path, "[grid]\ncomm_radius = [60e3, 80e3, 100e3]\n")
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out), "--dry-run"])
    assert r.exit_code == 0, r.output
    assert "3 point(s) x 3 seed(s) = 9 runs" in r.output and not out.exists()


@pytest.mark.parametrize("body, message", [
    ("[grid]\ncomm_radious = [1.0]\n", "did you mean 'comm_radius'"),
    ("[grid]\ncomm_radius = []\n", "grid.comm_radius: must be a non-empty list"),
    ("[params]\nsigma_range = \"ten\"\n", "params.sigma_range: must be a number"),
    ("[config]\nfilters = [\"cif\", \"ukf\"]\n", "unknown filter 'ukf'"),
])
def test_bad_spec_exit_2_nothing_written(tmp_path, body, message):
    spec = _spec(tmp_path, body) if not body.startswith("[config]") else None
    if spec is None:
        spec = tmp_path / "spec.toml"
        spec.write_text(f'base = "{BASE}"\n' + body)
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out)])
    assert r.exit_code == 2, r.output
    assert message in r.output
    assert not out.exists()


def test_help_explains_options():
    r = CliRunner().invoke(main, ["sweep", "--help"])
    assert r.exit_code == 0
    for opt in ("--out", "--seeds", "--chunk-size", "--set", "--dry-run", "--force"):
        assert opt in r.output
