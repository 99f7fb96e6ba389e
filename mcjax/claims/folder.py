"""The files of a check folder, read and written without JAX: ``check.json`` (what ``--resume``
compares, with the claims file as read: :func:`claim_tables`), ``claims.parquet`` (the verdict table
with its metadata), where each sweep's runs are (:func:`sweep_folder`) and, for one of those
folders, which check and claims it serves (:func:`served_claims`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd

from mcjax.base.files import read_json_object
from mcjax.base.parquet import read_single_table, write_single_table

CHECK_FILE = "check.json"
TABLE_FILE = "claims.parquet"


def is_check_folder(folder: str | Path) -> bool:
    """True for the output folder of ``mcjax check`` (it holds ``check.json``)."""
    return (Path(folder) / CHECK_FILE).is_file()


def write_table(path: Path, table: pd.DataFrame, metadata: dict[str, Any]) -> Path:
    """The verdict table as Parquet with ``metadata`` (JSON under ``mcjax.check``), atomically."""
    return write_single_table(path, table, "mcjax.check", metadata)


def read_verdicts(folder: str | Path) -> tuple[pd.DataFrame, dict]:
    """The verdict table of a check folder and its metadata; FileNotFoundError naming the file
    when the check has not finished."""
    path = Path(folder) / TABLE_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no verdicts yet (the check has not finished: run it again with --resume)")
    return read_single_table(path, "mcjax.check")


def read_check(folder: str | Path) -> dict:
    """``check.json`` of a check folder ({} when it is missing or damaged)."""
    return read_json_object(Path(folder) / CHECK_FILE)


def claim_tables(folder: str | Path) -> dict[str, dict]:
    """Each claim's table as the claims file gave it (``check.json`` holds the file as read), by id,
    with ``sweep`` filled in when the file has one sweep; {} when the folder does not say."""
    source = read_check(folder).get("claims")
    if not isinstance(source, dict) or not isinstance(source.get("claim"), list):
        return {}
    sweeps = list(source.get("sweeps") or {}) if isinstance(source.get("sweeps"), dict) else []
    out = {}
    for raw in source["claim"]:
        if isinstance(raw, dict) and isinstance(raw.get("id"), str):
            out[raw["id"]] = {**({"sweep": sweeps[0]} if len(sweeps) == 1 else {}), **raw}
    return out


def sweep_folder(folder: str | Path, sweep: str) -> Path:
    """The folder of the check's sweep ``sweep``: ``folder/<sweep>``, or range 0's
    (``folder/range_0/<sweep>``) in a replication."""
    own = Path(folder) / sweep
    return own if own.is_dir() or not (Path(folder) / "range_0" / sweep).is_dir() else Path(folder) / "range_0" / sweep


def _sides(raw: dict) -> list[dict]:
    """A claim's table and the side tables inside it (``minus``, ``than``, each of ``order``)."""
    sides = [raw, *(raw[k] for k in ("minus", "than") if isinstance(raw.get(k), dict))]
    return sides + [o for o in raw.get("order") or () if isinstance(o, dict)]


def served_claims(sweep_dir: str | Path) -> tuple[dict, list[str]] | None:
    """For the folder of one of a check's sweeps (``CHECK/<sweep>``, or ``CHECK/range_<r>/<sweep>`` in a
    replication): the check's ``check.json`` and the ids of the claims that read the sweep (a side of
    theirs names it, or the file has this one sweep); None for any other folder."""
    sweep_dir = Path(sweep_dir)
    check = sweep_dir.parent
    if not is_check_folder(check):
        return None
    saved = read_check(check)
    ids = [cid for cid, raw in claim_tables(check).items()
           if any(side.get("sweep", raw.get("sweep")) == sweep_dir.name for side in _sides(raw))]
    return saved, ids
