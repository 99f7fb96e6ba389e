"""The rows every built-in config and the docs' example scenario give (6 runs x 40 steps)
are bit-identical to rows stored from the code before the study pipeline's restructuring
(tests/golden/*.parquet, written by tests/golden/make_rows.py at that commit): moving code
between modules must not move a bit. Outputs added since (the faults' counts, all at rate 0 in
these configs) are new columns; every stored column keeps its bits."""

import sys
from pathlib import Path

import pandas as pd
import pytest

from mcjax.scenarios import faults

sys.path.insert(0, str(Path(__file__).resolve().parent / "golden"))
from golden_cases import CASES, case_rows  # noqa: E402

STORED = Path(__file__).resolve().parent / "golden"


@pytest.mark.parametrize("name", CASES)
def test_rows_are_bit_identical_to_the_stored_ones(name):
    stored = pd.read_parquet(STORED / f"{name}.parquet")
    got = case_rows(name)
    assert len(stored) > 0
    assert set(got.columns) - set(stored.columns) <= set(faults.SUMMARY_OUTPUTS)
    pd.testing.assert_frame_equal(got[list(stored.columns)].reset_index(drop=True), stored, check_exact=True,
                                  check_dtype=True)
