"""Tests for mcjax.base.parquet (Parquet layer of a sweep's output folder)."""

from __future__ import annotations

import json
import os

import numpy as np
import pandas as pd
import pyarrow.dataset as pads
import pyarrow.parquet as pq
import pytest

from mcjax.base import parquet
from mcjax.base.provenance import environment_metadata
from mcjax.base.parquet import (
    clean_staging,
    existing_parts,
    read_metadata,
    read_table,
    write_part,
)

FILTERS = ["ekf", "ukf"]


def _part_df(point_id: int, n_seeds: int = 3) -> pd.DataFrame:
    """One part: a tidy table with one row per (seed, filter)."""
    rows = []
    for seed in range(n_seeds):
        for f in FILTERS:
            rows.append(
                {
                    "point_id": point_id,
                    "seed_index": seed,
                    "filter": f,
                    "sigma_r": 0.5 * (point_id + 1),
                    "n_sensors": np.int32(point_id + 2),
                    "rmse": float(point_id * 10 + seed + (0.25 if f == "ukf" else 0.0)),
                    "diverged": bool(seed % 2),
                }
            )
    return pd.DataFrame(rows)


def _expected(point_ids) -> pd.DataFrame:
    df = pd.concat([_part_df(p) for p in point_ids], ignore_index=True)
    return df.sort_values(["point_id", "seed_index", "filter"], kind="stable").reset_index(drop=True)


def _sorted(df: pd.DataFrame) -> pd.DataFrame:
    return df.sort_values(["point_id", "seed_index", "filter"], kind="stable").reset_index(drop=True)


def _write_three(out) -> None:
    # written out of order on purpose: read_table must sort
    for p in (2, 0, 1):
        write_part(out, "runs", _part_df(p), f"part-{p:06d}", {"config": {"point": p}})


def test_hive_partitioned_round_trip(tmp_path):
    # two chunks, the second straddling points 1 and 2: one file per (point, chunk)
    for chunk, points in ((0, (0, 1)), (1, (1, 2))):
        for p in points:
            write_part(tmp_path, "runs", _part_df(p), f"part-{chunk:06d}", {}, partition={"point_id": p})
    assert existing_parts(tmp_path, "runs") == ["point_id=0/part-000000", "point_id=1/part-000000",
                                                "point_id=1/part-000001", "point_id=2/part-000001"]
    assert "point_id" not in pq.read_schema(tmp_path / "runs" / "point_id=0" / "part-000000.parquet").names
    expected = _sorted(pd.concat([_part_df(p) for p in (0, 1, 1, 2)], ignore_index=True))
    got = read_table(tmp_path)
    assert got["point_id"].dtype == np.int64
    pd.testing.assert_frame_equal(got[expected.columns], expected)
    arrow = pads.dataset(tmp_path / "runs", partitioning="hive").to_table().to_pandas()
    assert sorted(arrow["point_id"].astype(int)) == sorted(expected["point_id"])
    with pytest.raises(ValueError, match="partition"):
        write_part(tmp_path, "runs", _part_df(0), "part-000009", {}, partition={"point_id": "../x"})


def test_round_trip_three_readers(tmp_path):
    _write_three(tmp_path)
    expected = _expected([0, 1, 2])

    got = read_table(tmp_path)
    pd.testing.assert_frame_equal(got, expected)

    via_pandas = _sorted(pd.read_parquet(tmp_path / "runs"))
    pd.testing.assert_frame_equal(via_pandas, expected)

    via_arrow = _sorted(pads.dataset(tmp_path / "runs", format="parquet").to_table().to_pandas())
    pd.testing.assert_frame_equal(via_arrow, expected)

    assert list(got.dtypes) == list(_part_df(0).dtypes)
    assert got["n_sensors"].dtype == np.int32
    assert existing_parts(tmp_path, "runs") == ["part-000000", "part-000001", "part-000002"]


def test_files_are_zstd_and_keep_key_columns(tmp_path):
    path = write_part(tmp_path, "runs", _part_df(0), "part-000000", {})
    assert path == tmp_path / "runs" / "part-000000.parquet"
    md = pq.ParquetFile(path).metadata
    assert md.row_group(0).column(0).compression.upper() == "ZSTD"
    names = set(pq.read_schema(path).names)
    assert {"point_id", "seed_index", "filter", "sigma_r"} <= names


def test_metadata_round_trip_keeps_pandas_metadata(tmp_path):
    meta = {
        "config": {"model": "cv", "dt": 0.1, "filters": FILTERS, "nested": {"a": [1, 2]}},
        "n_runs": 6,
        "note": None,
        "environment": environment_metadata(),
    }
    write_part(tmp_path, "runs", _part_df(0), "part-000000", meta)
    assert read_metadata(tmp_path) == json.loads(json.dumps(meta))
    raw = pq.read_schema(tmp_path / "runs" / "part-000000.parquet").metadata
    assert b"pandas" in raw
    assert raw[b"mcjax.n_runs"] == b"6"
    assert json.loads(raw[b"mcjax.config"])["model"] == "cv"


def test_read_metadata_uses_first_part(tmp_path):
    _write_three(tmp_path)
    assert read_metadata(tmp_path) == {"config": {"point": 0}}


def test_empty_output_folder(tmp_path):
    df = read_table(tmp_path)
    assert isinstance(df, pd.DataFrame) and df.empty
    assert read_metadata(tmp_path) == {}
    assert existing_parts(tmp_path, "runs") == []
    assert clean_staging(tmp_path) == 0


def test_no_leftovers_after_successful_writes(tmp_path):
    _write_three(tmp_path)
    write_part(tmp_path, "timeseries", _part_df(0), "part-000000")
    staging = tmp_path / parquet.STAGING_DIR
    assert not staging.exists() or list(staging.iterdir()) == []
    for table in ("runs", "timeseries"):
        entries = list((tmp_path / table).iterdir())
        assert entries and all(e.is_file() and e.suffix == ".parquet" for e in entries)
        assert not any(e.name.startswith((".", "_")) for e in entries)
    # staging folder is a sibling of the dataset folders, never inside them
    assert set(p.name for p in tmp_path.iterdir()) <= {"runs", "timeseries", parquet.STAGING_DIR}


def test_interrupted_replace_leaves_dataset_untouched(tmp_path, monkeypatch):
    _write_three(tmp_path)
    before = sorted(p.name for p in (tmp_path / "runs").iterdir())

    def boom(src, dst):
        raise OSError("simulated crash during rename")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError, match="simulated crash"):
        write_part(tmp_path, "runs", _part_df(3), "part-000003", {"config": {}})
    # overwriting an existing part that fails must leave the old one intact too
    with pytest.raises(OSError, match="simulated crash"):
        write_part(tmp_path, "runs", _part_df(9), "part-000001", {"config": {}})
    monkeypatch.undo()

    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == before
    pd.testing.assert_frame_equal(read_table(tmp_path), _expected([0, 1, 2]))
    pd.testing.assert_frame_equal(_sorted(pd.read_parquet(tmp_path / "runs")), _expected([0, 1, 2]))
    staging = tmp_path / parquet.STAGING_DIR
    assert not staging.exists() or list(staging.iterdir()) == []


def test_interrupted_parquet_write_leaves_dataset_untouched(tmp_path, monkeypatch):
    _write_three(tmp_path)
    real_write = pq.write_table

    def torn_write(table, where, **kwargs):
        assert os.path.dirname(where.name) == str(tmp_path / parquet.STAGING_DIR)  # never inside runs/
        where.write(b"PAR1 half a file")
        raise KeyboardInterrupt

    monkeypatch.setattr(parquet.pq, "write_table", torn_write)
    with pytest.raises(KeyboardInterrupt):
        write_part(tmp_path, "runs", _part_df(3), "part-000003")
    monkeypatch.setattr(parquet.pq, "write_table", real_write)

    assert existing_parts(tmp_path, "runs") == ["part-000000", "part-000001", "part-000002"]
    pd.testing.assert_frame_equal(read_table(tmp_path), _expected([0, 1, 2]))


def test_killed_writer_leftover_is_ignored_and_cleaned(tmp_path):
    _write_three(tmp_path)
    # a process killed mid-write leaves a torn file in staging (outside runs/)
    staging = tmp_path / parquet.STAGING_DIR
    staging.mkdir(exist_ok=True)
    (staging / "runs.part-000003.123.deadbeef.tmp").write_bytes(b"PAR1 torn")
    (staging / ".part-000004.parquet.123.0123456789ab.tmp").write_bytes(b"PAR1 torn")  # files.atomic_write's name

    pd.testing.assert_frame_equal(read_table(tmp_path), _expected([0, 1, 2]))
    pd.testing.assert_frame_equal(_sorted(pd.read_parquet(tmp_path / "runs")), _expected([0, 1, 2]))
    assert clean_staging(tmp_path) == 2
    assert not staging.exists() or list(staging.iterdir()) == []
    pd.testing.assert_frame_equal(read_table(tmp_path), _expected([0, 1, 2]))


def test_overwrite_is_idempotent(tmp_path):
    _write_three(tmp_path)
    write_part(tmp_path, "runs", _part_df(1), "part-000001", {"config": {"point": 1}})
    write_part(tmp_path, "runs", _part_df(1), "part-000001", {"config": {"point": 1}})
    assert existing_parts(tmp_path, "runs") == ["part-000000", "part-000001", "part-000002"]
    pd.testing.assert_frame_equal(read_table(tmp_path), _expected([0, 1, 2]))

    # a different payload replaces the part entirely (no duplicated rows)
    changed = _part_df(1).assign(rmse=-1.0)
    write_part(tmp_path, "runs", changed, "part-000001", {"config": {"point": "new"}})
    got = read_table(tmp_path)
    assert len(got) == len(_expected([0, 1, 2]))
    assert (got.loc[got.point_id == 1, "rmse"] == -1.0).all()
    meta = pq.read_schema(tmp_path / "runs" / "part-000001.parquet").metadata
    assert json.loads(meta[b"mcjax.config"]) == {"point": "new"}


@pytest.mark.parametrize(
    "bad", ["a/b", "a\\b", "../x", "..", ".", "", ".hidden", "_tmp", "part-1.parquet", "x y"]
)
def test_bad_part_name_raises(tmp_path, bad):
    with pytest.raises(ValueError, match="part_name"):
        write_part(tmp_path, "runs", _part_df(0), bad)
    assert not (tmp_path / "runs").exists() or existing_parts(tmp_path, "runs") == []


def test_bad_arguments_name_the_argument(tmp_path):
    with pytest.raises(TypeError, match="part_name"):
        write_part(tmp_path, "runs", _part_df(0), 12)
    with pytest.raises(ValueError, match="table_name"):
        write_part(tmp_path, "../runs", _part_df(0), "part-0")
    with pytest.raises(ValueError, match="table_name"):
        write_part(tmp_path, parquet.STAGING_DIR, _part_df(0), "part-0")
    with pytest.raises(TypeError, match="df"):
        write_part(tmp_path, "runs", [1, 2], "part-0")
    with pytest.raises(TypeError, match="metadata"):
        write_part(tmp_path, "runs", _part_df(0), "part-0", {"x": object()})
    with pytest.raises(TypeError, match="metadata"):
        write_part(tmp_path, "runs", _part_df(0), "part-0", ["not", "a", "dict"])
    with pytest.raises(ValueError, match="metadata"):
        write_part(tmp_path, "runs", _part_df(0), "part-0", {1: "x"})
    with pytest.raises(TypeError, match="out_dir"):
        write_part(None, "runs", _part_df(0), "part-0")


def test_read_table_sorts_by_present_keys_and_unifies_schemas(tmp_path):
    a = pd.DataFrame({"seed_index": [2, 0], "x": [1.0, 2.0]})
    b = pd.DataFrame({"seed_index": [1], "x": [3.0], "extra": ["only here"]})
    write_part(tmp_path, "timeseries", a, "part-a")
    write_part(tmp_path, "timeseries", b, "part-b")
    got = read_table(tmp_path, "timeseries")
    assert got["seed_index"].tolist() == [0, 1, 2]
    assert got["x"].tolist() == [2.0, 3.0, 1.0]
    assert got["extra"].isna().tolist() == [True, False, True]
    assert list(got.index) == [0, 1, 2]


def test_named_index_becomes_column(tmp_path):
    df = _part_df(0).set_index("point_id")
    write_part(tmp_path, "runs", df, "part-000000")
    got = read_table(tmp_path)
    assert "point_id" in got.columns
    assert isinstance(got.index, pd.RangeIndex)


def test_environment_metadata():
    env = environment_metadata()
    for key in ("python", "jax", "jaxlib", "numpy", "pandas", "pyarrow", "optax", "mcjax",
                "git_revision", "created_utc"):
        assert isinstance(env[key], str) and env[key], key
    assert env["pandas"] == pd.__version__
    assert env["numpy"] == np.__version__
    if "git_dirty" in env:
        assert isinstance(env["git_dirty"], bool)
    created = pd.Timestamp(env["created_utc"])
    assert created.tzinfo is not None
    json.dumps(env)  # usable as write_part metadata
