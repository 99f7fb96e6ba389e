"""Reading and validating specs: a sweep spec or a config file becomes a :class:`~mcjax.study.plan.Study`.

A config file (``configs/*.toml``) holds a scenario's ``[config]`` and ``[params]`` (and may
give ``seeds``, the paper's run count, used when the spec or ``mcjax run`` gives none). A sweep
spec (``sweeps/*.toml``) names a base config file and adds overrides and axes::

    base = "../configs/sun2011.toml"   # relative to the spec file
    seeds = 100
    base_seed = 0
    chunk_size = 1000
    timeseries = false  # true: also write OUT/timeseries/ (one row per run, step and filter)
    [sensitivity] # derivatives of outputs by Params on the smooth system (mcjax.study.sensitivity)
    params = ["comm_radius"]
    [config]      # Config overrides (recompile)
    [params]      # Params overrides
    [grid]        # axes combined as a cartesian product
    comm_radius = [60e3, 80e3, 100e3]                  # an explicit list
    sigma_bearing = {linspace = [0.005, 0.03, 6]}       # start, stop, count
    sensing_radius = {logspace = [5e4, 2e5, 4]}         # geometric from start to stop
    [zip]         # axes of equal length walked together (one more product axis)
    uav_speed = [600.0, 800.0]
    turn_rate_max = [0.1, 0.2]

Every check derives from the scenario's declarations (:mod:`mcjax.contract`) and is made by
:mod:`mcjax.base.validation`; a bad spec stops with one :class:`SpecError` naming the key path, before
anything compiles or is written. A spec with several mistakes gets one line for each mistake that is
found on its own (:func:`build_spec`).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any, Mapping, NamedTuple

import numpy as np

from mcjax import scenarios
from mcjax.contract import Scenario
from mcjax.base.plugins import absolute_reference
from mcjax.base.validation import (Mistakes, SpecError, check_keys, check_text, count, got, is_int, is_number, key_text,
                                   near_path, one_line, read_toml, setting_problem, show, subtable, unknown_key)
from mcjax.study.plan import DEFAULT_SEEDS, Study, check_memory
from mcjax.study.sensitivity import read_sensitivity

SPEC_KEYS = ("scenario", "base", "seeds", "base_seed", "chunk_size", "config", "params", "grid", "zip",
             "description", "timeseries", "sensitivity")
CONFIG_FILE_KEYS = ("scenario", "config", "params", "description", "seeds")
RANGE_KINDS = ("linspace", "logspace")

# Declared upper bounds of a sweep: what one machine can hold or finish. Each is checked
# before anything is allocated (a 10**12-seed spec is refused, not tried).
#: Seeds per point.
MAX_SEEDS = 10_000_000
#: Values of one axis, and points of a whole sweep (grid product x zipped block).
MAX_POINTS = 100_000
#: Runs of a sweep (points x seeds): 10 million runs are days of work on one machine.
MAX_RUNS = 10_000_000
#: Runs per chunk (the memory check below may allow fewer).
MAX_CHUNK_SIZE = 1_000_000
#: base_seed is a 32-bit unsigned integer (the engine's keys are made of 32-bit words).
MAX_BASE_SEED = 2**32 - 1

#: How a message names the values given beside a spec: the command line's options (``mcjax sweep --seeds 0``:
#: ``--seeds: …``), the default, or the keyword arguments of :mod:`mcjax.notebook` (``mc.sweep(…, seeds=0)``:
#: ``seeds: …``). Keys: ``seeds``, ``chunk_size``, ``set``.
COMMAND_LINE = {"seeds": "--seeds", "chunk_size": "--chunk-size", "set": "--set"}
KEYWORDS = {"seeds": "seeds", "chunk_size": "chunk_size", "set": "set"}


def _set_text(path, given_as: Mapping[str, str], value=None, example: bool = False, quote: bool = True) -> str:
    """An override as its giver wrote it: ``--set params.x`` (``quote``: a key TOML would quote, quoted; as an
    example, ``--set 'grid.x=[...]'``) on the command line, ``set['params.x']`` (``set={'grid.x': [...]}``)
    from Python."""
    if given_as["set"].startswith("--"):
        if example:
            return f"{given_as['set']} '{path}={value}'"
        return f"{given_as['set']} {key_text(path) if quote else path}"
    return f"{given_as['set']}={{{str(path)!r}: {value}}}" if example else f"{given_as['set']}[{str(path)!r}]"


def _see_all(scenario: Scenario, config_path: Path | None = None) -> str:
    """Where a scenario's every Config and Params key is listed: ``mcjax list NAME`` (a built-in or installed
    scenario), else ``mcjax list --config FILE`` (a scenario of a file, named by its config file)."""
    if scenario.name in scenarios.BUILTIN or config_path is None or scenario.name in scenarios.known():
        return f"`mcjax list {scenario.name}`"
    return f"`mcjax list --config {config_path}`"


def _build_config(scenario: Scenario, table: dict, where: str, see: str | None = None):
    """The Config from a table of values: every field against its Setting first (exact kinds,
    declared ranges and ceilings; ``where`` + field named; every unknown key and bad field, one
    line each), then the scenario's checks across fields (the first that fails). ``see``: where
    every key is listed."""
    lines = [unknown_key(where, k, list(scenario.settings), see) for k in table if k not in scenario.settings]
    values = {}
    for k, v in table.items():
        s = scenario.settings.get(k)
        if s is None:
            continue
        v = tuple(v) if s.many and isinstance(v, list) else v
        msg = setting_problem(k, s, v)
        if msg:
            lines.append(f"{where}{k}: {msg}")
        values[k] = v
    if lines:
        raise SpecError("\n".join(lines))
    try:
        return scenario.Config(**values)
    except (TypeError, ValueError) as exc:
        text = one_line(exc)
        # the scenario's checks across fields open with the field they blame ("warmup_steps must …")
        field, _, rest = text.partition(" ")
        if field in scenario.settings and rest:
            raise SpecError(f"{where}{field}: {rest}") from None
        raise SpecError(f"{where.rstrip('.')}: {text}") from None


def _absolute_filters(table: dict, base_dir: str | Path) -> dict:
    """``table`` (a ``[config]`` table) with each ``"file.py:ATTRIBUTE"`` of its ``filters`` made absolute against
    ``base_dir``, the folder of the file that wrote it (:func:`mcjax.base.plugins.absolute_reference`): a
    filter file sits beside its config or spec, as a scenario file does, and names the same file on a worker."""
    filters = table.get("filters") if isinstance(table, dict) else None
    if isinstance(filters, (list, tuple)):
        return {**table, "filters": [absolute_reference(f, base_dir) for f in filters]}
    if isinstance(filters, str):  # --set config.filters=NAME: a one-item list, made so later
        return {**table, "filters": absolute_reference(filters, base_dir)}
    return table


def _check_params(scenario: Scenario, cfg, table: dict, where: str, see: str | None = None) -> None:
    """Every value against its declaration, read exactly (kinds, range, shape for ``cfg``; without
    ``cfg``, a Config that has mistakes of its own, no shape): every unknown key and bad value, one line
    each. ``see``: where every key is listed."""
    lines = []
    for k, v in table.items():
        p = scenario.params_table.get(k)
        msg = p.problem(v, exact=True, cfg=cfg) if p is not None else None
        if p is None:
            lines.append(unknown_key(where, k, list(scenario.params_table), see))
        elif msg:
            lines.append(f"{where}{k}: {msg}")
    if lines:
        raise SpecError("\n".join(lines))


def _axis_values(where: str, v, integral: bool) -> list:
    """An axis given as a list, or as ``{linspace = [a, b, n]}`` / ``{logspace = [a, b, n]}``
    (at most :data:`MAX_POINTS` values; an integer field's range must give integers)."""
    if isinstance(v, dict):
        check_keys(f"{where}.", v, RANGE_KINDS)
        if len(v) != 1:
            raise SpecError(f"{where}: a range must be {{linspace = [start, stop, count]}} or "
                            f"{{logspace = [start, stop, count]}}; got {show(v)}")
        kind, args = next(iter(v.items()))
        if (not isinstance(args, list) or len(args) != 3 or not all(is_number(a) for a in args[:2])
                or not all(math.isfinite(a) for a in args[:2]) or not is_int(args[2]) or args[2] < 1):
            raise SpecError(f"{where}.{kind}: must be [start, stop, count] with finite numbers start and stop "
                            f"and an integer count >= 1; got {show(args)}")
        a, b, n = args
        if n > MAX_POINTS:
            raise SpecError(f"{where}.{kind}: count must be an integer in [1, {MAX_POINTS}]; got {n}")
        if kind == "logspace":
            if not (a > 0 and b > 0):
                raise SpecError(f"{where}.logspace: start and stop must be > 0; got {show(args)}")
            values = np.geomspace(a, b, n).tolist()
        else:
            values = np.linspace(a, b, n).tolist()
        if integral:
            ints = [round(x) for x in values]
            if any(abs(x - i) > 1e-9 * max(1.0, abs(x)) for x, i in zip(values, ints)):
                raise SpecError(f"{where}.{kind}: must give integers for an integer field (choose start, stop and "
                                f"count so, or list the values); got {show(values)}")
            values = ints
        return values
    if not isinstance(v, list) or not v:
        raise SpecError(f"{where}: must be a non-empty list of values or a linspace/logspace range; got {show(v)}")
    if len(v) > MAX_POINTS:
        raise SpecError(f"{where}: must have at most {MAX_POINTS} values; got {len(v)}")
    return v


def _same_shape(where: str, values: list, param, cfg) -> list:
    """An axis's values with one shape, so its points stack into one array: a per-agent
    field's numbers become one per agent when some value lists them (``[450.0, [400.0, …]]``);
    any other field's values must already agree."""
    arrays = [np.asarray(v, np.float64) for v in values]
    shapes = {a.shape for a in arrays}
    if len(shapes) == 1:
        return values
    if param.per_agent:
        return [np.broadcast_to(a, (cfg.n_agents,)).tolist() for a in arrays]
    raise SpecError(f"{where}: must hold values of one shape (they are the points of one array); got shapes "
                    f"{', '.join(sorted('x'.join(map(str, sh)) or 'scalar' for sh in shapes))}")


def _distinct(values) -> str | None:
    """The first value given twice (as text), or None."""
    seen = set()
    for v in values:
        text = json.dumps(v)
        if text in seen:
            return text
        seen.add(text)
    return None

def is_sweep_spec(data: dict) -> bool:
    """A sweep spec names a base config file."""
    return "base" in data


def is_config_file(data: dict) -> bool:
    """A config file names a scenario and no base."""
    return "scenario" in data and "base" not in data


class ConfigFile(NamedTuple):
    """A ``configs/*.toml`` file, read once and validated."""

    scenario: Scenario
    config: Any          # the scenario's Config
    params: dict         # Params values given by the file
    seeds: int | None    # the paper's run count, if the file gives one
    path: Path


def read_config_file(path: str | Path, what: str = "config file") -> ConfigFile:
    """Read and validate a config file (scenario, ``[config]``, ``[params]``, ``seeds``)."""
    path = Path(path)
    data = read_toml(path, what)
    where = f"{path.name}: "
    if is_sweep_spec(data):
        raise SpecError(f"{path} is a sweep spec (it names a base config), not a config file: run it with "
                        f"`mcjax sweep {path}`, or name a config file (configs/*.toml)")
    check_keys(where, data, CONFIG_FILE_KEYS)
    seeds = data.get("seeds")
    if seeds is not None:
        count(f"{where}seeds", seeds, 1, MAX_SEEDS)
    check_text(where, data, "description")
    if "scenario" not in data:
        raise SpecError(f"{where}scenario: missing; allowed: {', '.join(scenarios.known())}")
    if not isinstance(data["scenario"], str) or not data["scenario"]:
        raise SpecError(f"{where}scenario: must be one of {', '.join(scenarios.known())} (or 'file.py:ATTRIBUTE'); "
                        f"got {show(data['scenario'])}")
    try:
        scenario = scenarios.get(data["scenario"], base_dir=path.parent)
    except (ValueError, ImportError) as exc:  # unknown name, missing file or module; a bug inside a
        raise SpecError(f"{where}scenario: {one_line(exc)}") from None  # scenario keeps its traceback
    see = _see_all(scenario, path)
    mistakes = Mistakes()
    cfg = None
    with mistakes.check():
        cfg = _build_config(scenario, _absolute_filters(subtable(where, data, "config"), path.parent), f"{where}config.",
                            see)
    params = {}
    with mistakes.check():
        params = dict(subtable(where, data, "params"))
        _check_params(scenario, cfg, params, f"{where}params.", see)
    mistakes.stop()
    return ConfigFile(scenario, cfg, params, seeds, path)


def load_config_file(path: str | Path):
    """``(scenario, Config, params dict)`` of a config file (see :func:`read_config_file`)."""
    f = read_config_file(path)
    return f.scenario, f.config, f.params


def load_spec(path: str | Path, *, seeds: int | None = None, chunk_size: int | None = None,
              overrides: dict[str, Any] | None = None, out_dir: str | Path | None = None,
              given_as: Mapping[str, str] = COMMAND_LINE) -> Study:
    """Read and validate a sweep spec file; raises :class:`SpecError` naming the key path.
    ``base`` is relative to the spec's folder; ``out_dir``: the study's output folder; ``given_as``:
    how messages name ``seeds``, ``chunk_size`` and the overrides (:data:`COMMAND_LINE`, :data:`KEYWORDS`)."""
    path = Path(path)
    data = read_toml(path, "sweep spec")
    if is_config_file(data):
        raise SpecError(f"{path} is a config file (it names a scenario), not a sweep spec: run one point with "
                        f"`mcjax run {path}`, or name it as `base` in a sweep spec")
    return build_spec(data, path.parent, seeds=seeds, chunk_size=chunk_size, overrides=overrides, out_dir=out_dir,
                      given_as=given_as)


def _apply_overrides(data: dict, overrides: Mapping[str, Any], given_as: Mapping[str, str] = COMMAND_LINE) -> None:
    """Set each ``"table.key"`` path of ``overrides`` in ``data`` (tables created as needed)."""
    for path, value in overrides.items():
        parts = str(path).split(".")
        if not all(parts):
            raise SpecError(f"{_set_text(path, given_as)}: must be a key path such as params.comm_radius")
        target = data
        for i, part in enumerate(parts[:-1]):
            target = target.setdefault(part, {})
            if not isinstance(target, dict):
                where = ".".join(parts[:i + 1])
                raise SpecError(f"{_set_text(path, given_as, quote=False)}: {where} is not a table; got {got(target)}")
        target[parts[-1]] = value


def build_spec(data: dict, base_dir: str | Path, *, seeds: int | None = None, chunk_size: int | None = None,
               overrides: dict[str, Any] | None = None, out_dir: str | Path | None = None,
               given_as: Mapping[str, str] = COMMAND_LINE) -> Study:
    """Validate a sweep spec given as a dict (the TOML's tables); ``base`` is relative to
    ``base_dir``. ``overrides`` maps key paths (``"params.comm_radius"``) to values; a string
    given for a list Config field (``config.filters = "NAME"``) is a one-item list. ``given_as``:
    how messages name ``seeds``, ``chunk_size`` and the overrides (:data:`COMMAND_LINE`, the
    default, or :data:`KEYWORDS`).

    A spec with several mistakes gets them all, one line each, in one :class:`SpecError`: every
    unknown key of every table, every bad value of ``[config]``, ``[params]``, ``[grid]`` and ``[zip]``
    (each checked on its own; ``[params]`` without a shape check when ``[config]`` has mistakes; of the
    base file's values a changed ``[config]`` makes wrong, the first) and of ``seeds``, ``chunk_size``,
    ``base_seed`` and ``timeseries``. The checks that need all of
    those right — a Config's fields together, ``[zip]``'s lengths, the number of points and runs, the
    scenario's checks across Params, the memory a chunk needs — come after, and the first that
    fails stops. A missing or unreadable ``base`` (or a mistake inside it) stops at once."""
    overrides = dict(overrides or {})
    data = json.loads(json.dumps(data))  # a deep copy: the overrides never touch the caller's dict
    if isinstance(data.get("config"), dict):  # the spec's filter files beside the spec, the command line's here
        data["config"] = _absolute_filters(data["config"], base_dir)
    if "config.filters" in overrides:
        overrides["config.filters"] = _absolute_filters({"filters": overrides["config.filters"]}, Path.cwd())["filters"]
    _apply_overrides(data, overrides, given_as)
    mistakes = Mistakes()
    with mistakes.check():
        check_keys("", data, SPEC_KEYS)
    for key in ("description", "scenario"):
        with mistakes.check():
            check_text("", data, key)
    for key in ("config", "params", "grid", "zip"):
        with mistakes.check():
            subtable("", data, key)
    tables = {key: data.get(key, {}) if isinstance(data.get(key, {}), dict) else {}
              for key in ("config", "params", "grid", "zip")}
    if "base" not in data:
        mistakes.lines.append("base: missing; give the config file the sweep starts from")
        mistakes.stop()
    if not isinstance(data["base"], str) or not data["base"].strip():
        mistakes.lines.append(f"base: must be the path of a config file (configs/*.toml), relative to the spec; "
                              f"got {got(data['base'])}")
        mistakes.stop()
    base_path = (Path(base_dir) / data["base"]).resolve()
    if base_path.is_dir():
        mistakes.lines.append(f"base: {data['base']!r} is a folder ({base_path}), not a config file (configs/*.toml)")
    elif not base_path.exists():
        mistakes.lines.append(f"base: config file not found: {base_path}{near_path(data['base'], base_path)}")
    mistakes.stop()
    with mistakes.check():
        base = read_config_file(base_path)
    mistakes.stop()  # the base's own mistakes: nothing of the spec can be checked without it
    scenario, cfg, params = base.scenario, base.config, dict(base.params)
    see = _see_all(scenario, base_path)
    if "scenario" in data and isinstance(data["scenario"], str) and data["scenario"] != scenario.name:
        mistakes.lines.append(f"scenario: must be the base config's {scenario.name!r} (or left out); got "
                              f"{data['scenario']!r}")
    cfg_over = dict(tables["config"])
    for path, value in overrides.items():  # --set config.filters=NAME: a one-item list
        table, _, name = str(path).partition(".")
        s = scenario.settings.get(name)
        if table == "config" and s is not None and s.many and isinstance(value, str):
            cfg_over[name] = [value]
            data["config"][name] = [value]
    if cfg_over:
        cfg = None  # unless [config] is right: [params] and the axes are then checked without their shapes
        with mistakes.check():
            cfg = _build_config(scenario, {**dataclasses.asdict(base.config), **cfg_over}, "config.", see)
    spec_params = tables["params"]
    with mistakes.check():
        _check_params(scenario, cfg, spec_params, "params.", see)
    params.update(spec_params)
    if cfg_over and cfg is not None:  # the base file's values again, against the final Config (e.g. a new n_agents)
        swept = {*tables["grid"], *tables["zip"]}
        try:
            _check_params(scenario, cfg, {k: v for k, v in base.params.items() if k not in spec_params and k not in swept},
                          f"{base.path.name}: params.", see)
        except SpecError as exc:  # the consequences of one change of [config]: the first of them
            mistakes.lines.append(str(exc).splitlines()[0])
    wrong = {k for k in spec_params if any(line.startswith(f"params.{k}: ") for line in mistakes.lines)}
    axes = {}
    for table in ("grid", "zip"):
        raw = tables[table]
        with mistakes.check():
            check_keys(f"{table}.", raw, list(scenario.params_table), see)
        axes[table] = {}
        for k, v in raw.items():
            if k not in scenario.params_table:
                continue
            with mistakes.check():  # a [params] value already wrong is not told again that it is swept
                axes[table][k] = _axis(table, k, v, scenario, cfg, {p: 1 for p in spec_params if p not in wrong},
                                       given_as)
    with mistakes.check():
        seeds_where = given_as["seeds"] if seeds is not None else "seeds"
        if seeds is None:  # the spec's seeds, else the config file's (the paper's run count), else DEFAULT_SEEDS
            seeds = data.get("seeds", base.seeds if base.seeds is not None else DEFAULT_SEEDS)
        count(seeds_where, seeds, 1, MAX_SEEDS)
    chunk_where = given_as["chunk_size"] if chunk_size is not None else "chunk_size"
    with mistakes.check():
        chunk = count(chunk_where, data.get("chunk_size", 1000) if chunk_size is None else chunk_size, 1, MAX_CHUNK_SIZE)
    with mistakes.check():
        base_seed = count("base_seed", data.get("base_seed", 0), 0, MAX_BASE_SEED)
    timeseries = data.get("timeseries", False)
    if not isinstance(timeseries, bool):
        mistakes.lines.append(f"timeseries: must be true or false; got {got(timeseries)}")
    elif timeseries and scenario.timeseries is None:
        mistakes.lines.append(f"timeseries: must be false: scenario {scenario.name!r} has no per-step series")
    mistakes.stop()
    # the checks across values: each needs the values above right
    grid, zipped = axes["grid"], axes["zip"]
    both = set(grid) & set(zipped)
    if both:
        raise SpecError(f"zip.{sorted(both)[0]}: must not also be a grid axis (grid.{sorted(both)[0]}); an axis goes "
                        f"in [grid] or in [zip]")
    lengths = {k: len(v) for k, v in zipped.items()}
    if len(set(lengths.values())) > 1:
        raise SpecError(f"zip: axes must have equal lengths; got {lengths}")
    if zipped and (dup := _distinct(list(zip(*zipped.values())))) is not None:
        raise SpecError(f"zip: must not repeat a point (each point once); {dup} is given twice "
                        f"({', '.join(zipped)})")
    n_points = math.prod(len(v) for v in grid.values()) * (next(iter(lengths.values())) if lengths else 1)
    if n_points > MAX_POINTS:
        sizes = " x ".join(str(len(v)) for v in [*grid.values(), *([next(iter(zipped.values()))] if zipped else [])])
        raise SpecError(f"{'grid' if grid else 'zip'}: the axes make {n_points} points ({sizes}); allowed: at most "
                        f"{MAX_POINTS} points per sweep")
    base_params = scenario.default_params(cfg, **params)
    if n_points * seeds > MAX_RUNS:
        raise SpecError(f"{seeds_where}: {n_points} point(s) x {seeds} seeds = {n_points * seeds} runs; allowed: at "
                        f"most {MAX_RUNS} runs per sweep ({seeds_where} <= {MAX_RUNS // n_points})")
    sensitivity = read_sensitivity(scenario, cfg, data.get("sensitivity"))
    spec = Study(scenario, cfg, base_params, grid, zipped, seeds, base_seed, chunk, data, timeseries,
                 json.loads(json.dumps(overrides)), None if out_dir is None else Path(out_dir), sensitivity)
    _check_points(spec, params)
    check_memory(spec, chunk_where)
    return spec


def _axis(table: str, k: str, v, scenario: Scenario, cfg, spec_params: dict, given_as: Mapping[str, str]) -> list:
    """The values of the axis ``k`` of ``[grid]`` or ``[zip]`` (``table``), each checked against its
    declaration (its shape too, and one shape for all, when ``cfg`` is known)."""
    p = scenario.params_table[k]
    values = _axis_values(f"{table}.{k}", v, p.integral())
    for value in values:
        _check_params(scenario, cfg, {k: value}, f"{table}.")
    if cfg is not None:
        values = _same_shape(f"{table}.{k}", values, p, cfg)
    if table == "grid" and (dup := _distinct(values)) is not None:
        raise SpecError(f"grid.{k}: must not repeat a value (each point once); {dup} is given twice")
    if k in spec_params:
        raise SpecError(f"params.{k}: must not be set while {table}.{k} sweeps it; change the axis instead "
                        f"({table}.{k} = [...], or {_set_text(f'{table}.{k}', given_as, '[...]', example=True)})")
    return values


def _check_points(spec: Study, params: dict) -> None:
    """Checks across fields that depend on the Config (e.g. t_r <= max_horizon), over every point."""
    check = spec.scenario.check_params
    if check is None:
        return
    merged = {**params, **{axis: np.asarray(getattr(spec.params, axis)) for axis in spec.axes}}
    bad = check(spec.config, merged)
    # a check written for one point may skip arrays with a point axis: each value of an axis of
    # vectors or matrices is checked on its own too (with the other fields at their base values)
    for axis in spec.axes:
        values = spec.grid.get(axis, spec.zipped.get(axis))
        for value in (values if not bad and np.ndim(values[0]) > 0 else []):
            bad = [(name, allowed) for name, allowed in check(spec.config, {**params, axis: np.asarray(value)})
                   if name == axis]
            if bad:
                raise SpecError(f"{'grid' if axis in spec.grid else 'zip'}.{axis}: must be {bad[0][1]}; "
                                f"got {show(value)}")
    for name, allowed in bad:
        where = "grid." if name in spec.grid else "zip." if name in spec.zipped else "params."
        if name in spec.axes:  # an axis: its distinct values
            values = spec.grid.get(name, spec.zipped.get(name))
            got = sorted(set(values)) if all(np.ndim(v) == 0 for v in values) else [
                json.loads(t) for t in dict.fromkeys(json.dumps(v) for v in values)]
            got = got if len(got) > 1 else got[0]
        else:  # as given
            got = np.asarray(merged.get(name, getattr(spec.base_params, name))).tolist()
        raise SpecError(f"{where}{name}: must be {allowed}; got {show(got)}")

