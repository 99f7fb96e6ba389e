"""The files of a league folder, read and written without JAX: ``league.json`` (what ``--resume``
compares), ``timing.json`` (the timing pass, kept for a resumed league) and ``league.parquet``
(the league table with its metadata)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pandas as pd

from mcjax.base.files import atomic_write, read_json_object
from mcjax.base.parquet import read_single_table, write_single_table

LEAGUE_FILE = "league.json"
TIMING_FILE = "timing.json"
TABLE_FILE = "league.parquet"


def is_league_folder(folder: str | Path) -> bool:
    """True for the output folder of ``mcjax league`` (it holds ``league.json``)."""
    return (Path(folder) / LEAGUE_FILE).is_file()


def read_timing(folder: str | Path) -> dict:
    """The timing pass saved in ``folder`` (``{}`` when none is, or it is damaged)."""
    return read_json_object(Path(folder) / TIMING_FILE)


def write_timing(folder: str | Path, timing: dict) -> None:
    atomic_write(Path(folder) / TIMING_FILE, json.dumps(timing, indent=1))


def write_table(path: Path, table: pd.DataFrame, metadata: dict[str, Any]) -> Path:
    """The league table as Parquet with ``metadata`` (JSON under ``mcjax.league``), atomically."""
    return write_single_table(path, table, "mcjax.league", metadata)


def read_league(folder: str | Path) -> tuple[pd.DataFrame, dict]:
    """The league table of a league folder and its metadata; FileNotFoundError naming the file
    when the league has not finished."""
    path = Path(folder) / TABLE_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no league table yet (the league has not finished: run it again with "
                                f"--resume)")
    return read_single_table(path, "mcjax.league")
