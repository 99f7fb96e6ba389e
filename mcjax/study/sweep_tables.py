"""What the files that run several sweeps share (a claims file's ``[sweeps.NAME]`` tables, a league
file's ``[scenarios.NAME]`` and ``[points.NAME]``): their named tables, checked one by one, each
name that of an output folder; and their loader, every problem of which is one error of the file's
own kind. It imports :mod:`mcjax.base.validation` alone, but the package :mod:`mcjax.study` brings
JAX: a module that starts without it (:mod:`mcjax.league.spec`) imports this one where it reads a
file::

    for name, where, table in named_tables("claims.toml: sweeps", data.get("sweeps"), SPEC_TABLE_KEYS,
                                           ClaimsError, missing="...", bad_name="..."):
        ...
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Callable, Iterator, TypeVar

from mcjax.base.validation import SpecError, check_keys, key_text, show

#: A table's name that names an output folder: letters, digits, '_', '-' or '.', a letter or digit first.
FOLDER_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")

T = TypeVar("T")


def load_checked(load: Callable[[Path, int | None], T], path: str | Path, seeds: int | None,
                 error: type[SpecError]) -> T:
    """``load(Path(path), seeds)``, raising ``error`` alone: its own errors pass, any other
    :class:`SpecError` (the shared validation's: unknown keys, reading the TOML) becomes an
    ``error`` with the same message."""
    try:
        return load(Path(path), seeds)
    except error:
        raise
    except SpecError as exc:
        raise error(str(exc)) from None


def named_tables(where: str, raw: Any, keys: tuple, error: type[SpecError], *, missing: str, bad_name: str,
                 table: str = "a table") -> Iterator[tuple[Any, str, dict]]:
    """``(name, where it is, table)`` of each table of ``raw`` (a file's ``[KEY.NAME]`` tables; ``where``:
    ``"FILE: KEY"``), in order, each checked as it comes: a name of :data:`FOLDER_NAME`, a table,
    no key but ``keys``. A problem is an ``error`` of one line naming the key path: ``raw`` not a
    non-empty table (``missing`` says what it must name), a name that cannot name a folder
    (``bad_name``), a value not a table (it must be ``table``), an unknown key."""
    if not isinstance(raw, dict) or not raw:
        raise error(f"{where}: {missing}" + ("" if raw is None else f"; got {show(raw)}"))
    for name, value in raw.items():
        at = f"{where}.{key_text(name)}"
        if not FOLDER_NAME.match(str(name)):
            raise error(f"{at}: {bad_name}")
        if not isinstance(value, dict):
            raise error(f"{at}: must be {table}; got {show(value)}")
        check_keys(f"{at}.", value, keys)
        yield name, at, value
