"""A league file (TOML) read and checked whole, before anything runs.

A league file names the filters, the scenarios with their base configs, the fault points and the
runs::

    title = "Consensus filters against faults of the network"
    seeds = 500                  # runs per scenario x point (--seeds overrides); every filter runs on the same seeds
    base_seed = 0
    chunk_size = 1000
    timing_runs = 200            # runs of each filter alone in the timing pass (0: no timing pass)
    filters = ["cif", "kcf", "local", "my_filters.py:FILTER"]   # built-in, installed or "file.py:ATTRIBUTE"
    plugins = { diffusion_kf = "../plugins/diffusion_kf" }    # optional: where a plugin filter comes from

    [scenarios.flocking]         # a name of your own (it names the output folder OUT/flocking/)
    base = "../../configs/lou2013.toml"          # relative to the league file
    filters = ["kcf", "local"]   # optional: the league's filters this scenario runs (default: all of them)
    config = { n_steps = 100 }   # optional Config and Params overrides of this scenario
    params = {}

    [points.none]                # a fault point: Config and Params overrides applied to every scenario
    description = "no faults"
    [points.iid_0_3]
    config = { faults = "on" }
    params = { link_loss = 0.3 }

Every scenario × point is a sweep spec built from the base config, the scenario's overrides and the
point's (the point's win), with the scenario's filters as its ``filters``: one sweep per cell of
the league, all on the same seeds, so differences between filters pair by seed. A league filter a
scenario does not run gets a row saying why: the scenario's own one-line refusal, or "left out by
the league file" when it would run it. A filter the scenario is asked to run but refuses, an unknown
filter, an unknown key: a :class:`LeagueError` of one line naming the key path.

No JAX at import; checking a file imports the scenarios and filters (and so JAX).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, NamedTuple

from mcjax.base.plugins import absolute_reference
from mcjax.base.validation import SpecError, check_keys, count, key_text, read_toml, show, subtable, suggest

FILE_KEYS = ("title", "description", "seeds", "base_seed", "chunk_size", "timing_runs", "filters", "plugins",
             "scenarios", "points")
SCENARIO_KEYS = ("base", "description", "filters", "config", "params")
POINT_KEYS = ("description", "config", "params")
#: Runs per cell when neither the league file nor --seeds gives a number.
DEFAULT_SEEDS = 100
#: Runs of each filter in the timing pass when the league file gives none.
DEFAULT_TIMING_RUNS = 100
MAX_TIMING_RUNS = 100_000


class LeagueError(SpecError):
    """A league file is invalid; the message (one line) names the key path."""


class Entry(NamedTuple):
    """One scenario of the league: its ``key`` (the league file's name for it), the registered
    ``scenario`` name, the ``filters`` it runs (league names, in the league's order) and ``notes``:
    why each other league filter has no runs here."""

    key: str
    scenario: str
    filters: tuple
    notes: dict


class League(NamedTuple):
    """A checked league file: its ``path``, ``title``, ``filters`` (as written), ``config_names``
    (league name → the name a Config's ``filters`` takes: a file reference made absolute),
    ``scenarios`` (key → :class:`Entry`), ``points`` (name → description), ``studies`` ((scenario,
    point) → Study), ``seeds``, ``timing_runs`` and the file's tables as read (``source``)."""

    path: Path
    title: str
    filters: tuple
    config_names: dict
    scenarios: dict
    points: dict
    studies: dict
    seeds: int
    timing_runs: int
    source: dict

    def filter_name(self, config_name: str) -> str:
        """The league's name of a dataset's ``filter`` value: a filter of one's own is shown in a dataset by
        its record's name (:func:`mcjax.tracking.filters.registry.shown_name`), and in one written before
        2026-12-07 by its Config name (the reference made absolute); either gives the name the league file
        wrote."""
        from mcjax.tracking.filters.registry import shown_name  # resolved already: the league's filters were

        back = {shown_name(v): k for k, v in self.config_names.items()}
        back.update({v: k for k, v in self.config_names.items()})
        return back.get(config_name, config_name)


def _err(where: str, text: str) -> LeagueError:
    return LeagueError(f"{where}: {text}")


def _names(where: str, value, allowed: tuple | None = None) -> tuple:
    if not isinstance(value, list) or not value or not all(isinstance(v, str) and v.strip() for v in value):
        raise _err(where, f"must be a non-empty list of filter names; got {show(value)}")
    if len(set(value)) != len(value):
        dup = next(v for v in value if value.count(v) > 1)
        raise _err(where, f"must not name a filter twice; {dup!r} is given twice")
    for i, v in enumerate(value):
        if allowed is not None and v not in allowed:
            raise _err(f"{where}[{i}]", f"must be one of the league's filters {', '.join(allowed)}; got {v!r}"
                       f"{suggest(v, allowed)}")
    return tuple(value)


def install_command(folder: Path) -> str:
    """``pip install -e FOLDER``, the folder as one would type it from the current folder."""
    import os
    import shlex

    try:
        shown = os.path.relpath(folder)
    except ValueError:  # another drive
        shown = str(folder)
    if Path(shown).parts[:1] == ("..",) and Path(shown).parts.count("..") >= len(Path.cwd().parts) - 1:
        shown = str(folder)  # up to the root and down again: the whole path reads better
    return f"pip install -e {shlex.quote(shown)}"


def _plugins(path: Path, data: dict, names: tuple) -> dict:
    """The league file's ``plugins`` table checked: ``{filter: its plugin's folder}``, each a filter of
    the league that is not built in, each folder (relative to the league file) a Python project."""
    from mcjax.tracking.filters.registry import BUILTIN

    raw = data.get("plugins", {})
    where = f"{path.name}: plugins"
    if not isinstance(raw, dict):
        raise _err(where, f"must be a table of filter name = the plugin's folder (relative to the league file), "
                   f'e.g. plugins = {{ my_filter = "../plugins/my_filter" }}; got {show(raw)}')
    out = {}
    for name, folder in raw.items():
        at = f"{where}.{key_text(name)}"
        if name in BUILTIN:
            raise _err(at, f"{name!r} is a built-in filter, not a plugin")
        if name not in names:
            raise _err(at, f"names no filter of the league (its filters: {', '.join(names)})")
        if not isinstance(folder, str) or not folder.strip():
            raise _err(at, f"must be the plugin's folder (relative to the league file); got {show(folder)}")
        full = (path.parent / folder).resolve()
        if not any((full / f).is_file() for f in ("pyproject.toml", "setup.py")):
            raise _err(at, f"{folder!r} is not a plugin's folder: {full} holds no pyproject.toml or setup.py")
        out[name] = full
    return out


def _filters(path: Path, data: dict) -> tuple[tuple, dict]:
    from mcjax.tracking.filters import registry

    names = _names(f"{path.name}: filters", data.get("filters"))
    plugins = _plugins(path, data, names)
    config_names = {}
    for i, name in enumerate(names):
        try:
            registry.get(name, path.parent)
        except ValueError as exc:
            if name in plugins and name not in registry.known():
                raise _err(f"{path.name}: filters[{i}]", f"filter {name!r} is a plugin that is not installed: "
                           f"{install_command(plugins[name])}") from None
            raise _err(f"{path.name}: filters[{i}]", " ".join(str(exc).split())) from None
        config_names[name] = absolute_reference(name, path.parent)  # the same file from any folder or worker
    return names, config_names


def _tables(where: str, data: dict, key: str, keys: tuple) -> dict:
    from mcjax.study.sweep_tables import named_tables

    raw = data.get(key)
    for name, at, table in named_tables(f"{where}{key}", raw, keys, LeagueError,
                                        missing=f"must name at least one ([{key}.NAME] tables)",
                                        bad_name="a name must be letters, digits, '_', '-' or '.' (it names an "
                                                 "output folder)"):
        for sub in ("config", "params"):
            subtable(f"{at}.", table, sub)
        if "description" in table and not isinstance(table["description"], str):
            raise _err(f"{at}.description", f"must be a string; got {show(table['description'])}")
    return raw


def cell_spec(table: dict, point: dict, filters: list, data: dict) -> dict:
    """The sweep spec of one scenario (``table``) at one ``point`` running ``filters`` (Config names);
    ``data``: the league file's tables (its ``base_seed``, ``chunk_size``)."""
    spec = {"base": table["base"], "config": {**table.get("config", {}), **point.get("config", {}),
                                              "filters": filters},
            "params": {**table.get("params", {}), **point.get("params", {})}}
    for key in ("base_seed", "chunk_size"):
        if key in data:
            spec[key] = data[key]
    return spec


def load_league(path: str | Path, *, seeds: int | None = None) -> League:
    """Read and check the league file ``path`` (module docstring); ``seeds``: runs per cell over the
    file's. Raises :class:`LeagueError` (one line naming the key path) before anything runs."""
    from mcjax.study.sweep_tables import load_checked

    return load_checked(_load, path, seeds, LeagueError)


def _load(path: Path, seeds: int | None) -> League:
    from mcjax.study.spec import MAX_SEEDS, build_spec

    data = read_toml(path, "league file")
    where = f"{path.name}: "
    check_keys(where, data, FILE_KEYS)
    for key in ("title", "description"):
        if key in data and not isinstance(data[key], str):
            raise _err(f"{where}{key}", f"must be a string; got {show(data[key])}")
    seeds_where = "--seeds" if seeds is not None else f"{where}seeds"
    seeds = count(seeds_where, seeds if seeds is not None else data.get("seeds", DEFAULT_SEEDS), 1, MAX_SEEDS)
    timing = count(f"{where}timing_runs", data.get("timing_runs", DEFAULT_TIMING_RUNS), 0, MAX_TIMING_RUNS)
    names, config_names = _filters(path, data)
    scen_tables = _tables(where, data, "scenarios", SCENARIO_KEYS)
    points = _tables(where, data, "points", POINT_KEYS)
    entries, studies = {}, {}
    for key, table in scen_tables.items():
        at = f"{where}scenarios.{key_text(key)}"
        if not isinstance(table.get("base"), str) or not table["base"].strip():
            raise _err(f"{at}.base", "missing; give the scenario's config file (configs/*.toml), relative to the "
                       "league file" if "base" not in table else f"must be a path; got {show(table['base'])}")
        own = _names(f"{at}.filters", table["filters"], names) if "filters" in table else names
        own = tuple(f for f in names if f in own)  # the league's order
        cfg_filters = [config_names[f] for f in own]
        for point, ptable in points.items():
            try:
                studies[key, point] = build_spec(cell_spec(table, ptable, cfg_filters, data),
                                                 path.parent, seeds=seeds)
            except SpecError as exc:
                raise _err(f"{at} at points.{key_text(point)}", " ".join(str(exc).split())) from None
        first = studies[key, next(iter(points))]
        notes = {}
        for f in names:
            if f in own:
                continue
            try:
                build_spec(cell_spec(table, next(iter(points.values())), [*cfg_filters, config_names[f]], data),
                           path.parent, seeds=1)
                notes[f] = "left out by the league file"
            except SpecError as exc:
                notes[f] = "cannot run here: " + _refusal(first.scenario, f, exc)
        entries[key] = Entry(key, first.scenario.name, own, notes)
    described = {p: t.get("description", p) for p, t in points.items()}
    source = json.loads(json.dumps(data, default=str))
    return League(path, data.get("title", path.stem), names, config_names, entries, described, studies, seeds,
                  timing, source)


def _refusal(scenario, name: str, exc: Exception) -> str:
    """Why ``scenario`` cannot run the filter ``name``, short: a built-in filter it does not offer is named
    with the ones it does; anything else is the scenario's own one-line refusal."""
    from mcjax.tracking.filters.registry import FILTER_KINDS  # loaded already: the league's filters were resolved

    setting = scenario.settings.get("filters")
    if setting is not None and name in FILTER_KINDS and name not in (setting.choices or ()):
        own = "; or a filter of one's own" if setting.plugins else ""
        return f"{scenario.name} offers no {name!r} (its filters: {', '.join(setting.choices)}{own})"
    return " ".join(str(exc).split())


def describe(league: League) -> str:
    """One line: scenarios × points × filters, runs per cell."""
    cells = sum(len(e.filters) for e in league.scenarios.values()) * len(league.points)
    return (f"{league.title}: {len(league.scenarios)} scenario(s) x {len(league.points)} point(s), "
            f"{len(league.filters)} filter(s) ({cells} cells run), {league.seeds} runs per cell")


def identity(league: League) -> dict[str, Any]:
    """What makes two leagues the same for ``--resume``: the file as read and the seeds."""
    return json.loads(json.dumps({"league": league.source, "seeds": league.seeds}, default=str))
