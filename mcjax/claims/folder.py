"""The files of a check folder, read and written without JAX: ``check.json`` (what ``--resume``
compares) and ``claims.parquet`` (the verdict table with its metadata)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd

from mcjax.base.files import atomic_write

CHECK_FILE = "check.json"
TABLE_FILE = "claims.parquet"
def is_check_folder(folder: str | Path) -> bool:
    """True for the output folder of ``mcjax check`` (it holds ``check.json``)."""
    return (Path(folder) / CHECK_FILE).is_file()


def write_table(path: Path, table: pd.DataFrame, metadata: dict[str, Any]) -> Path:
    """The verdict table as Parquet with ``metadata`` (JSON under ``mcjax.check``), atomically."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    t = pa.Table.from_pandas(table, preserve_index=False)
    t = t.replace_schema_metadata({**(t.schema.metadata or {}), b"mcjax.check": json.dumps(metadata).encode()})
    return atomic_write(path, lambda tmp: pq.write_table(t, tmp))


def read_verdicts(folder: str | Path) -> tuple[pd.DataFrame, dict]:
    """The verdict table of a check folder and its metadata; FileNotFoundError naming the file
    when the check has not finished."""
    import pyarrow.parquet as pq

    path = Path(folder) / TABLE_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no verdicts yet (the check has not finished: run it again with --resume)")
    t = pq.read_table(path)
    meta = json.loads((t.schema.metadata or {}).get(b"mcjax.check", b"{}"))
    return t.to_pandas(), meta
