"""The rows every built-in config and the docs' example scenario give (6 runs x 40 steps)
are bit-identical to rows stored from the code before the study pipeline's restructuring
(tests/golden/*.parquet, written by tests/golden/make_rows.py at that commit): moving code
between modules must not move a bit. Outputs added since (the faults' counts, all at rate 0 in
these configs) are new columns; every stored column keeps its bits.

The configs with a fault model are also run with every kind of fault drawn and their per-step
series written (tests/golden/*_faults*.parquet, 6 seeds x 30 steps): written at the restructuring
of 2026-12-04 and checked equal, bit for bit, to the rows of the code before it (5ffcd9d).

Lou, Cui & Li 2013's three files were written again later on 2026-12-04: λ2's eigenvalues in pieces
(mcjax.tracking.numerics.eigvalsh, the fix of a two-device hang) moved the flock's floating-point columns under the
suite's cheap compile options by ≤ 7.4e-11 relative (no count or flag moved); with XLA's default options a
100-run sweep of every built-in config (40 steps) gave the same bits before and after."""

import sys
from pathlib import Path

import pandas as pd
import pytest

from mcjax.scenarios.kit import faults

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "golden"))
from golden_cases import CASES, FAULT_CASES, case_rows, fault_rows  # noqa: E402

STORED = Path(__file__).resolve().parents[1] / "golden"


@pytest.mark.parametrize("name", CASES)
def test_rows_are_bit_identical_to_the_stored_ones(name):
    stored = pd.read_parquet(STORED / f"{name}.parquet")
    got = case_rows(name)
    assert len(stored) > 0
    assert set(got.columns) - set(stored.columns) <= set(faults.SUMMARY_OUTPUTS)
    pd.testing.assert_frame_equal(got[list(stored.columns)].reset_index(drop=True), stored, check_exact=True,
                                  check_dtype=True)


@pytest.mark.parametrize("name", FAULT_CASES)
def test_rows_under_faults_and_their_series_are_bit_identical_to_the_stored_ones(name):
    runs, series = fault_rows(name)
    for got, file in ((runs, f"{name}_faults.parquet"), (series, f"{name}_faults_timeseries.parquet")):
        stored = pd.read_parquet(STORED / file)
        assert len(stored) > 0 and set(stored.columns) <= set(got.columns), file
        pd.testing.assert_frame_equal(got[list(stored.columns)].reset_index(drop=True), stored, check_exact=True,
                                      check_dtype=True)
