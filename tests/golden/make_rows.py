"""Writes the rows tests/product/test_golden_rows.py compares with: every built-in config and the
docs' example scenario, 6 runs x 40 steps, as the code of the commit that wrote them computes
them (run from the repository root: ``python tests/golden/make_rows.py``; the suite's XLA
flags are set the same way as in tests/conftest.py)."""

import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
import conftest  # noqa: E402,F401  (the suite's environment: XLA flags, one CPU device)

from golden_cases import CASES, FAULT_CASES, case_rows, fault_rows  # noqa: E402


if __name__ == "__main__":
    for name in CASES:
        df = case_rows(name)
        df.to_parquet(HERE / f"{name}.parquet", index=False)
        print(name, df.shape)
    for name in FAULT_CASES:
        runs, series = fault_rows(name)
        runs.to_parquet(HERE / f"{name}_faults.parquet", index=False)
        series.to_parquet(HERE / f"{name}_faults_timeseries.parquet", index=False)
        print(name, "faults", runs.shape, series.shape)
