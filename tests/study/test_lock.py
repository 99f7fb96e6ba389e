"""One writer per output folder (mcjax.study.lock): two sweeps on one folder → one runs, the
other exits 2 naming the holder; a lock left by a process that is gone is taken over with a
warning; --resume and --force respect the lock; the lock goes when the command ends."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
from click.testing import CliRunner

from mcjax.base.parquet import read_table
from mcjax.cli import main
from mcjax.study import lock

#: The tests' probe scenario (flag files: ``slow`` holds every chunk, ``pace`` slows it), copied next to each spec.
PROBE = Path(__file__).resolve().parents[1] / "support" / "probe.py"


def write_probe(root: Path) -> Path:
    """A 3-point sweep of the probe scenario, one chunk per point; returns the spec."""
    shutil.copy(PROBE, root / "probe.py")
    (root / "probe.toml").write_text('scenario = "probe.py:SCENARIO"\n')
    spec = root / "sweep.toml"
    spec.write_text('base = "probe.toml"\nseeds = 100\nchunk_size = 100\n[grid]\nr = [0.5, 1.0, 2.0]\n')
    return spec


@pytest.fixture
def probe(tmp_path):
    return write_probe(tmp_path)


def _plant(out: Path, **info) -> Path:
    out.mkdir(parents=True, exist_ok=True)
    path = out / lock.LOCK_FILE
    path.write_text(json.dumps({"host": socket.gethostname(), "pid": os.getpid(), "time": time.time(),
                                "command": "mcjax sweep other.toml", "token": "t", **info}))
    return path


def _gone_pid() -> int:
    done = subprocess.run(["true"])  # a process that has ended: its pid is free
    p = subprocess.Popen(["true"])
    p.wait()
    assert done.returncode == 0
    return p.pid


def test_a_held_folder_refuses_a_second_holder_and_is_free_after(tmp_path):
    out = tmp_path / "out"
    with lock.hold(out) as held:
        assert (out / lock.LOCK_FILE).is_file() and held is not None
        with pytest.raises(lock.LockError, match=f"in use by .*pid {os.getpid()} on {socket.gethostname()}"):
            with lock.hold(out):
                pass
        assert (out / lock.LOCK_FILE).is_file()  # the refused one did not remove it
    assert not out.exists()  # the lock made the folder, and it is empty: gone with the lock


@pytest.mark.parametrize("case", ["pid_gone", "pid_reused", "other_host_old", "unreadable_old"])
def test_a_lock_left_behind_is_taken_over_with_a_warning(tmp_path, case):
    out = tmp_path / "out"
    if case == "pid_gone":
        path = _plant(out, pid=_gone_pid())
    elif case == "pid_reused":
        path = _plant(out, start="1")  # this process, but one started at another time
    elif case == "other_host_old":
        path = _plant(out, host="elsewhere.example")
        os.utime(path, (time.time() - lock.STALE_AFTER - 5,) * 2)
    else:
        path = out / lock.LOCK_FILE
        out.mkdir()
        path.write_text("{not json")
        os.utime(path, (time.time() - lock.HEARTBEAT - 5,) * 2)
    said = []
    with lock.hold(out, warn=said.append):
        assert json.loads(path.read_text())["pid"] == os.getpid()
    assert len(said) == 1 and said[0].startswith(f"taking over the lock of {out}")
    assert not path.exists()


@pytest.mark.parametrize("case", ["other_host_fresh", "pid_alive"])
def test_a_live_lock_is_respected(tmp_path, case):
    out = tmp_path / "out"
    if case == "other_host_fresh":
        _plant(out, host="elsewhere.example", pid=1)
    else:
        _plant(out, pid=os.getppid())
    with pytest.raises(lock.LockError, match="in use by mcjax sweep other.toml"):
        with lock.hold(out):
            pass
    assert (out / lock.LOCK_FILE).is_file()


def test_two_sweeps_on_one_folder_one_runs_the_other_exits_2(probe, tmp_path):
    out = tmp_path / "out"
    slow = probe.with_name("slow")
    slow.touch()
    first = subprocess.Popen([sys.executable, "-m", "mcjax.cli", "sweep", str(probe), "--out", str(out)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        t0 = time.time()
        while not (out / lock.LOCK_FILE).exists():
            assert first.poll() is None and time.time() - t0 < 120, first.communicate()
            time.sleep(0.05)
        for args in ([], ["--resume"], ["--force"]):  # --resume and --force respect it too
            r = CliRunner().invoke(main, ["sweep", str(probe), "--out", str(out), *args])
            assert r.exit_code == 2, r.output
            lines = [line for line in r.output.splitlines() if line.strip()]
            assert len(lines) == 1 and f"pid {first.pid} on {socket.gethostname()}" in lines[0], lines
            assert "mcjax sweep" in lines[0] and "in use by" in lines[0]
    finally:
        slow.unlink()
    stdout, stderr = first.communicate(timeout=300)
    assert first.returncode == 0, stderr
    assert not (out / lock.LOCK_FILE).exists()  # released at the end
    assert len(read_table(out)) == 300


def test_a_tune_respects_the_lock(tmp_path):
    out = tmp_path / "out"
    _plant(out, pid=os.getppid())
    spec = Path(__file__).resolve().parents[2] / "sweeps" / "tune_chen2013.toml"
    r = CliRunner().invoke(main, ["tune", str(spec), "--out", str(out)])
    assert r.exit_code == 2 and "error: output folder" in r.output and "in use by mcjax sweep other.toml" in r.output
    assert sorted(p.name for p in out.iterdir()) == [lock.LOCK_FILE]  # nothing written


def test_a_sweep_takes_over_a_lock_left_by_a_killed_one_and_force_keeps_its_own(probe, tmp_path):
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["sweep", str(probe), "--out", str(out)])
    assert r.exit_code == 0, r.output
    reference = read_table(out)
    _plant(out, pid=_gone_pid())  # as a kill -9 leaves it
    r = CliRunner().invoke(main, ["sweep", str(probe), "--out", str(out), "--resume"])
    assert r.exit_code == 0, r.output
    assert "warning: taking over the lock of" in r.output and "no longer runs" in r.output
    assert f"scenario probe (imported from {probe.with_name('probe.py')}): 3 point(s)" in r.output
    _plant(out, pid=_gone_pid())
    r = CliRunner().invoke(main, ["sweep", str(probe), "--out", str(out), "--force"])
    assert r.exit_code == 0, r.output
    pd.testing.assert_frame_equal(read_table(out), reference, check_exact=True)
    assert not (out / lock.LOCK_FILE).exists()


@pytest.mark.parametrize("presses", [1, 2])
def test_the_lock_goes_on_ctrl_c_once_or_twice(probe, tmp_path, presses):
    """The first Ctrl-C stops after the chunk in flight, the second at once (os._exit, which
    skips every `finally`): the lock goes either way (mcjax.base.interrupt.AT_EXIT)."""
    import signal

    out = tmp_path / "out"
    slow = probe.with_name("slow")
    slow.touch()
    proc = subprocess.Popen([sys.executable, "-m", "mcjax.cli", "sweep", str(probe), "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        t0 = time.time()
        while not (out / lock.LOCK_FILE).exists():
            assert proc.poll() is None and time.time() - t0 < 120, proc.communicate()
            time.sleep(0.05)
        time.sleep(0.5)  # in the first chunk, held by the flag file
        proc.send_signal(signal.SIGINT)
        time.sleep(0.5)
        if presses == 2:
            proc.send_signal(signal.SIGINT)
        else:
            slow.unlink()  # the chunk in flight ends
        _, stderr = proc.communicate(timeout=120)
    finally:
        slow.unlink(missing_ok=True)
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, stderr
    assert "--resume" in stderr.strip().splitlines()[-1]
    assert not (out / lock.LOCK_FILE).exists()
