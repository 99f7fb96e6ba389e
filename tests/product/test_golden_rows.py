"""The rows every built-in config and the docs' example scenario give (6 runs x 40 steps) agree with rows
stored from the code before the study pipeline's restructuring (tests/golden/*.parquet, written by
tests/golden/make_rows.py at that commit) by the golden-row rule (tests/golden/rule.py): every output of a
run that did not diverge to 1e-9 relative, every count and flag equal, the diverged runs by statistics. On
the machine that wrote them they agree bit for bit (``MCJAX_GOLDEN_EXACT=1`` checks that); another CPU
model's vector code (AVX2 where these were written with AVX-512) rounds otherwise, and an extended Kalman
filter far from the truth amplifies any rounding. Outputs added since (the faults' counts, all at rate 0
in these configs) are new columns.

The configs with a fault model are also run with every kind of fault drawn and their per-step
series written (tests/golden/*_faults*.parquet, 6 seeds x 30 steps): written at the restructuring
of 2026-12-04 and checked equal, bit for bit, to the rows of the code before it (5ffcd9d).

Lou, Cui & Li 2013's three files were written again later on 2026-12-04: λ2's eigenvalues in pieces
(mcjax.tracking.numerics.eigvalsh, the fix of a two-device hang) moved the flock's floating-point columns under the
suite's cheap compile options by ≤ 7.4e-11 relative (no count or flag moved); with XLA's default options a
100-run sweep of every built-in config (40 steps) gave the same bits before and after.

tests/product/test_other_cpu.py runs these tests again under XLA's AVX2 code where this machine has more."""

import os
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mcjax.scenarios.kit import faults

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "golden"))
from golden_cases import CASES, FAULT_CASES, case_rows, closed_loop, fault_rows  # noqa: E402
from rule import compare  # noqa: E402

STORED = Path(__file__).resolve().parents[1] / "golden"
#: On the machine that wrote the rows, a restructuring is checked bit for bit (tests/golden/rule.py).
EXACT = os.environ.get("MCJAX_GOLDEN_EXACT") == "1"


def _agree(name: str, got: pd.DataFrame, stored: pd.DataFrame, flags: pd.DataFrame | None = None):
    got = got[list(stored.columns)].reset_index(drop=True)
    if EXACT:
        pd.testing.assert_frame_equal(got, stored, check_exact=True, check_dtype=True)
        return
    assert list(got.dtypes) == list(stored.dtypes)
    problems = compare(got, stored, flags=flags, closed_loop=closed_loop(name))
    assert not problems, "\n".join(problems)


def _flags(got_runs: pd.DataFrame, stored_runs: pd.DataFrame) -> pd.DataFrame:
    """Each run x filter's divergence flag on both sides (the per-step series follow their run's)."""
    keys = ["point_id", "seed_index", "filter"]
    mine = got_runs[keys + ["diverged"]].astype({"point_id": np.int64})
    theirs = stored_runs[keys + ["diverged"]].astype({"point_id": np.int64})
    return mine.merge(theirs, on=keys, suffixes=("", "_stored"))


@pytest.mark.parametrize("name", CASES)
def test_rows_agree_with_the_stored_ones_by_the_golden_row_rule(name):
    stored = pd.read_parquet(STORED / f"{name}.parquet")
    got = case_rows(name)
    assert len(stored) > 0
    assert set(got.columns) - set(stored.columns) <= set(faults.SUMMARY_OUTPUTS)
    _agree(name, got, stored)


@pytest.mark.parametrize("name", FAULT_CASES)
def test_rows_under_faults_and_their_series_agree_with_the_stored_ones(name):
    runs, series = fault_rows(name)
    stored_runs = pd.read_parquet(STORED / f"{name}_faults.parquet")
    for got, file in ((runs, f"{name}_faults.parquet"), (series, f"{name}_faults_timeseries.parquet")):
        stored = pd.read_parquet(STORED / file)
        assert len(stored) > 0 and set(stored.columns) <= set(got.columns), file
        _agree(name, got, stored, None if got is runs else _flags(runs, stored_runs))
