"""The small checks a spec reader is made of: reading TOML, exact kinds of values, one-line
messages naming the key path (:class:`SpecError`). Shared by the sweep spec
(:mod:`mcjax.study.spec`) and the tune spec (:mod:`mcjax.tune.spec`). No JAX.
"""

from __future__ import annotations

import difflib
import json
import re
import tomllib
from pathlib import Path


class SpecError(ValueError):
    """A sweep spec or config file is invalid; the message names the key path."""


BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def key_text(key) -> str:
    """A key as TOML writes it: bare if it can be, else quoted (so a message stays one line)."""
    return key if isinstance(key, str) and BARE_KEY.match(key) else json.dumps(str(key))


def show(value) -> str:
    """A value on one line, cut to a readable length."""
    text = repr(value).replace("\n", " ")
    return text if len(text) <= 120 else text[:100] + f"... ({len(text)} characters)"


def one_line(text) -> str:
    """``text`` with its white space folded: one line."""
    return " ".join(str(text).split())


def suggest(key, allowed) -> str:
    """`` (did you mean 'X'?)`` for the allowed key closest to ``key``, else ``""``."""
    close = difflib.get_close_matches(str(key), allowed, n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def check_keys(where: str, table, allowed) -> None:
    """SpecError naming the first key of ``table`` that is not ``allowed`` (``where`` + key)."""
    for key in table:
        if key not in allowed:
            raise SpecError(f"{where}{key_text(key)}: unknown key{suggest(key, allowed)}; allowed: {', '.join(allowed)}")


def is_int(v) -> bool:
    """An integer in kind (a boolean is none)."""
    return isinstance(v, int) and not isinstance(v, bool)


def is_number(v) -> bool:
    """A number in kind (a boolean is none)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def count(where: str, value, low: int, high: int) -> int:
    """An integer count in [low, high] (a boolean or a float is no count)."""
    if not is_int(value) or not low <= value <= high:
        raise SpecError(f"{where}: must be an integer in [{low}, {high}]; got {show(value)}")
    return value


def subtable(where: str, data: dict, key: str) -> dict:
    """``data[key]``, which must be a table (``{}`` when missing)."""
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise SpecError(f"{where}{key}: must be a table ([{key}] with one key = value per line); got {show(value)}")
    return value


def check_text(where: str, data: dict, key: str) -> None:
    """SpecError unless ``data[key]``, when given, is a string."""
    if key in data and not isinstance(data[key], str):
        raise SpecError(f"{where}{key}: must be a string; got {show(data[key])}")


def read_toml(path: Path, what: str) -> dict:
    """A TOML file read as UTF-8 (a byte-order mark is skipped); SpecError in one line when it
    is missing, a folder, unreadable, not UTF-8 or not TOML."""
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise SpecError(f"{what} not found: {path}") from None
    except IsADirectoryError:
        raise SpecError(f"{what} {path} is a folder, not a TOML file") from None
    except OSError as exc:
        raise SpecError(f"{what} {path} cannot be read: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SpecError(f"{path}: not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start}); "
                        f"save it as UTF-8") from None
    try:
        return tomllib.loads(text.removeprefix("\ufeff"))
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{path}: not valid TOML: {one_line(exc)}") from None


def set_value(raw: str):
    """A ``--set`` value: TOML (``80e3``, ``true``, ``"name"``, ``[1, 2]``), else a bracketed
    list of bare words (``[name1,name2]``), else the text itself (``name``)."""
    try:
        return tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        pass
    if raw.startswith("[") and raw.endswith("]"):
        items = [item.strip() for item in raw[1:-1].split(",")]
        return [set_value(item) for item in items if item]
    return raw
