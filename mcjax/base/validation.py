"""Validation, in one place: the exact kinds of values, their range, choice and shape checks, the
unknown-key check with its did-you-mean hint, and the one-line messages they give — used by the
contract's declarations (:class:`~mcjax.contract.Setting`, :class:`~mcjax.contract.Param`), by
the sweep and config-file reader (:mod:`mcjax.study.spec`) and by the tune spec
(:mod:`mcjax.tune.spec`); also reading a spec's TOML.

Every message has one form: ``"must be …; got …"`` (:func:`bad`) for a value, what it got
named by its kind when that is what is wrong (:func:`got`: ``the string '100e3'``), and
:class:`SpecError` ``"<key path>: …"`` for a spec, the key path written as TOML writes it, one
line per mistake.

Kinds are exact, as TOML has them: a boolean is no number, a float no integer, a string or a
table no list (numpy scalars count as their Python kinds).

This module is a leaf: it imports nothing from mcjax and no JAX.
"""

from __future__ import annotations

import contextlib
import difflib
import json
import math
import re
import tomllib
from pathlib import Path

import numpy as np


class SpecError(ValueError):
    """A sweep spec or config file is invalid; the message names the key path, one line per mistake
    (several lines when a spec has several independent mistakes: :func:`mcjax.study.build_spec`)."""


# ------------------------------------------------------------------ text of messages

BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def key_text(key) -> str:
    """A key as TOML writes it: bare if it can be, else quoted (so a message stays one line)."""
    return key if isinstance(key, str) and BARE_KEY.match(key) else json.dumps(str(key))


def show(value) -> str:
    """``repr(value)`` on one line (an array as its list), cut to a readable length."""
    text = repr(value.tolist() if isinstance(value, np.ndarray) else value).replace("\n", " ")
    return text if len(text) <= 120 else text[:100] + f"... ({len(text)} characters)"


def one_line(text) -> str:
    """``text`` with its white space folded: one line."""
    return " ".join(str(text).split())


def got(value) -> str:
    """What a message says it got: the value on one line (:func:`show`), named by its kind where
    the kind is easy to miss in a spec — ``the string '100e3'`` (quoted in the TOML), ``the boolean
    true``, ``the table {...}``; a string that reads as a number says how to write one."""
    if isinstance(value, str):
        text, number = value.strip(), None
        if text and len(text) <= 40 and "\n" not in text and "=" not in text:
            try:
                number = tomllib.loads(f"v = {text}")["v"]
            except tomllib.TOMLDecodeError:
                pass
        hint = f" (a number is written without quotes: {text})" if is_number(number) else ""
        return f"the string {show(value)}{hint}"
    if is_bool(value):
        return f"the boolean {'true' if value else 'false'}"
    if isinstance(value, dict):
        return f"the table {show(value)}"
    return show(value)


def suggest(key, allowed) -> str:
    """`` (did you mean 'X'?)`` for the allowed key closest to ``key``, else ``""``."""
    close = difflib.get_close_matches(str(key), allowed, n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def near_name(name: str, names) -> str | None:
    """The one of ``names`` a typo away from ``name`` — a letter missing, wrong or extra
    (:func:`difflib.get_close_matches` at 0.75), or two letters swapped ('kfc' for 'kcf') — else None."""
    names = [str(n) for n in names]
    close = difflib.get_close_matches(name, names, n=1, cutoff=0.75)
    if not close:
        close = [n for n in names if len(n) == len(name) and sorted(n) == sorted(name)
                 and sum(a != b for a, b in zip(n, name)) == 2]
    return close[0] if close else None


def near_path(written, actual=None, *, folder: bool = False) -> str:
    """``"; did you mean X?"`` for a path that does not exist: the file (with ``folder``, the
    folder) beside it whose name is closest to its own (:mod:`difflib`), written as the user wrote
    the path (``written``; ``actual``: where it points, when that is not ``written`` itself, e.g.
    relative to a spec's folder), else ``""``."""
    text = str(written).rstrip("/\\") or str(written)
    target = Path(text if actual is None else actual)
    try:
        names = [p.name for p in target.parent.iterdir() if (p.is_dir() if folder else p.is_file())]
    except OSError:
        return ""
    close = difflib.get_close_matches(target.name, names, n=1)
    if not close or not text.endswith(Path(text).name):
        return ""
    return f"; did you mean {text[:len(text) - len(Path(text).name)]}{close[0]}?"


def bad(allowed: str, value, kind_ok: bool = False) -> str:
    """The one-line message of a value that is not allowed: ``"must be …; got …"``, the value named by its
    kind (:func:`got`) unless ``kind_ok`` (a string where a string is wanted, but not one of the choices)."""
    return f"must be {allowed}; got {show(value) if kind_ok else got(value)}"


def number_text(v) -> str:
    """A bound or choice as a message writes it (``80000`` for ``80e3``)."""
    return f"{v:g}" if isinstance(v, float) else str(v)


def range_text(low, high, low_open, integer) -> str:
    """An allowed range in words: ``"in [0, 1]"``, ``"an integer >= 1"``, ``"any number"``."""
    kind = "an integer " if integer else ""
    lo_ok, hi_ok = low is not None and low > -math.inf, high is not None and high < math.inf
    if lo_ok and hi_ok:
        return f"{kind}in {'(' if low_open else '['}{number_text(low)}, {number_text(high)}]"
    if lo_ok:
        return f"{kind}{'>' if low_open else '>='} {number_text(low)}"
    if hi_ok:
        return f"{kind}<= {number_text(high)}"
    return "an integer" if integer else "any number"


def shape_text(shape, n_agents=None) -> str:
    """A declared shape as ``n_agentsx2`` (or, given ``n_agents``, its numbers: ``5x2``)."""
    return "x".join(("n_agents" if n_agents is None else str(n_agents)) if d == "n" else str(d) for d in shape)


# ------------------------------------------------------------------ exact kinds

def is_bool(v) -> bool:
    return isinstance(v, (bool, np.bool_))


def is_int(v) -> bool:
    """An integer in kind (a boolean is none)."""
    return isinstance(v, (int, np.integer)) and not is_bool(v)


def is_number(v) -> bool:
    """A number in kind (a boolean is none)."""
    return isinstance(v, (int, float, np.integer, np.floating)) and not is_bool(v)


def same(value, choice) -> bool:
    """``value`` is ``choice`` in kind and in value: true is not 1, 1.0 is not 1, "1" is not 1."""
    for kind in (lambda v: isinstance(v, str), is_bool, is_int, is_number):
        if kind(choice):
            return kind(value) and value == choice
    return type(value) is type(choice) and value == choice


def leaves(value):
    """The leaves of a nested list (a value itself if it is no list); None if a leaf is a
    table, a string, a boolean or anything but a number."""
    if isinstance(value, np.ndarray):
        return [value] if value.dtype.kind in "iuf" else None
    if isinstance(value, (list, tuple)):
        subs = [leaves(v) for v in value]
        return None if any(sub is None for sub in subs) else [leaf for sub in subs for leaf in sub]
    return [value] if is_number(value) else None


def integral_leaves(items) -> bool:
    """Every leaf is an integer in kind (an integer-typed array counts; a float never does)."""
    return all(is_int(v) or (isinstance(v, np.ndarray) and v.dtype.kind in "iu") for v in items)


def within(value, low, high, low_open):
    """A range check (element-wise for an array) that also holds for integers beyond float range."""
    ok = True if low is None else (value > low if low_open else value >= low)
    return ok & (True if high is None else value <= high)


# ------------------------------------------------------------------ declared values (Setting, Param)

#: Upper bounds of the integer Config fields that declare none (agents, steps; every other count:
#: COUNT_CEILING), so no spec asks for more than a machine holds (the study plan's memory check refines them).
COUNT_CEILINGS = {"n_agents": 1_000, "n_steps": 1_000_000}
COUNT_CEILING = 100_000


def ceiling(name: str, setting) -> int | None:
    """The upper bound a Config enforces on an integer Setting that declares no ``high``
    (:data:`COUNT_CEILINGS`, else :data:`COUNT_CEILING`); None for other fields."""
    if not setting.integer or setting.choices is not None or (setting.high is not None and setting.high < math.inf):
        return None
    return COUNT_CEILINGS.get(name, COUNT_CEILING)


def setting_allowed(s) -> str:
    """What a :class:`~mcjax.contract.Setting` allows, in words."""
    if s.many:
        more = ""
        if getattr(s, "plugins", None):
            from importlib.metadata import entry_points

            installed = sorted({ep.name for ep in entry_points(group=s.plugins)} - set(s.choices))
            more = (f", an installed one ({', '.join(installed)})" if installed
                    else f", a name installed under {s.plugins}") + " or 'file.py:ATTRIBUTE'"
        return "a non-empty list of distinct values from " + ", ".join(map(str, s.choices)) + more
    if s.choices is not None:
        return "one of " + ", ".join(map(str, s.choices))
    return range_text(s.low, s.high, s.low_open, s.integer)


def is_plugin_name(value, group: str) -> bool:
    """Whether ``value`` may name a plugin of the entry-point ``group`` (a Setting's ``plugins``): a name an
    installed package declares there, or a reference ``FILE.py:ATTR`` / ``MODULE:ATTR``. Whether it loads and
    is what it should be is the registry's to say (the scenario's checks ask it)."""
    if not isinstance(value, str) or not value:
        return False
    if ":" in value:
        return True
    from importlib.metadata import entry_points

    return value in {ep.name for ep in entry_points(group=group)}


def setting_value_problem(s, value) -> str | None:
    """None if a Setting allows ``value``, else ``"must be …; got …"``. Kinds are exact: a
    boolean is no number, a float no integer, a string no list."""
    if s.many:
        if not isinstance(value, (tuple, list)):
            return bad(setting_allowed(s), value)
        unknown = [v for v in value if not any(same(v, c) for c in s.choices)
                   and not (getattr(s, "plugins", None) and is_plugin_name(v, s.plugins))]
        refuses = getattr(s, "refuses", None)
        if unknown and refuses and any(is_plugin_name(v, refuses[0]) for v in unknown):
            return f"must be among its own {', '.join(map(str, s.choices))} ({refuses[1]}); got {show(value)}"
        if unknown:
            close = near_name(unknown[0], s.choices) if isinstance(unknown[0], str) else None
            hint = f"; did you mean {close!r}?" if close else ""
            return bad(setting_allowed(s), value) + f" (unknown: {', '.join(map(show, unknown))}{hint})"
        return bad(setting_allowed(s), value) if len(value) == 0 or len(set(value)) != len(value) else None
    if s.choices is not None:
        strings = isinstance(value, str) and all(isinstance(c, str) for c in s.choices)
        return None if any(same(value, c) for c in s.choices) else bad(setting_allowed(s), value, kind_ok=strings)
    unit = f" {s.unit}" if s.unit else ""
    if not is_number(value) or (s.integer and not is_int(value)):
        return bad(setting_allowed(s) + ("" if s.integer else unit), value)
    finite = is_int(value) or math.isfinite(value)
    return None if finite and within(value, s.low, s.high, s.low_open) else bad(setting_allowed(s) + unit, value)


def setting_problem(name: str, setting, value) -> str | None:
    """:meth:`Setting.problem <mcjax.contract.Setting.problem>`, then the field's :func:`ceiling`."""
    msg = setting_value_problem(setting, value)
    top = ceiling(name, setting)
    if msg is None and top is not None and value > top:
        low, unit = setting.low if setting.low is not None else -math.inf, f" {setting.unit}" if setting.unit else ""
        return bad(range_text(low, top, setting.low_open, True) + unit, value)
    return msg


def param_allowed(p) -> str:
    """What a :class:`~mcjax.contract.Param` allows, in words (its choices or range)."""
    if p.choices is not None:
        return " or ".join(number_text(c) for c in p.choices)
    return range_text(p.low, p.high, p.low_open, p.integer)


def param_expected(p, n_agents: int | None = None, cfg=None) -> str:
    """What a Param takes, in words: its form (a number, one per agent, a shape) and its
    allowed values, e.g. ``"a number or a list of n_agents = 5 numbers, >= 0 m"``."""
    kind = "integer" if p.integral() else "number"
    one = f"a{'n' if kind == 'integer' else ''} {kind}"
    if p.shape is not None:
        want = "" if n_agents is None else f" ({shape_text(p.shape, n_agents)})"
        form = f"an array of {kind}s of shape {shape_text(p.shape)}{want}"
    elif p.per_agent:
        form = f"{one} or a list of {'n_agents' if n_agents is None else f'n_agents = {n_agents}'} {kind}s"
    else:
        form = one if cfg is not None and p.scalar(cfg) else f"{one} or a rectangular list of {kind}s"
    if p.choices is not None:
        return f"{form}, {param_allowed(p)}"
    rng = range_text(p.low, p.high, p.low_open, False)
    return form if rng == "any number" else f"{form}, {rng}" + (f" {p.unit}" if p.unit else "")


def param_problem(p, value, n_agents: int | None = None, *, exact: bool = False, cfg=None) -> str | None:
    """None if a Param allows ``value`` (for ``n_agents`` agents, when given: shapes are then
    checked too), else ``"must be …; got …"``; a boolean, string, table or ragged list is no
    number. ``exact=True`` reads ``value`` as a spec gives it: an integer field (or one with
    integer choices) takes integers only (``5.0`` is a float), and with ``cfg`` (which also
    sets ``n_agents``) a scalar field takes one number only."""
    if cfg is not None:
        n_agents = cfg.n_agents
    items = leaves(value)
    if items is None:
        return bad(param_expected(p, n_agents, cfg) if exact else "a number or a list of numbers", value)
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):  # ragged, or an integer beyond float range
        return bad(param_expected(p, n_agents, cfg) if exact else "a number or a list of numbers", value)
    if exact and p.integral() and not integral_leaves(items):
        return bad(param_expected(p, n_agents, cfg), value)
    if exact and cfg is not None and p.scalar(cfg) and arr.ndim != 0:
        return bad(param_expected(p, n_agents, cfg), value)
    if not np.all(np.isfinite(arr)):
        return bad("finite", value)
    if p.choices is not None:
        if not np.all(np.isin(arr, p.choices)):
            return bad(param_allowed(p), value)
    elif p.integer and np.any(arr != np.round(arr)):
        return bad(param_allowed(p), value)
    elif not np.all(within(arr, p.low, p.high, p.low_open)):
        return bad(param_allowed(p) + (f" {p.unit}" if p.unit else ""), value)
    if n_agents is not None:
        if p.per_agent and arr.shape not in ((), (n_agents,)):
            return bad(f"a number or a list of n_agents = {n_agents} numbers", value)
        if p.shape is not None:
            if arr.shape != tuple(n_agents if d == "n" else d for d in p.shape):
                return bad(f"of shape {shape_text(p.shape)} ({shape_text(p.shape, n_agents)})", value)
    return None


# ------------------------------------------------------------------ spec tables (SpecError naming the key path)

#: An unknown key's message lists every allowed key while they fit in this many characters; past it, the
#: closest ones and where to see them all (``see``).
ALLOWED_TEXT = 100


def unknown_key(where: str, key, allowed, see: str | None = None) -> str:
    """The line of a key that is not ``allowed``: the did-you-mean hint, then every allowed key when
    they are few (:data:`ALLOWED_TEXT`), else the three closest and where to see all (``see``,
    e.g. ``mcjax list leader_follower``)."""
    allowed = list(allowed)
    every = ", ".join(allowed)
    if see is None or len(every) <= ALLOWED_TEXT:
        return f"{where}{key_text(key)}: unknown key{suggest(key, allowed)}; allowed: {every}"
    hint = suggest(key, allowed)
    close = [k for k in difflib.get_close_matches(str(key), allowed, n=4, cutoff=0.5) if f"{k!r}?" not in hint][:2]
    closest = f"; {'also close' if hint else 'the closest'}: {', '.join(close)}" if close else ""
    return f"{where}{key_text(key)}: unknown key{hint}{closest}; all {len(allowed)} listed by {see}"


def check_keys(where: str, table, allowed, see: str | None = None) -> None:
    """SpecError naming each key of ``table`` that is not ``allowed`` (``where`` + key), one line
    each (:func:`unknown_key`; ``see``: where the allowed keys are all listed)."""
    lines = [unknown_key(where, key, allowed, see) for key in table if key not in allowed]
    if lines:
        raise SpecError("\n".join(lines))


class Mistakes:
    """The mistakes of a spec found so far, each check made on its own: ``with m.check(): …`` keeps the
    lines of a :class:`SpecError` and goes on; :meth:`stop` raises them all in one, one line each."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    @contextlib.contextmanager
    def check(self):
        try:
            yield
        except SpecError as exc:
            self.lines += [line for line in str(exc).splitlines() if line not in self.lines]

    def stop(self) -> None:
        if self.lines:
            raise SpecError("\n".join(self.lines))


def count(where: str, value, low: int, high: int) -> int:
    """An integer count in [low, high] (a boolean or a float is no count)."""
    if not is_int(value) or not low <= value <= high:
        raise SpecError(f"{where}: must be an integer in [{low}, {high}]; got {got(value)}")
    return value


def number(where: str, value, *, positive: bool = False, nonneg: bool = False) -> float:
    """A finite number (> 0 with ``positive``, >= 0 with ``nonneg``), as a float."""
    if not is_number(value) or not math.isfinite(value) or (positive and value <= 0) or (nonneg and value < 0):
        what = "a number > 0" if positive else "a number >= 0" if nonneg else "a finite number"
        raise SpecError(f"{where}: must be {what}; got {got(value)}")
    return float(value)


def choice(where: str, value, allowed, *, hint: bool = False):
    """``value`` if it is one of ``allowed`` (with ``hint``: a string gets the did-you-mean hint)."""
    if value not in allowed:
        tip = suggest(value, allowed) if hint and isinstance(value, str) else ""
        strings = isinstance(value, str) and all(isinstance(a, str) for a in allowed)
        raise SpecError(f"{where}: must be one of {', '.join(allowed)}; got {show(value) if strings else got(value)}{tip}")
    return value


def subtable(where: str, data: dict, key: str) -> dict:
    """``data[key]``, which must be a table (``{}`` when missing)."""
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise SpecError(f"{where}{key}: must be a table ([{key}] with one key = value per line); got {got(value)}")
    return value


def check_text(where: str, data: dict, key: str) -> None:
    """SpecError unless ``data[key]``, when given, is a string."""
    if key in data and not isinstance(data[key], str):
        raise SpecError(f"{where}{key}: must be a string; got {got(data[key])}")


# ------------------------------------------------------------------ reading TOML

def read_toml(path: Path, what: str) -> dict:
    """A TOML file read as UTF-8 (a byte-order mark is skipped); SpecError in one line when it
    is missing, a folder, unreadable, not UTF-8 or not TOML."""
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise SpecError(f"{what} not found: {path}{near_path(path)}") from None
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
