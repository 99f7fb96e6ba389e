"""Datasets outlive the code that wrote them: a sweep dataset and a tune folder written by mcjax
as of 2026-12-04 (tests/fixtures/legacy/, each cut short as an interruption leaves it; how they
were made: tests/fixtures/legacy/README.md) are read by today's ``mcjax report`` and finished by
``--resume`` to the rows of an uninterrupted run of today's code: the rows the resume computes bit for bit,
the rows the earlier code wrote by the golden-row rule (tests/golden/rule.py: they were written on another
machine, whose CPU model may round otherwise)."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import pandas as pd
from click.testing import CliRunner

from mcjax.base.parquet import read_table
from mcjax.cli import main

LEGACY = Path(__file__).resolve().parents[1] / "fixtures" / "legacy"
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "golden"))
from rule import compare  # noqa: E402


def _cli(*args: str):
    r = CliRunner().invoke(main, list(args))
    assert r.exit_code == 0, r.output
    return r


def _sorted(df: pd.DataFrame, keys: list[str]) -> pd.DataFrame:
    df = df.copy()
    for c in df.columns:
        if isinstance(df[c].dtype, pd.CategoricalDtype):
            df[c] = df[c].astype(str)
    return df.sort_values(keys).reset_index(drop=True)


def test_an_earlier_sweep_is_reported_and_resumed_to_the_uninterrupted_rows(tmp_path):
    old, fresh = tmp_path / "old", tmp_path / "fresh"
    shutil.copytree(LEGACY / "sweep", old)
    written = read_table(old)  # two of the three chunks: 2 x 150 runs x 3 filters less chunk 2's point 1
    assert 0 < len(written) < 2 * 150 * 3
    r = _cli("report", str(old), "--no-plots")
    assert "comm_radius" in r.output and "modified_icf" in r.output
    _cli("sweep", str(LEGACY / "sweep.toml"), "--out", str(old), "--resume")
    _cli("sweep", str(LEGACY / "sweep.toml"), "--out", str(fresh))
    keys = ["point_id", "seed_index", "filter"]
    resumed, whole = _sorted(read_table(old), keys), _sorted(read_table(fresh), keys)
    assert len(whole) == 2 * 150 * 3 and len(resumed) == len(whole)
    # the rows the resume computed are the uninterrupted run's, bit for bit (this machine, both times)
    earlier = written[keys].astype({"point_id": "int64"}).assign(_earlier=True)
    new = resumed.astype({"point_id": "int64"}).merge(earlier, on=keys, how="left")["_earlier"].isna().to_numpy()
    assert 0 < new.sum() < len(resumed)
    pd.testing.assert_frame_equal(resumed[new].reset_index(drop=True), whole[new].reset_index(drop=True),
                                  check_exact=True)
    # the rows the earlier code wrote are today's, by the golden-row rule
    before = whole.astype({"point_id": "int64"}).merge(earlier, on=keys, how="left")["_earlier"].notna().to_numpy()
    problems = compare(whole[before], _sorted(written, keys))  # planner = "none": an open loop
    assert not problems, "\n".join(problems)
    _cli("report", str(old), "--no-plots")


def test_an_earlier_tune_is_resumed_to_the_uninterrupted_trace_and_reported(tmp_path):
    old, fresh = tmp_path / "old", tmp_path / "fresh"
    shutil.copytree(LEGACY / "tune", old)
    before = pd.read_parquet(old / "trace.parquet")
    assert list(before["step"]) == [0]  # stopped in its second step
    _cli("tune", str(LEGACY / "tune.toml"), "--out", str(old), "--resume")
    _cli("tune", str(LEGACY / "tune.toml"), "--out", str(fresh))
    cols = ["step", "loss", "soft_rmse", "soft_divergence", "comm_radius", "sigma_accel", "grad_norm",
            "dropped_runs"]
    resumed, whole = pd.read_parquet(old / "trace.parquet"), pd.read_parquet(fresh / "trace.parquet")
    assert list(whole["step"]) == [0, 1, 2]
    pd.testing.assert_frame_equal(resumed[cols].iloc[:1], before[cols], check_exact=True)  # the step it kept
    # the earlier machine's step 0 and this one's may differ in rounding (another CPU model's vector code), and
    # the steps after it with them: the rule's 1e-8 across CPU models (tests/golden/rule.py)
    pd.testing.assert_frame_equal(resumed[cols], whole[cols], check_exact=False, rtol=1e-8, atol=1e-12)
    keys = ["point_id", "seed_index", "filter"]
    problems = compare(_sorted(read_table(old), keys), _sorted(read_table(fresh), keys))
    assert not problems, "\n".join(problems)
    r = _cli("report", str(old), "--no-plots")
    assert "initial" in r.output or "comm_radius" in r.output
