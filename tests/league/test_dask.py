"""The tiny league (conftest.py) on a Dask cluster gives the league.parquet of a league run here.

The cluster is tests/study/test_dask.py's kind: a LocalCluster of 2 worker processes
(:func:`mcjax.study.dask.local_cluster`), started once for the module, its workers importing mcjax
while this process runs the league locally.
"""

import importlib
import threading
from pathlib import Path
from typing import Any, NamedTuple

import pandas as pd
import pytest
from click.testing import CliRunner

from mcjax.base.parquet import read_table
from mcjax.cli import main
from mcjax.league.folder import read_league
from mcjax.league.runner import run_league

from .conftest import TINY

# on the pytest-xdist worker of the other Dask tests (pyproject: --dist loadgroup): one cluster at a time
pytestmark = pytest.mark.xdist_group("dask")

#: The league table's columns a Dask run need not repeat to the bit: the seconds per run the timing
#: pass measures (a clock's reading; NaN here, the tiny league has no timing pass).
MEASURED = ["cost_per_run_s"]
#: league.parquet's metadata that is a time stamp (environment_metadata's created_utc).
STAMPED = ["created_utc"]


class Lab(NamedTuple):
    client: Any
    address: str
    league: Path       # the tiny league file
    local: Any         # its LeagueResult, run in this process into local/


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    distributed = pytest.importorskip("distributed")
    from mcjax.study.dask import local_cluster

    root = tmp_path_factory.mktemp("league_dask")
    league = root / "tiny.toml"
    league.write_text(TINY, encoding="utf-8")
    with local_cluster(2) as cluster, distributed.Client(cluster, set_as_default=False) as client:
        # the workers import mcjax while this process runs the league locally
        warm = threading.Thread(target=client.run, args=(lambda: importlib.import_module("mcjax.study.dask").__name__,))
        warm.start()
        local = run_league(league, out_dir=root / "local")
        warm.join()
        yield Lab(client, cluster.scheduler_address, league, local)


def _on_workers() -> dict:
    from mcjax.study import dask as cluster

    return {token: spec.scenario.name for token, spec in cluster.worker_specs().items()}


def test_a_league_on_dask_gives_the_local_league_parquet(lab, tmp_path):
    """`mcjax league --executor dask --scheduler ADDRESS`: every cell's sweep folder holds the local
    league's runs and league.parquet the local table, bit for bit but for the measured cost column;
    its metadata too, but for the time stamp."""
    out = tmp_path / "dask"
    r = CliRunner().invoke(main, ["league", str(lab.league), "--out", str(out),
                                  "--executor", "dask", "--scheduler", lab.address])
    assert r.exit_code == 0, r.output
    # the cells' chunks were computed by the workers (each cell's spec was shipped to them), not here
    shipped = {}
    for specs in lab.client.run(_on_workers).values():
        shipped.update(specs)
    league = lab.local.league
    cells = len(league.studies)
    assert len(shipped) == cells, shipped
    assert set(shipped.values()) == {e.scenario for e in league.scenarios.values()}, shipped

    local_dir = lab.local.out_dir
    for key, point in league.studies:
        pd.testing.assert_frame_equal(read_table(out / key / point), read_table(local_dir / key / point),
                                      check_exact=True)
    dask_table, dask_meta = read_league(out)
    local_table, local_meta = read_league(local_dir)
    assert len(local_table) == 2 * 2 and set(local_table["status"]) == {"run"} and (local_table["runs"] == 8).all()
    pd.testing.assert_frame_equal(dask_table.drop(columns=MEASURED), local_table.drop(columns=MEASURED),
                                  check_exact=True)
    assert dask_table[MEASURED].isna().all().all() and local_table[MEASURED].isna().all().all()  # no timing pass
    assert {k: v for k, v in dask_meta.items() if k not in STAMPED} == \
        {k: v for k, v in local_meta.items() if k not in STAMPED}
