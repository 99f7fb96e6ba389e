"""The golden-row rule (tests/golden/rule.py) catches what it is for: stored rows perturbed by hand."""

import sys
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "golden"))
from rule import RTOL, compare  # noqa: E402

STORED = pd.read_parquet(Path(__file__).resolve().parents[1] / "golden" / "sun2011.parquet")


def _calm_row() -> int:
    return int((~STORED["diverged"]).to_numpy().argmax())


def _calm_scale(column: str) -> float:
    return float(STORED.loc[~STORED["diverged"], column].abs().max())


def test_the_same_rows_agree_and_rounding_in_a_calm_run_is_allowed():
    assert compare(STORED.copy(), STORED) == []
    got = STORED.copy()
    got.loc[_calm_row(), "rmse"] += 3e-9 * _calm_scale("rmse")
    assert compare(got, STORED) == []  # another CPU model's rounding
    assert compare(got, STORED, rtol=RTOL) != []  # two programs on one machine: 1e-9


def test_a_moved_output_of_a_run_that_did_not_diverge_is_caught():
    got = STORED.copy()
    got.loc[_calm_row(), "rmse"] += 1e-7 * _calm_scale("rmse")
    (line,) = compare(got, STORED)
    assert line.startswith("rmse: 1 of") and "1e-08" in line
    assert compare(got, STORED, closed_loop=True) == []  # within the closed loop's 1e-6
    got.loc[_calm_row(), "rmse"] += 1e-5 * _calm_scale("rmse")
    assert any(p.startswith("rmse") for p in compare(got, STORED, closed_loop=True))


def test_a_flipped_divergence_flag_a_changed_count_and_a_missing_row_are_caught():
    got = STORED.copy()
    got.loc[0, "diverged"] = not got.loc[0, "diverged"]
    assert "divergence flags differ" in compare(got, STORED)[0]
    got = STORED.copy()
    got.loc[_calm_row(), "disconnected_steps"] += 1
    assert any(p.startswith("disconnected_steps") for p in compare(got, STORED))
    assert "in one table only" in compare(STORED.iloc[1:], STORED)[0]


def test_diverged_runs_are_judged_by_their_statistics_not_their_bits():
    got = STORED.copy()
    diverged = got["diverged"].to_numpy()
    assert diverged.sum() >= 4
    got.loc[diverged, "rmse"] *= 1 + 1e-6  # rounding amplified: the statistics hold
    assert compare(got, STORED) == []
    got.loc[diverged, "rmse"] *= 3.0  # a different filter: they do not
    assert any("outside each other's 95 % intervals" in p for p in compare(got, STORED))
