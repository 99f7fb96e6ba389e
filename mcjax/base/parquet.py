"""Parquet layer of a sweep's output folder.

Layout of an output folder ``OUT``::

    OUT/
      runs/                 dataset: one row per (run, filter), tidy, hive-partitioned
        point_id=0/part-000000.parquet     (chunk 0's runs of point 0)
        point_id=1/part-000000.parquet
        point_id=1/part-000001.parquet
      timeseries/           optional second dataset (one row per run, step and filter), same rules
      _staging/             temporary files only (never read as data)

Rules:

* Every dataset folder (``runs/``, ``timeseries/``, ...) contains **only** finished
  ``<part_name>.parquet`` files.  Temporary files live in ``OUT/_staging/``, which is a
  *sibling* of the dataset folders: DuckDB and Polars globs (``runs/**/*.parquet``) also
  read hidden folders, so a temporary file inside ``runs/`` could be picked up half written.
* A part is written to ``OUT/_staging/`` first, flushed to disk, then moved into place with
  :func:`os.replace` (atomic on the same file system; :func:`mcjax.base.files.atomic_write`).
  A reader therefore sees either the old part, the new part, or no part, never a torn file.
  An interrupted writer leaves at most a file in ``OUT/_staging/`` (removed by
  :func:`clean_staging`).
* A dataset may be hive-partitioned: a part written with ``partition={"point_id": 3}``
  lands in ``<table>/point_id=3/`` and its ``point_id`` column lives in the folder name,
  not the file (``pd.read_parquet("OUT/runs")`` and
  ``pyarrow.dataset.dataset("OUT/runs", partitioning="hive")`` both restore it; pandas
  reads it as a categorical). The other key columns (``seed_index``, ``filter``, swept
  parameters) are ordinary columns. :func:`read_table` reads the folder names with
  :mod:`pyarrow.dataset`'s hive partitioning and returns the keys as ordinary integer
  columns. Parts are written one file at a time (:func:`write_part`), not with
  ``pyarrow.dataset.write_dataset``, which writes in place (no staging and rename) and
  names files by its own template. Unpartitioned parts (``<table>/<part>.parquet``) are
  read too.
* Run-level metadata (config, environment, ...) is stored in the Parquet schema metadata
  as JSON strings under keys ``mcjax.<key>``; pandas' own ``pandas`` key is kept so dtypes
  round-trip.
* Files are compressed with zstd.

This module does not import JAX.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Any, Mapping

import pandas as pd
import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq
from pyarrow import fs as pafs

from mcjax.base.files import atomic_write

__all__ = [
    "STAGING_DIR",
    "METADATA_PREFIX",
    "SORT_COLUMNS",
    "COMPRESSION",
    "write_part",
    "existing_parts",
    "read_table",
    "read_metadata",
    "clean_staging",
    "remove_empty_staging",
    "part_problem",
    "remove_part",
    "DamagedPartError",
]

#: Name of the staging folder (a sibling of the dataset folders, never inside them).
STAGING_DIR = "_staging"
#: Prefix of mcjax keys in the Parquet schema metadata.
METADATA_PREFIX = "mcjax."
#: Columns used (when present, in this order) to sort rows returned by :func:`read_table`.
SORT_COLUMNS = ("point_id", "seed_index", "filter")
#: Parquet compression codec of every part file.
COMPRESSION = "zstd"

_PARQUET_SUFFIX = ".parquet"
# Names of parts and tables: one path component, no separators, not hidden ('.' / '_'
# prefixes are skipped by pyarrow/pandas dataset discovery), portable characters only.
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")



# --------------------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------------------


def _check_name(value: Any, arg: str) -> str:
    """Validate a single path component used as a file or folder name."""
    if not isinstance(value, str):
        raise TypeError(f"{arg} must be a str, got {type(value).__name__}")
    if not _NAME_RE.fullmatch(value) or value in (".", ".."):
        raise ValueError(
            f"{arg}={value!r} is invalid: it must be a single file name (no path separators "
            "such as '/' or '\\'), start with a letter or digit and contain only letters, "
            "digits, '.', '_' and '-'"
        )
    if value.endswith(_PARQUET_SUFFIX):
        raise ValueError(
            f"{arg}={value!r} must not end with {_PARQUET_SUFFIX!r} (the suffix is added "
            f"automatically; pass {value[: -len(_PARQUET_SUFFIX)]!r})"
        )
    return value


def _check_out_dir(out_dir: Any) -> Path:
    if not isinstance(out_dir, (str, os.PathLike)):
        raise TypeError(f"out_dir must be a str or os.PathLike, got {type(out_dir).__name__}")
    path = Path(out_dir)
    if str(out_dir) == "":
        raise ValueError("out_dir must not be empty")
    return path


def _encode_metadata(metadata: Mapping[str, Any] | None) -> dict[bytes, bytes]:
    """Encode ``metadata`` as ``{b'mcjax.<key>': b'<json>'}``."""
    if metadata is None:
        return {}
    if not isinstance(metadata, Mapping):
        raise TypeError(f"metadata must be a dict (str -> JSON value), got {type(metadata).__name__}")
    encoded: dict[bytes, bytes] = {}
    for key, value in metadata.items():
        if not isinstance(key, str) or not key:
            raise ValueError(f"metadata keys must be non-empty str, got {key!r}")
        try:
            text = json.dumps(value)  # key order kept: a spec's grid axes are in the order written
        except (TypeError, ValueError) as exc:
            raise TypeError(
                f"metadata[{key!r}] is not JSON-serialisable ({type(value).__name__}): {exc}"
            ) from exc
        encoded[(METADATA_PREFIX + key).encode()] = text.encode()
    return encoded


def _decode_metadata(raw: Mapping[bytes, bytes] | None) -> dict[str, Any]:
    out: dict[str, Any] = {}
    prefix = METADATA_PREFIX.encode()
    for key, value in (raw or {}).items():
        if key.startswith(prefix):
            out[key[len(prefix):].decode()] = json.loads(value.decode())
    return out


class DamagedPartError(ValueError):
    """A part file cannot be read (truncated, empty, not Parquet); the message names it."""


def _damaged(out: Path, path: Path, exc: BaseException) -> DamagedPartError:
    text = " ".join(str(exc).split())[:200]
    return DamagedPartError(f"{path.relative_to(out) if out in path.parents else path} is damaged "
                            f"({type(exc).__name__}: {text}); repair the dataset with `mcjax sweep SPEC --out "
                            f"{out} --resume`")


_READ_ERRORS = (pa.ArrowException, OSError, ValueError, KeyError, UnicodeDecodeError)


def _part_files(out_dir: Path, table_name: str) -> list[Path]:
    return [out_dir / table_name / f"{name}{_PARQUET_SUFFIX}" for name in existing_parts(out_dir, table_name)]


# --------------------------------------------------------------------------------------
# public API
# --------------------------------------------------------------------------------------


def write_part(
    out_dir: str | os.PathLike,
    table_name: str,
    df: pd.DataFrame,
    part_name: str,
    metadata: Mapping[str, Any] | None = None,
    partition: Mapping[str, int] | None = None,
) -> Path:
    """Atomically write ``df`` as ``OUT/<table_name>/<part_name>.parquet``; return its path.

    With ``partition={"point_id": 3}`` the file goes to
    ``OUT/<table_name>/point_id=3/<part_name>.parquet`` (hive layout) and the partition
    columns are dropped from the file (the folder name carries them).

    Steps: convert ``df`` to a :class:`pyarrow.Table` (the pandas index is dropped, except
    that *named* index levels are first turned into ordinary columns); add ``metadata`` to
    the schema metadata (each value JSON-encoded under ``mcjax.<key>``, pandas' own
    ``pandas`` key kept); write it zstd-compressed to a uniquely named file in
    ``OUT/_staging/``; fsync; then :func:`os.replace` it onto the final path
    (:func:`mcjax.base.files.atomic_write`).

    * Readers never see a partial file; if the process dies mid-write only a staging file
      remains (see :func:`clean_staging`).  If the write fails with an exception the
      staging file is removed and the exception re-raised; the dataset is unchanged.
    * If the part already exists it is replaced atomically, so re-writing a part (e.g. on
      resume) is idempotent.
    * Choosing unique part names (e.g. ``part-000012``) is the caller's job.

    Args:
        out_dir: output folder ``OUT`` (created if missing).
        table_name: dataset folder name, e.g. ``"runs"`` or ``"timeseries"``.
        df: tidy table to write; keep key columns (``point_id``, ``seed_index``,
            ``filter``, swept parameters) as ordinary columns.
        part_name: file stem, a single path component without ``.parquet``.
        metadata: ``str -> JSON-serialisable`` mapping, or ``None``.

    Raises:
        TypeError / ValueError naming the offending argument for bad input.
    """
    out = _check_out_dir(out_dir)
    _check_name(table_name, "table_name")
    _check_name(part_name, "part_name")
    if not isinstance(df, pd.DataFrame):
        raise TypeError(f"df must be a pandas DataFrame, got {type(df).__name__}")
    extra = _encode_metadata(metadata)

    frame = df
    if any(name is not None for name in frame.index.names):
        frame = frame.reset_index()
    subdir = ""
    for key, value in (partition or {}).items():
        _check_name(key, "partition key")
        if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]*", str(value)):
            raise ValueError(f"partition value {key}={value!r} must be a single path component of "
                             "letters, digits, '.', '_' and '-'")
        subdir = f"{subdir}{key}={value}/"
        frame = frame.drop(columns=[key], errors="ignore")
    try:
        table = pa.Table.from_pandas(frame, preserve_index=False)
    except (pa.ArrowException, TypeError, ValueError) as exc:
        raise TypeError(f"df cannot be converted to a pyarrow Table: {exc}") from exc
    table = table.replace_schema_metadata({**(table.schema.metadata or {}), **extra})

    final_dir = out / table_name / subdir
    final_dir.mkdir(parents=True, exist_ok=True)

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            pq.write_table(table, fh, compression=COMPRESSION)

    return atomic_write(final_dir / f"{part_name}{_PARQUET_SUFFIX}", write, staging=out / STAGING_DIR)


def _scan_parts(folder: Path, prefix: str = "") -> list[str]:
    names = []
    for entry in os.scandir(folder):
        if entry.name.startswith((".", "_")):
            continue
        if entry.is_file() and entry.name.endswith(_PARQUET_SUFFIX):
            names.append(prefix + entry.name[: -len(_PARQUET_SUFFIX)])
        elif entry.is_dir() and "=" in entry.name:  # a hive partition folder
            names += _scan_parts(Path(entry.path), f"{prefix}{entry.name}/")
    return names


def existing_parts(out_dir: str | os.PathLike, table_name: str) -> list[str]:
    """Sorted names (without ``.parquet``) of the part files in ``OUT/<table_name>/``,
    partitioned ones as ``"point_id=3/part-000001"``.

    Hidden files (``.``/``_`` prefix) and non-Parquet files are ignored; a missing folder
    gives ``[]``.
    """
    out = _check_out_dir(out_dir)
    _check_name(table_name, "table_name")
    folder = out / table_name
    if not folder.is_dir():
        return []
    return sorted(_scan_parts(folder))


def _dataset(out: Path, table_name: str, files: list[Path]) -> ds.Dataset:
    """The parts ``files`` of ``OUT/<table_name>/`` as one :mod:`pyarrow.dataset`: hive
    partition keys (``point_id=3/``) read from the folder names as columns, the parts'
    schemas unified permissively (a column missing from a part is null there)."""
    options = ds.FileSystemFactoryOptions(partition_base_dir=os.path.abspath(out / table_name),
                                          partitioning=ds.partitioning(flavor="hive"))
    factory = ds.FileSystemDatasetFactory(pafs.LocalFileSystem(), [os.path.abspath(f) for f in files],
                                          ds.ParquetFileFormat(), options)
    return factory.finish(factory.inspect(promote_options="permissive"))


def _arrow_table(out: Path, table_name: str, files: list[Path], columns=None) -> pa.Table:
    """The rows of :func:`_dataset` (only ``columns``, those that exist, if given), partition
    keys first (integers as int64); a part that cannot be read is a :class:`DamagedPartError`
    naming it."""
    try:
        dataset = _dataset(out, table_name, files)
        table = dataset.to_table(columns=None if columns is None else
                                 [c for c in dict.fromkeys(columns) if c in dataset.schema.names])
    except _READ_ERRORS:
        for f in files:  # which part is damaged?
            try:
                pq.read_table(f)
            except _READ_ERRORS as part_exc:
                raise _damaged(out, f, part_exc) from None
        raise
    found = {k for f in dataset.get_fragments() for k in ds.get_partition_keys(f.partition_expression)}
    keys = [n for n in dataset.schema.names if n in found and n in table.column_names]  # the folders' order
    for key in keys:
        i = table.schema.get_field_index(key)
        if pa.types.is_integer(table.schema.field(i).type):  # discovery infers int32
            table = table.set_column(i, key, table.column(i).cast(pa.int64()))
    return table.select([*keys, *(n for n in table.column_names if n not in keys)])


def read_table(out_dir: str | os.PathLike, table_name: str = "runs", columns=None) -> pd.DataFrame:
    """Read every part of ``OUT/<table_name>/`` into one pandas DataFrame (only ``columns``,
    those of them that exist, if given: a million-run dataset's summary needs a few).

    Uses :mod:`pyarrow.dataset` with hive partitioning over the files listed by
    :func:`existing_parts` (so the staging folder and stray files are never read).  Part
    schemas are unified permissively (a column missing from some parts is read as null
    there); partition keys come first, integer ones as int64.  Rows are sorted (stable) by
    whichever of ``point_id``, ``seed_index``, ``filter`` are present, with a fresh
    ``RangeIndex``.  Returns an empty DataFrame if nothing has been written.
    """
    out = _check_out_dir(out_dir)
    files = _part_files(out, table_name)
    if not files:
        return pd.DataFrame()
    frame = _arrow_table(out, table_name, files, columns).to_pandas()
    keys = [c for c in SORT_COLUMNS if c in frame.columns]
    if keys:
        frame = frame.sort_values(keys, kind="stable")
    return frame.reset_index(drop=True)


def read_metadata(out_dir: str | os.PathLike, table_name: str = "runs") -> dict[str, Any]:
    """Decoded ``mcjax.*`` schema metadata (prefix removed) of the first part file.

    "First" is the first name in :func:`existing_parts` order.  Returns ``{}`` if nothing
    has been written.
    """
    out = _check_out_dir(out_dir)
    files = _part_files(out, table_name)
    if not files:
        return {}
    try:
        return _decode_metadata(pq.read_schema(files[0]).metadata)
    except _READ_ERRORS as exc:
        raise _damaged(out, files[0], exc) from None


def clean_staging(out_dir: str | os.PathLike) -> int:
    """Remove leftover files in ``OUT/_staging/``; return how many were removed.

    Leftovers come from writers that were killed mid-write.  Call this only when no writer
    is active on ``out_dir`` (e.g. when starting or resuming a sweep), otherwise an
    in-progress write would fail.  The staging folder itself is removed if it ends up empty.
    """
    out = _check_out_dir(out_dir)
    staging = out / STAGING_DIR
    if not staging.is_dir():
        return 0
    removed = 0
    for entry in os.scandir(staging):
        if entry.is_file() or entry.is_symlink():
            try:
                os.unlink(entry.path)
                removed += 1
            except FileNotFoundError:
                pass
    try:
        staging.rmdir()
    except OSError:
        pass
    return removed


def remove_empty_staging(out_dir: str | os.PathLike) -> None:
    """Remove ``OUT/_staging/`` if it holds nothing (a finished writer leaves it empty)."""
    try:
        (_check_out_dir(out_dir) / STAGING_DIR).rmdir()
    except OSError:
        pass


def part_problem(out_dir: str | os.PathLike, table_name: str, part_name: str, seeds: range,
                 rows_per_run: int) -> str | None:
    """None if the part ``OUT/<table_name>/<part_name>.parquet`` is readable and holds exactly
    the runs ``seeds`` (its ``seed_index`` values), each in ``rows_per_run`` rows; else what
    is wrong, in a few words."""
    path = _check_out_dir(out_dir) / table_name / f"{part_name}{_PARQUET_SUFFIX}"
    expected = len(seeds) * rows_per_run
    try:
        meta = pq.ParquetFile(path).metadata
        if meta.num_rows != expected:
            return f"{meta.num_rows} rows, not {expected}"
        got = pq.read_table(path, columns=["seed_index"]).column(0).to_numpy()
    except _READ_ERRORS as exc:
        return f"unreadable: {type(exc).__name__}: {' '.join(str(exc).split())[:160]}"
    if len(got) and (got.min() < seeds.start or got.max() >= seeds.stop):
        return f"runs outside seeds {seeds.start}..{seeds.stop - 1}"
    counts = pd.Series(got).value_counts()
    if len(counts) != len(seeds) or not (counts == rows_per_run).all():
        return f"not {rows_per_run} rows for each of seeds {seeds.start}..{seeds.stop - 1}"
    return None


def remove_part(out_dir: str | os.PathLike, table_name: str, part_name: str) -> None:
    """Delete a part file (a damaged one, before its chunk is written again)."""
    try:
        (_check_out_dir(out_dir) / table_name / f"{part_name}{_PARQUET_SUFFIX}").unlink()
    except FileNotFoundError:
        pass


def write_single_table(path: str | os.PathLike, table: pd.DataFrame, key: str, metadata: Mapping[str, Any]) -> Path:
    """One Parquet file (a league's or a check's table, not parts) with ``metadata`` as JSON under the schema
    metadata key ``key`` (``"mcjax.league"``, ``"mcjax.check"``), written atomically."""
    t = pa.Table.from_pandas(table, preserve_index=False)
    t = t.replace_schema_metadata({**(t.schema.metadata or {}), key.encode(): json.dumps(metadata).encode()})
    return atomic_write(path, lambda tmp: pq.write_table(t, tmp))


def read_single_table(path: str | os.PathLike, key: str) -> tuple[pd.DataFrame, dict]:
    """A file of :func:`write_single_table`: the table and the metadata under ``key`` ({} when none)."""
    t = pq.read_table(path)
    return t.to_pandas(), json.loads((t.schema.metadata or {}).get(key.encode(), b"{}"))
