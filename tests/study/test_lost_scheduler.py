"""A Dask scheduler that goes away in the middle of a sweep (kill -9): the command ends within
mcjax.study.dask.LOST_AFTER seconds with one line and exit code 1; the parts written are whole;
--resume, locally, completes a dataset bit-identical to a local sweep's."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time

import pandas as pd
import pytest
from click.testing import CliRunner

from mcjax.base.parquet import read_table
from mcjax.cli import main
from mcjax.study import check_parts, load_spec
from tests.study.test_lock import write_probe

pytestmark = pytest.mark.xdist_group("dask")  # not beside the other Dask tests' cluster


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for(cond, what: str, timeout: float = 120.0) -> None:
    t0 = time.monotonic()
    while not cond():
        assert time.monotonic() - t0 < timeout, f"timed out waiting for {what}"
        time.sleep(0.05)


def test_scheduler_killed_mid_sweep_exits_1_in_time_and_resume_is_bit_identical(tmp_path):
    pytest.importorskip("distributed")
    from mcjax.study.dask import LOST_AFTER

    dask = shutil.which("dask")
    if dask is None:
        pytest.skip("the dask command is not installed")
    spec = write_probe(tmp_path)
    spec.write_text('base = "probe.toml"\nseeds = 100\nchunk_size = 100\n[grid]\nr = [0.5, 1.0, 2.0, 4.0, 8.0, 16.0]\n')
    address = f"tcp://127.0.0.1:{_free_port()}"
    logs = open(tmp_path / "cluster.log", "w")
    scheduler = subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", address.rsplit(":", 1)[1],
                                  "--no-dashboard"], stdout=logs, stderr=logs)
    worker = None
    try:
        worker = subprocess.Popen([dask, "worker", address, "--nthreads", "1", "--no-dashboard"], stdout=logs,
                                  stderr=logs, env={**os.environ, "MCJAX_CPU_DEVICES": "1"})
        r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(tmp_path / "local")])  # meanwhile
        assert r.exit_code == 0, r.output
        reference = read_table(tmp_path / "local")
        out = tmp_path / "out"
        (tmp_path / "pace").touch()  # half a second per chunk: the kill lands mid-sweep
        sweep = subprocess.Popen([sys.executable, "-m", "mcjax.cli", "sweep", str(spec), "--out", str(out),
                                  "--executor", "dask", "--scheduler", address],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        _wait_for(lambda: sweep.poll() is not None or list((out / "runs").glob("*/*.parquet")), "a first part")
        scheduler.kill()
        t0 = time.monotonic()
        stdout, stderr = sweep.communicate(timeout=120)
        took = time.monotonic() - t0
    finally:
        for p in (worker, scheduler):  # the worker first, gently: its nanny stops its worker process
            if p is not None and p.poll() is None:
                p.terminate()
                try:
                    p.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
        logs.close()
        (tmp_path / "pace").unlink(missing_ok=True)
    assert sweep.returncode == 1, (stdout, stderr)
    assert took < LOST_AFTER, took
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"error: lost the Dask scheduler at {address}"), stderr
    assert "--resume" in lines[0]
    todo, problems = check_parts(load_spec(spec), out)
    assert 0 < len(todo) < 6 and all("missing" in p for p in problems), (todo, problems)
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out), "--resume"])
    assert r.exit_code == 0, r.output
    pd.testing.assert_frame_equal(read_table(out), reference, check_exact=True)
