"""Scenarios: one package per paper, each exporting ``SCENARIO`` (a
:class:`mcjax.contract.Scenario`) and holding everything only that paper uses (its scenario,
models, planner); :mod:`.kit` holds what they share; and the registry that finds them by name.

Three ways to name a scenario (in a config file's ``scenario = "..."``, or :func:`get`):

* a built-in name (``leader_follower``, ``uuv_imm``, ``urban_bearing``, ``flocking``, ``wind_formation``);
* the name a plugin registers: another installed package declares, in its
  ``pyproject.toml``, ``[project.entry-points."mcjax.scenarios"] my_name = "my_pkg.module:SCENARIO"``;
* a reference ``"path/to/file.py:SCENARIO"`` (relative to the config file's folder) or
  ``"some.module:SCENARIO"`` (an importable module) — for a scenario you are writing.

The last two import and run Python code named by a config file: a config or spec from
elsewhere is to be read like code (docs/cli.md, "What a spec may run"). :func:`origin` tells
which file or module a scenario came from (``mcjax sweep`` / ``run`` / ``tune`` print it).
"""

from __future__ import annotations

import difflib
import sys
from importlib.metadata import entry_points
from pathlib import Path

from mcjax.base.plugins import import_reference, module_file
from mcjax.contract import Scenario
from mcjax.scenarios import chen2013, chen2022, lou2013, ren2017, sun2011

#: Entry-point group of third-party scenarios.
ENTRY_POINT_GROUP = "mcjax.scenarios"

BUILTIN: dict[str, Scenario] = {s.name: s for s in (sun2011.SCENARIO, ren2017.SCENARIO, chen2022.SCENARIO,
                                                  lou2013.SCENARIO, chen2013.SCENARIO)}


#: Where each scenario that is not built in was imported from, by id (kept alive with it).
_ORIGINS: dict[int, tuple[Scenario, str]] = {}


def _note_origin(obj, where: str):
    if isinstance(obj, Scenario) and obj not in BUILTIN.values():
        _ORIGINS.setdefault(id(obj), (obj, where))
    return obj


def origin(scenario: Scenario) -> str | None:
    """The file, module or plugin a scenario was imported from (by :func:`get`), or None for a
    built-in one (and for one :func:`get` did not import)."""
    entry = _ORIGINS.get(id(scenario))
    return entry[1] if entry is not None and entry[0] is scenario else None


def describe(scenario: Scenario) -> str:
    """A scenario's name, and where it was imported from when it is not built in (:func:`origin`)."""
    where = origin(scenario)
    return scenario.name if where is None else f"{scenario.name} (imported from {where})"


def _plugin_points() -> dict:
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP) if ep.name not in BUILTIN}


def known() -> list[str]:
    """Names of every scenario: the built-in ones, then the installed plugins'."""
    return [*BUILTIN, *sorted(_plugin_points())]


def _checked(obj, ref: str) -> Scenario:
    if not isinstance(obj, Scenario):
        raise ValueError(f"scenario {ref!r} is a {type(obj).__name__}, not an mcjax.contract.Scenario")
    return obj


def _from_reference(ref: str, base_dir: Path | None) -> Scenario:
    obj, source = import_reference(ref, base_dir, "scenario")
    return _note_origin(_checked(obj, ref), source)


def get(name: str, base_dir: str | Path | None = None) -> Scenario:
    """The scenario called ``name`` (see the module docstring); ValueError listing the known
    ones otherwise. ``base_dir``: the folder a relative ``file.py:ATTR`` reference is read from."""
    if name in BUILTIN:
        return BUILTIN[name]
    plugins = _plugin_points()
    if name in plugins:
        point = plugins[name]
        obj = _checked(point.load(), name)
        return _note_origin(obj, f"plugin {point.value}{module_file(sys.modules.get(point.module))}")
    if ":" in name:
        return _from_reference(name, None if base_dir is None else Path(base_dir))
    raise ValueError(f"scenario must be one of {', '.join(known())} (or 'file.py:ATTRIBUTE'); got {name!r}"
                     f"{did_you_mean(name, known())}")


def did_you_mean(name: str | None, known_names: list[str]) -> str:
    """``"; did you mean 'NAME'?"`` for a scenario name one typo away from a known
    one (:func:`difflib.get_close_matches`), else ``""``."""
    if not isinstance(name, str) or not name or name in known_names:
        return ""
    close = difflib.get_close_matches(name, known_names, n=1, cutoff=0.75)
    return f"; did you mean {close[0]!r}? (`mcjax list {close[0]}`)" if close else ""
