"""Sweeps on a Dask cluster (mcjax.study.dask): a LocalCluster of 2 worker processes, shared by the tests.

The scenario is the tests' one-agent Kalman filter (tests/support/probe.py) copied into the
test's folder (so it travels to the workers by value), with a host callback the tests steer
through flag files in the scenario's folder: ``pace`` makes every chunk sleep, ``armed`` makes
the next chunk announce its worker's pid and wait to be killed, and the point r = 13.0 raises
(a bad point).
"""

import importlib
import os
import shlex
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any, NamedTuple

import pandas as pd
import pytest
from click.testing import CliRunner

from mcjax.base.interrupt import ACK_DASK
from mcjax.base.parquet import read_table
from mcjax.cli import main
from mcjax.study import check_parts, load_spec, prepare_output, run_sweep

#: The tests' probe scenario, copied next to each spec (its flag files: its docstring).
PROBE = Path(__file__).resolve().parents[1] / "support" / "probe.py"

CLI = [sys.executable, "-m", "mcjax.cli"]
# all on one pytest-xdist worker (pyproject: --dist loadgroup), so the module starts one cluster
pytestmark = pytest.mark.xdist_group("dask")


class Lab(NamedTuple):
    root: Path
    client: Any
    address: str
    good: Path           # 6 points x 100 seeds, 6 chunks of 100 runs (one point each)
    bad: Path            # 4 points, the last one (chunk 3) raises
    spec: Any            # good, loaded
    reference: pd.DataFrame  # good, run locally


def _write(root: Path) -> tuple[Path, Path]:
    shutil.copy(PROBE, root / "probe.py")
    (root / "probe.toml").write_text('scenario = "probe.py:SCENARIO"\n')
    good, bad = root / "good.toml", root / "bad.toml"
    good.write_text('base = "probe.toml"\nseeds = 100\nchunk_size = 100\n[grid]\nr = [0.5, 1.0, 2.0, 4.0, 8.0, 16.0]\n')
    bad.write_text('base = "probe.toml"\nseeds = 100\nchunk_size = 100\n[grid]\nr = [0.5, 1.0, 2.0, 13.0]\n')
    return good, bad


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    distributed = pytest.importorskip("distributed")
    from mcjax.study.dask import local_cluster

    root = tmp_path_factory.mktemp("dask")
    good, bad = _write(root)
    with local_cluster(2) as cluster, distributed.Client(cluster, set_as_default=False) as client:
        # the workers import mcjax while this process computes the reference
        warm = threading.Thread(target=client.run, args=(lambda: importlib.import_module("mcjax.study.dask").__name__,))
        warm.start()
        spec = load_spec(good)
        run_sweep(spec, root / "local")
        warm.join()
        yield Lab(root, client, cluster.scheduler_address, good, bad, spec, read_table(root / "local"))


def _same(out: Path, lab: Lab) -> None:
    pd.testing.assert_frame_equal(read_table(out), lab.reference, check_exact=True)
    assert check_parts(lab.spec, out) == ([], [])  # every part whole, none extra
    assert not (out / "_staging").exists()


def _dask(lab: Lab) -> list[str]:
    return ["--executor", "dask", "--scheduler", lab.address]


def _wait_for(cond, timeout=120.0):
    t0 = time.time()
    while not cond():
        assert time.time() - t0 < timeout, "timed out"
        time.sleep(0.01)


def _parts(out: Path) -> list[Path]:
    return sorted((out / "runs").glob("*/*.parquet"))


def test_same_bytes_as_local_and_one_compilation_per_worker(lab, tmp_path):
    from mcjax.study.dask import DaskExecutor, ship

    for name in ("a", "b"):  # two sweeps of one spec
        run_sweep(lab.spec, tmp_path / name, executor=DaskExecutor(lab.client))
        _same(tmp_path / name, lab)
    # the command line, with another chunk size (chunks of 2 points): the same bytes again
    out = tmp_path / "cli"
    r = CliRunner().invoke(main, ["sweep", str(lab.good), "--out", str(out), "--chunk-size", "200", *_dask(lab)])
    assert r.exit_code == 0, r.output
    pd.testing.assert_frame_equal(read_table(out), lab.reference, check_exact=True)
    assert len(_parts(out)) == 6

    def programs(token):
        from mcjax import engine
        from mcjax.study import dask as cluster

        specs = [s for t, s in cluster.worker_specs().items() if t == token]
        fns = {engine.compiled(s.scenario, s.config) for s in cluster.worker_specs().values()}
        return len(specs), len(fns), sum(len(engine.cached_programs(f)) for f in fns)

    # a worker unpickled the spec at most once and compiled one program for all three sweeps
    counts = lab.client.run(programs, ship(lab.spec).spec_token)
    assert all(specs <= 1 and fns <= 1 and n <= 1 for specs, fns, n in counts.values()), counts
    assert sum(n for _, _, n in counts.values()) >= 1, counts


def test_client_killed_then_resumed_locally(lab, tmp_path):
    out = tmp_path / "out"
    (lab.root / "pace").touch()
    try:
        proc = subprocess.Popen([*CLI, "sweep", str(lab.good), "--out", str(out), *_dask(lab)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        _wait_for(lambda: proc.poll() is not None or _parts(out))
        proc.kill()
        proc.wait()
    finally:
        (lab.root / "pace").unlink()
    assert 1 <= len(_parts(out)) < 6, _parts(out)
    r = CliRunner().invoke(main, ["sweep", str(lab.good), "--out", str(out), "--resume"])
    assert r.exit_code == 0, r.output
    assert "chunk(s) already written" in r.output
    _same(out, lab)


def test_started_locally_ctrl_c_on_dask_then_finished_on_dask(lab, tmp_path, monkeypatch, capfd):
    """Ctrl-C in this process (the command's own handler hears it): the chunks in flight are
    cancelled, exit 130, only whole parts, and the printed resume command finishes the sweep."""
    from mcjax.cli import commands

    monkeypatch.setattr(commands, "exit_now", sys.exit)  # exit 130 without leaving pytest
    out = tmp_path / "out"
    prepare_output(lab.spec, out, spec_file=lab.good)
    run_sweep(lab.spec, out, chunks=[0])  # a local sweep that stopped after one chunk

    def ctrl_c():
        _wait_for(lambda: len(_parts(out)) > 1)
        os.kill(os.getpid(), signal.SIGINT)

    (lab.root / "pace").touch()
    calm = signal.signal(signal.SIGINT, lambda *_: None)  # the command restores this: a late signal lands here
    try:
        thread = threading.Thread(target=ctrl_c, daemon=True)
        thread.start()
        r = CliRunner().invoke(main, ["sweep", str(lab.good), "--out", str(out), "--resume", *_dask(lab)])
        thread.join()
        time.sleep(0.1)
    finally:
        signal.signal(signal.SIGINT, calm)
        (lab.root / "pace").unlink()
    assert r.exit_code == 130, r.output
    assert ACK_DASK in capfd.readouterr().err and "Traceback" not in r.stderr, r.stderr  # said at once, on fd 2
    assert len(_parts(out)) >= 2
    problems = check_parts(lab.spec, out)[1]
    assert all("is missing" in p for p in problems), problems  # only whole parts
    _wait_for(lambda: not lab.client.run_on_scheduler(
        lambda dask_scheduler: [k for k in dask_scheduler.tasks if "mcjax-chunk" in str(k)]), timeout=30)
    hint = next(line for line in r.stderr.splitlines() if "finish with: " in line).split("finish with: ")[1]
    words = shlex.split(hint)
    assert words[-4:] == _dask(lab), words
    r = CliRunner().invoke(main, words[1:])
    assert r.exit_code == 0, r.output
    _same(out, lab)


def test_a_worker_that_raises_names_the_point_and_the_chunk(lab, tmp_path):
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["sweep", str(lab.bad), "--out", str(out), *_dask(lab)])
    assert r.exit_code == 1, r.output
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("error: chunk 3 (runs 300..399; point_id 3: r = 13.0) failed on a Dask worker: "
                               "ValueError: bad point: r = 13.0"), lines[0]
    todo, problems = check_parts(load_spec(lab.bad), out)
    assert 3 in todo and all("is missing" in p for p in problems), problems  # complete parts kept, none damaged
    assert f"{4 - len(todo)} of 4 chunk(s) written" in lines[0] and len(_parts(out)) == 4 - len(todo)
    assert not (out / "_staging").exists()


def test_a_worker_with_other_software_refuses_the_chunk(lab, tmp_path, monkeypatch):
    from mcjax.study import ChunkError
    from mcjax.study import dask as cluster

    monkeypatch.setattr(cluster, "software_fingerprint", lambda: "another mcjax")  # as a client of another version
    with pytest.raises(ChunkError, match=r"^chunk \d .* failed on a Dask worker: RuntimeError: this worker runs "
                                         r"other software than the client"):
        run_sweep(lab.spec, tmp_path / "out", executor=cluster.DaskExecutor(lab.client))
    assert not list((tmp_path / "out").glob("runs/*/*.parquet"))


def test_a_worker_killed_mid_chunk_changes_nothing(lab, tmp_path):
    # last of the tests on the cluster: the worker started in place of the killed one is then never used
    from mcjax.study.dask import DaskExecutor

    killed = []

    def killer():
        _wait_for(lambda: list(lab.root.glob("busy-*")))
        busy = next(lab.root.glob("busy-*"))
        pid = int(busy.name.split("-")[1])
        os.kill(pid, signal.SIGKILL)
        killed.append(pid)
        busy.unlink()

    (lab.root / "armed").touch()
    thread = threading.Thread(target=killer, daemon=True)
    thread.start()
    out = tmp_path / "out"
    run_sweep(lab.spec, out, executor=DaskExecutor(lab.client))
    thread.join(timeout=10)
    assert killed, "no worker was killed"
    _same(out, lab)  # the chunk was run again elsewhere: nothing lost, nothing twice


def test_without_dask_the_dask_executor_says_how_to_install_it(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)  # import distributed now fails
    good, _ = _write(tmp_path)
    r = CliRunner().invoke(main, ["sweep", str(good), "--out", str(tmp_path / "o"), "--executor", "dask",
                                  "--workers", "2"])
    assert r.exit_code == 2
    assert r.output.count("\n") == 1 and 'pip install -e ".[dask]"' in r.output, r.output
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("args, words", [
    (["--scheduler", "tcp://127.0.0.1:8786"], "--scheduler needs --executor dask"),
    (["--workers", "2"], "--workers needs --executor dask"),
    (["--executor", "dask", "--workers", "0"], "--workers must be at least 1"),
    (["--executor", "dask"], "needs --scheduler ADDRESS"),
    (["--executor", "dask", "--workers", "2", "--scheduler", "tcp://127.0.0.1:8786"], "exclude each other"),
])
def test_option_combinations_that_make_no_sense(tmp_path, args, words):
    good, _ = _write(tmp_path)
    r = CliRunner().invoke(main, ["sweep", str(good), "--out", str(tmp_path / "o"), *args])
    assert r.exit_code == 2 and words in r.output and r.output.count("\n") == 1, r.output
    assert not (tmp_path / "o").exists()


def test_a_scheduler_that_cannot_be_reached_is_one_line_and_writes_nothing(tmp_path, monkeypatch):
    import socket

    pytest.importorskip("distributed")
    from mcjax.study import dask as cluster

    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT", 1)
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    good, _ = _write(tmp_path)
    out = tmp_path / "o"
    r = CliRunner().invoke(main, ["sweep", str(good), "--out", str(out), "--executor", "dask",
                                  "--scheduler", f"tcp://127.0.0.1:{port}"])
    assert r.exit_code == 2 and r.output.count("\n") == 1, r.output
    assert r.output.startswith(f"error: cannot reach the Dask scheduler at tcp://127.0.0.1:{port}"), r.output
    assert not out.exists()


def test_faults_are_the_same_on_dask(lab, tmp_path):
    """A sweep with every fault drawn gives on the Dask workers the dataset it gives here."""
    from tests.scenarios.kit.test_faults_tracking import faulty_spec

    spec = faulty_spec(tmp_path)
    for name, extra in (("local", []), ("dask", _dask(lab))):
        r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(tmp_path / name), *extra])
        assert r.exit_code == 0, r.output
    local = read_table(tmp_path / "local")
    assert local.agents_lost.sum() > 0
    pd.testing.assert_frame_equal(read_table(tmp_path / "dask"), local, check_exact=True)


def test_a_check_on_dask_gives_the_local_verdicts(lab, tmp_path):
    """`mcjax check --executor dask`: the sweep folder holds the local sweep's rows, byte for byte, and
    claims.parquet the verdicts of a check in this process."""
    from mcjax.claims.folder import read_verdicts
    from mcjax.claims.runner import run_check

    claims = lab.root / "claims.toml"
    claims.write_text('paper = "probe"\n[sweeps.good]\nspec = "good.toml"\n\n'
                      '[[claim]]\nid = "error-grows-with-r"\nclaim = "the error grows with the noise r"\n'
                      'output = "rmse"\nfilter = "kf"\nrelation = "monotone"\nalong = "r"\n')
    out = tmp_path / "dask"
    r = CliRunner().invoke(main, ["check", str(claims), "--out", str(out), *_dask(lab)])
    assert r.exit_code == 0, r.output
    pd.testing.assert_frame_equal(read_table(out / "good"), lab.reference, check_exact=True)
    run_check(claims, out_dir=tmp_path / "local")
    pd.testing.assert_frame_equal(read_verdicts(out)[0], read_verdicts(tmp_path / "local")[0], check_exact=True)
