"""Stage 3, executing (mcjax.study.execute): the chunks computed in this process, each published
as one part per point it touches, the progress told in runs, a stop honoured after a chunk and a
part that cannot be written ending the sweep with WriteError and nothing partial."""

from __future__ import annotations

import errno
from pathlib import Path

import pandas as pd
import pytest

from mcjax.base import parquet
from mcjax.study import LocalExecutor, build_spec, chunk_rows, run_sweep
from mcjax.study.execute import WriteError

ROOT = Path(__file__).resolve().parents[2]
WIND = str(ROOT / "configs" / "chen2013.toml")


@pytest.fixture(scope="module")
def study():
    """2 points x 150 seeds of a 3-step wind_formation run, chunks of 100 runs (3 chunks; chunk 1
    holds runs of both points)."""
    s = build_spec({"base": WIND, "config": {"n_steps": 3, "warmup_steps": 0}, "grid": {"eta": [0.0, 0.01]}},
                   ROOT, seeds=150, chunk_size=100)
    assert len(s.plan) == 3
    return s


def _parts(out: Path) -> list[str]:
    return sorted(str(p.relative_to(out)) for p in (out / "runs").rglob("*.parquet"))


def test_a_chunk_is_one_part_per_point_it_touches_and_progress_counts_its_runs(study, tmp_path):
    told = []
    rows = run_sweep(study, tmp_path, progress=told.append)
    assert told == [b - a for a, b in study.plan] and sum(told) == study.n_runs
    assert _parts(tmp_path) == ["runs/point_id=0/part-000000.parquet", "runs/point_id=0/part-000001.parquet",
                                "runs/point_id=1/part-000001.parquet", "runs/point_id=1/part-000002.parquet"]
    assert len(rows) == study.n_runs * len(study.config.filters)
    back = parquet.read_table(tmp_path, "runs")
    order = ["point_id", "seed_index", "filter"]
    pd.testing.assert_frame_equal(back[rows.columns].sort_values(order).reset_index(drop=True),
                                  rows.sort_values(order).reset_index(drop=True), check_dtype=False,
                                  check_categorical=False)


def test_chunks_computed_alone_are_the_rows_of_the_whole_sweep(study):
    whole = run_sweep(study)  # no output folder: nothing written
    alone = {c.index: c for c in chunk_rows(study, [2, 0])}
    assert sorted(alone) == [0, 2] and (alone[2].start, alone[2].stop) == study.plan[2]
    F = len(study.config.filters)
    for i in (0, 2):
        a, b = study.plan[i]
        pd.testing.assert_frame_equal(alone[i].runs.reset_index(drop=True),
                                      whole.iloc[a * F:b * F].reset_index(drop=True))


def test_should_stop_is_asked_before_the_first_chunk_and_after_each(study, tmp_path):
    assert list(LocalExecutor().map_chunks(study, [0, 1, 2], lambda: True)) == []
    told = []
    rows = run_sweep(study, tmp_path, progress=told.append, should_stop=lambda: len(told) == 1)
    assert told == [100] and _parts(tmp_path) == ["runs/point_id=0/part-000000.parquet"]
    assert len(rows) == 100 * len(study.config.filters)
    assert not (tmp_path / parquet.STAGING_DIR).exists()


def test_a_part_that_cannot_be_written_is_a_write_error_with_nothing_partial(study, tmp_path, monkeypatch):
    real = parquet.pq.write_table
    calls = []

    def full(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(*args, **kwargs)

    monkeypatch.setattr(parquet.pq, "write_table", full)
    with pytest.raises(WriteError, match="chunk 1 failed: No space left on device.*--resume"):
        run_sweep(study, tmp_path)
    assert _parts(tmp_path) == ["runs/point_id=0/part-000000.parquet"]  # chunk 0 whole; chunk 1 none of its parts
    assert not (tmp_path / parquet.STAGING_DIR).exists()
