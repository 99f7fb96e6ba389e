"""A full disk in the middle of a sweep: the k-th part's write fails with ENOSPC after writing
half its bytes (the Parquet writer is replaced by one that does so). The sweep stops with one
line (what failed, how much was written, how to resume), exit 1; no partial part is visible;
--resume completes a dataset bit-identical to an uninterrupted sweep's."""

from __future__ import annotations

import errno
import io

import pandas as pd
import pytest
from click.testing import CliRunner

from mcjax.base import parquet
from mcjax.base.parquet import read_table
from mcjax.cli import main
from mcjax.study import check_parts, load_spec
from tests.study.test_lock import write_probe


@pytest.fixture(scope="module")
def probe(tmp_path_factory):
    root = tmp_path_factory.mktemp("full_disk")
    spec = write_probe(root)
    spec.write_text('base = "probe.toml"\nseeds = 100\nchunk_size = 100\n[grid]\nr = [0.5, 1.0, 2.0, 4.0, 8.0]\n')
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(root / "reference")])
    assert r.exit_code == 0, r.output
    return spec, read_table(root / "reference")


def _full_after(monkeypatch, k: int) -> list:
    """From the k-th part on (1-based), every write fails half-way with ENOSPC."""
    real = parquet.pq.write_table
    calls = []

    def write_table(table, where, **kwargs):
        calls.append(1)
        if len(calls) < k:
            return real(table, where, **kwargs)
        buffer = io.BytesIO()
        real(table, buffer, **kwargs)
        where.write(buffer.getvalue()[: len(buffer.getvalue()) // 2])  # the disk fills half-way
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(parquet.pq, "write_table", write_table)
    return calls


@pytest.mark.parametrize("k", [1, 3])
def test_enospc_on_the_kth_part_stops_cleanly_and_resume_is_bit_identical(probe, tmp_path, monkeypatch, k):
    spec, reference = probe
    out = tmp_path / "out"
    with monkeypatch.context() as m:
        calls = _full_after(m, k)
        r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out)])
    assert r.exit_code == 1, r.output
    assert len(calls) == k  # stopped at the first failure
    errors = [line for line in r.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and r.output.count("error") == 1, r.output
    line = errors[0]
    assert f"chunk {k - 1} failed: No space left on device" in line and "--resume" in line
    assert f"{k - 1} of 5 chunk(s) written to {out}" in line
    # no partial part: the parts there are whole, the missing ones are missing, no staging file
    todo, problems = check_parts(load_spec(spec), out)
    assert todo == list(range(k - 1, 5)) and all("missing" in p for p in problems), problems
    assert not list(out.rglob("*.tmp")) and not (out / parquet.STAGING_DIR).exists()
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out), "--resume"])
    assert r.exit_code == 0, r.output
    assert f"resuming: {k - 1} of 5 chunk(s) already written" in r.output
    pd.testing.assert_frame_equal(read_table(out), reference, check_exact=True)


@pytest.mark.parametrize("failure", ["trace", "evaluation part"])
def test_a_full_disk_ends_a_tune_with_one_line_and_frees_the_folder(tmp_path, monkeypatch, failure):
    """mcjax tune: an OSError while saving its trace or state, or a part of its held-out
    evaluation that cannot be written (the sweep's WriteError), ends the command with exit 1 and
    one line saying what failed and to --resume — no traceback — and the folder's lock is gone."""
    from mcjax import tune
    from mcjax.study.execute import WriteError
    from mcjax.study.lock import LOCK_FILE
    from tests.tune.test_tune import SPEC, _write

    out = tmp_path / "out"

    def full(spec, out_dir, **kwargs):
        if failure == "trace":
            raise OSError(errno.ENOSPC, "No space left on device", str(out_dir / tune.TRACE_FILE))
        raise WriteError("writing the parts of chunk 1 failed: No space left on device; no partial part is "
                         "left; once there is room, finish with --resume")

    from mcjax.tune import runner

    monkeypatch.setattr(runner, "optimise", full)  # where the tune runner calls it
    r = CliRunner().invoke(main, ["tune", str(_write(tmp_path, SPEC)), "--out", str(out)])
    assert r.exit_code == 1, r.output
    errors = [line for line in r.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "Traceback" not in r.output, r.output
    assert "No space left on device" in errors[0] and "--resume" in errors[0]
    assert (failure == "trace") == (tune.TRACE_FILE in errors[0])
    assert not (out / LOCK_FILE).exists()
