"""Every claims file of benchmarks/claims/ is read and checked whole (every claim's sweep, point, output,
filter and relation against its sweeps' scenarios: :func:`mcjax.claims.spec.load_claims`), and the files of
three scenarios run through `mcjax check` at a small seed count: the machinery only (its sweeps build and
run, every claim gets a row); the verdicts are not asserted here — they need the 1,000 runs per point of the
full check (docs/papers.md). The other files' sweeps (Sun et al. 2011's closed loops, the fault sweeps of
every scenario, the urban planners) are the same programs at 2 runs; running them here cost ~110 s of the
suite's CPU time for no check the static one and tests/claims/test_claims.py do not make."""

from __future__ import annotations

from pathlib import Path

import pytest

from mcjax.claims.evaluate import COLUMNS
from mcjax.claims.runner import run_check
from mcjax.claims.spec import load_claims
from mcjax.claims.verdicts import VERDICTS

ROOT = Path(__file__).resolve().parents[2]
FILES = sorted((ROOT / "benchmarks" / "claims").glob("*.toml"))


def test_the_five_papers_have_claims_files():
    papers = {load_claims(f, seeds=1).paper for f in FILES}
    assert {"Sun, Zhou, Zou & Ding 2011", "Ren & Lv 2017", "Chen & Hao 2022", "Lou, Cui & Li 2013",
            "Chen & Lu 2013"} <= papers


#: The files run end to end here: three scenarios, the cheapest sweeps.
RUN = [f for f in FILES if f.stem in ("ren2017", "chen2022", "chen2013")]


@pytest.mark.parametrize("path", FILES, ids=[f.stem for f in FILES])
def test_claims_file_is_read_whole(path):
    claims = load_claims(path, seeds=2)
    assert claims.claims and len({c.id for c in claims.claims}) == len(claims.claims)


@pytest.mark.parametrize("path", RUN, ids=[f.stem for f in RUN])
def test_claims_file_runs_at_two_seeds(path, tmp_path):
    result = run_check(path, seeds=2, out_dir=tmp_path / "check")
    table = result.table
    assert list(table.columns) == list(COLUMNS)
    assert list(table["id"]) == [c.id for c in result.claims.claims]
    assert set(table["verdict"]) <= set(VERDICTS)
    assert (table["runs"] <= 2).all() and (tmp_path / "check" / "claims.parquet").is_file()
