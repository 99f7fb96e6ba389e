"""Sweep specs → batched Params; point ids; running a sweep into a Parquet dataset.

A config file (``configs/*.toml``) holds a scenario's ``[config]`` and ``[params]`` (and may
give ``seeds``, the paper's run count, used when the spec or ``mcjax run`` gives none). A sweep
spec (``sweeps/*.toml``) names a base config file and adds overrides and axes::

    base = "../configs/sun2011.toml"   # relative to the spec file
    seeds = 100
    base_seed = 0
    chunk_size = 1000
    timeseries = false  # true: also write OUT/timeseries/ (one row per run, step and filter)
    [config]      # Config overrides (recompile)
    [params]      # Params overrides
    [grid]        # axes combined as a cartesian product
    comm_radius = [60e3, 80e3, 100e3]                  # an explicit list
    sigma_bearing = {linspace = [0.005, 0.03, 6]}       # start, stop, count
    sensing_radius = {logspace = [5e4, 2e5, 4]}         # geometric from start to stop
    [zip]         # axes of equal length walked together (one more product axis)
    uav_speed = [600.0, 800.0]
    turn_rate_max = [0.1, 0.2]

Points are the product of the grid axes (in the order written) and the zipped block;
``point_id`` numbers them in that order.

This module owns the whole path from a spec to Parquet rows: reading and validating specs
(every check derives from the scenario's declarations, :mod:`mcjax.contract`), the points
and their Params, the tidy rows (:func:`run_rows`, also used by the benchmarks), the output
folder's identity file and ``--resume`` bookkeeping.
"""

from __future__ import annotations

import dataclasses
import difflib
import itertools
import json
import math
import os
import re
import shutil
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, NamedTuple, Protocol

import numpy as np
import pandas as pd

from mcjax import scenarios
from mcjax.contract import Scenario, setting_problem

SPEC_KEYS = ("scenario", "base", "seeds", "base_seed", "chunk_size", "config", "params", "grid", "zip",
             "description", "timeseries")
CONFIG_FILE_KEYS = ("scenario", "config", "params", "description", "seeds")
RANGE_KINDS = ("linspace", "logspace")
#: Seeds per point when neither the spec nor the config file gives a number.
DEFAULT_SEEDS = 20

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
#: A count Config field this many times its scenario default makes the spec's batch program
#: get measured (traced once, not compiled) against the memory budget.
MEASURE_FACTOR = 10
#: Rows held in memory per chunk cost about this many times their raw 8-byte cells (the
#: outputs, the DataFrame, its sorted copy, the Arrow table).
ROW_COPIES = 4
#: Arrays alive at once in one step, in units of its largest array.
STEP_COPIES = 4


class SpecError(ValueError):
    """A sweep spec or config file is invalid; the message names the key path."""


_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def _key(key) -> str:
    """A key as TOML writes it: bare if it can be, else quoted (so a message stays one line)."""
    return key if isinstance(key, str) and _BARE_KEY.match(key) else json.dumps(str(key))


def _show(value) -> str:
    """A value on one line, cut to a readable length."""
    text = repr(value).replace("\n", " ")
    return text if len(text) <= 120 else text[:100] + f"... ({len(text)} characters)"


def _one_line(text) -> str:
    return " ".join(str(text).split())


def _suggest(key, allowed):
    close = difflib.get_close_matches(str(key), allowed, n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _check_keys(where, table, allowed):
    for key in table:
        if key not in allowed:
            raise SpecError(f"{where}{_key(key)}: unknown key{_suggest(key, allowed)}; allowed: {', '.join(allowed)}")


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _count(where: str, value, low: int, high: int) -> int:
    """An integer count in [low, high] (a boolean or a float is no count)."""
    if not _is_int(value) or not low <= value <= high:
        raise SpecError(f"{where}: must be an integer in [{low}, {high}]; got {_show(value)}")
    return value


def _table(where: str, data: dict, key: str) -> dict:
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise SpecError(f"{where}{key}: must be a table ([{key}] with one key = value per line); got {_show(value)}")
    return value


def _text(where: str, data: dict, key: str) -> None:
    if key in data and not isinstance(data[key], str):
        raise SpecError(f"{where}{key}: must be a string; got {_show(data[key])}")


@dataclass(frozen=True)
class SweepSpec:
    """A validated sweep: scenario, config, base params, grid axes and seeds."""

    scenario: Scenario
    config: Any
    base_params: Any
    grid: dict = field(default_factory=dict)
    zipped: dict = field(default_factory=dict)
    seeds: int = DEFAULT_SEEDS
    base_seed: int = 0
    chunk_size: int = 1000
    source: dict = field(default_factory=dict)
    timeseries: bool = False
    overrides: dict = field(default_factory=dict)   # the --set values, as given

    @property
    def axes(self) -> list[str]:
        """Every swept Params field: the grid axes, then the zipped ones."""
        return [*self.grid, *self.zipped]

    @property
    def n_points(self) -> int:
        n = int(np.prod([len(v) for v in self.grid.values()])) if self.grid else 1
        return n * (len(next(iter(self.zipped.values()))) if self.zipped else 1)

    @property
    def n_runs(self) -> int:
        return self.n_points * self.seeds


def _build_config(scenario: Scenario, table: dict, where: str):
    """The Config from a table of values: every field against its Setting first (exact kinds,
    declared ranges and ceilings; ``where`` + field named), then the scenario's checks across
    fields."""
    _check_keys(where, table, list(scenario.settings))
    values = {}
    for k, v in table.items():
        s = scenario.settings[k]
        v = tuple(v) if s.many and isinstance(v, list) else v
        msg = setting_problem(k, s, v)
        if msg:
            raise SpecError(f"{where}{k}: {msg}")
        values[k] = v
    try:
        return scenario.Config(**values)
    except (TypeError, ValueError) as exc:
        text = _one_line(exc)
        # the scenario's checks across fields open with the field they blame ("warmup_steps must …")
        field, _, rest = text.partition(" ")
        if field in scenario.settings and rest:
            raise SpecError(f"{where}{field}: {rest}") from None
        raise SpecError(f"{where.rstrip('.')}: {text}") from None


def _check_params(scenario: Scenario, cfg, table: dict, where: str) -> None:
    """Every value against its declaration, read exactly (kinds, range, shape for ``cfg``)."""
    _check_keys(where, table, list(scenario.params_table))
    for k, v in table.items():
        msg = scenario.params_table[k].problem(v, exact=True, cfg=cfg)
        if msg:
            raise SpecError(f"{where}{k}: {msg}")


def _axis_values(where: str, v, integral: bool) -> list:
    """An axis given as a list, or as ``{linspace = [a, b, n]}`` / ``{logspace = [a, b, n]}``
    (at most :data:`MAX_POINTS` values; an integer field's range must give integers)."""
    if isinstance(v, dict):
        _check_keys(f"{where}.", v, RANGE_KINDS)
        if len(v) != 1:
            raise SpecError(f"{where}: a range must be {{linspace = [start, stop, count]}} or "
                            f"{{logspace = [start, stop, count]}}; got {_show(v)}")
        kind, args = next(iter(v.items()))
        if (not isinstance(args, list) or len(args) != 3 or not all(_is_number(a) for a in args[:2])
                or not all(math.isfinite(a) for a in args[:2]) or not _is_int(args[2]) or args[2] < 1):
            raise SpecError(f"{where}.{kind}: must be [start, stop, count] with finite numbers start and stop "
                            f"and an integer count >= 1; got {_show(args)}")
        a, b, n = args
        if n > MAX_POINTS:
            raise SpecError(f"{where}.{kind}: count must be an integer in [1, {MAX_POINTS}]; got {n}")
        if kind == "logspace":
            if not (a > 0 and b > 0):
                raise SpecError(f"{where}.logspace: start and stop must be > 0; got {_show(args)}")
            values = np.geomspace(a, b, n).tolist()
        else:
            values = np.linspace(a, b, n).tolist()
        if integral:
            ints = [round(x) for x in values]
            if any(abs(x - i) > 1e-9 * max(1.0, abs(x)) for x, i in zip(values, ints)):
                raise SpecError(f"{where}.{kind}: must give integers for an integer field (choose start, stop and "
                                f"count so, or list the values); got {_show(values)}")
            values = ints
        return values
    if not isinstance(v, list) or not v:
        raise SpecError(f"{where}: must be a non-empty list of values or a linspace/logspace range; got {_show(v)}")
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


def _read_toml(path: Path, what: str) -> dict:
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
        raise SpecError(f"{path}: not valid TOML: {_one_line(exc)}") from None


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
    data = _read_toml(path, what)
    where = f"{path.name}: "
    if is_sweep_spec(data):
        raise SpecError(f"{path} is a sweep spec (it names a base config), not a config file: run it with "
                        f"`mcjax sweep {path}`, or name a config file (configs/*.toml)")
    _check_keys(where, data, CONFIG_FILE_KEYS)
    seeds = data.get("seeds")
    if seeds is not None:
        _count(f"{where}seeds", seeds, 1, MAX_SEEDS)
    _text(where, data, "description")
    if "scenario" not in data:
        raise SpecError(f"{where}scenario: missing; allowed: {', '.join(scenarios.known())}")
    if not isinstance(data["scenario"], str) or not data["scenario"]:
        raise SpecError(f"{where}scenario: must be one of {', '.join(scenarios.known())} (or 'file.py:ATTRIBUTE'); "
                        f"got {_show(data['scenario'])}")
    try:
        scenario = scenarios.get(data["scenario"], base_dir=path.parent)
    except (ValueError, ImportError) as exc:  # unknown name, missing file or module; a bug inside a
        raise SpecError(f"{where}scenario: {_one_line(exc)}") from None  # scenario keeps its traceback
    cfg = _build_config(scenario, _table(where, data, "config"), f"{where}config.")
    params = dict(_table(where, data, "params"))
    _check_params(scenario, cfg, params, f"{where}params.")
    return ConfigFile(scenario, cfg, params, seeds, path)


def load_config_file(path: str | Path):
    """``(scenario, Config, params dict)`` of a config file (see :func:`read_config_file`)."""
    f = read_config_file(path)
    return f.scenario, f.config, f.params


def load_spec(path: str | Path, *, seeds: int | None = None, chunk_size: int | None = None,
              overrides: dict[str, Any] | None = None) -> SweepSpec:
    """Read and validate a sweep spec file; raises :class:`SpecError` naming the key path.
    ``base`` is relative to the spec's folder."""
    path = Path(path)
    data = _read_toml(path, "sweep spec")
    if is_config_file(data):
        raise SpecError(f"{path} is a config file (it names a scenario), not a sweep spec: run one point with "
                        f"`mcjax run {path}`, or name it as `base` in a sweep spec")
    return build_spec(data, path.parent, seeds=seeds, chunk_size=chunk_size, overrides=overrides)


def _apply_overrides(data: dict, overrides: Mapping[str, Any]) -> None:
    """Set each ``"table.key"`` path of ``overrides`` in ``data`` (tables created as needed)."""
    for path, value in overrides.items():
        parts = str(path).split(".")
        if not all(parts):
            raise SpecError(f"--set {_key(path)}: must be a key path such as params.comm_radius")
        target = data
        for i, part in enumerate(parts[:-1]):
            target = target.setdefault(part, {})
            if not isinstance(target, dict):
                where = ".".join(parts[:i + 1])
                raise SpecError(f"--set {path}: {where} is not a table; got {_show(target)}")
        target[parts[-1]] = value


def build_spec(data: dict, base_dir: str | Path, *, seeds: int | None = None, chunk_size: int | None = None,
               overrides: dict[str, Any] | None = None) -> SweepSpec:
    """Validate a sweep spec given as a dict (the TOML's tables); ``base`` is relative to
    ``base_dir``. ``overrides`` maps key paths (``"params.comm_radius"``) to values; a string
    given for a list Config field (``config.filters = "NAME"``) is a one-item list."""
    overrides = dict(overrides or {})
    data = json.loads(json.dumps(data))  # a deep copy: the overrides never touch the caller's dict
    _apply_overrides(data, overrides)
    _check_keys("", data, SPEC_KEYS)
    for key in ("description", "scenario"):
        _text("", data, key)
    for key in ("config", "params", "grid", "zip"):
        _table("", data, key)
    if "base" not in data:
        raise SpecError("base: missing; give the config file the sweep starts from")
    if not isinstance(data["base"], str) or not data["base"].strip():
        raise SpecError(f"base: must be the path of a config file (configs/*.toml), relative to the spec; "
                        f"got {_show(data['base'])}")
    base_path = (Path(base_dir) / data["base"]).resolve()
    if base_path.is_dir():
        raise SpecError(f"base: {data['base']!r} is a folder ({base_path}), not a config file (configs/*.toml)")
    if not base_path.exists():
        raise SpecError(f"base: config file not found: {base_path}")
    base = read_config_file(base_path)
    scenario, cfg, params = base.scenario, base.config, dict(base.params)
    if "scenario" in data and data["scenario"] != scenario.name:
        raise SpecError(f"scenario: must be the base config's {scenario.name!r} (or left out); got "
                        f"{data['scenario']!r}")
    cfg_over = dict(data.get("config", {}))
    for path, value in overrides.items():  # --set config.filters=NAME: a one-item list
        table, _, name = str(path).partition(".")
        s = scenario.settings.get(name)
        if table == "config" and s is not None and s.many and isinstance(value, str):
            cfg_over[name] = [value]
            data["config"][name] = [value]
    if cfg_over:
        _check_keys("config.", cfg_over, list(scenario.settings))
        cfg = _build_config(scenario, {**dataclasses.asdict(cfg), **cfg_over}, "config.")
    spec_params = data.get("params", {})
    _check_params(scenario, cfg, spec_params, "params.")
    params.update(spec_params)
    if cfg_over:  # the base file's values again, against the final Config (e.g. a new n_agents)
        swept = {*data.get("grid", {}), *data.get("zip", {})}
        _check_params(scenario, cfg, {k: v for k, v in base.params.items() if k not in spec_params and k not in swept},
                      f"{base.path.name}: params.")
    axes = {}
    for table in ("grid", "zip"):
        raw = data.get(table, {})
        _check_keys(f"{table}.", raw, list(scenario.params_table))
        axes[table] = {}
        for k, v in raw.items():
            p = scenario.params_table[k]
            values = _axis_values(f"{table}.{k}", v, p.integer or (p.choices is not None and all(
                isinstance(c, int) for c in p.choices)))
            for value in values:
                _check_params(scenario, cfg, {k: value}, f"{table}.")
            values = _same_shape(f"{table}.{k}", values, p, cfg)
            if table == "grid" and (dup := _distinct(values)) is not None:
                raise SpecError(f"grid.{k}: must not repeat a value (each point once); {dup} is given twice")
            axes[table][k] = values
            if k in spec_params:
                raise SpecError(f"params.{k}: must not be set while {table}.{k} sweeps it; change the axis instead "
                                f"({table}.{k} = [...], or --set '{table}.{k}=[...]')")
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
    # the spec's seeds, else the config file's (the paper's run count), else DEFAULT_SEEDS
    seeds_where = "--seeds" if seeds is not None else "seeds"
    if seeds is None:
        seeds = data.get("seeds", base.seeds if base.seeds is not None else DEFAULT_SEEDS)
    _count(seeds_where, seeds, 1, MAX_SEEDS)
    if n_points * seeds > MAX_RUNS:
        raise SpecError(f"{seeds_where}: {n_points} point(s) x {seeds} seeds = {n_points * seeds} runs; allowed: at "
                        f"most {MAX_RUNS} runs per sweep ({seeds_where} <= {MAX_RUNS // n_points})")
    chunk_where = "--chunk-size" if chunk_size is not None else "chunk_size"
    chunk = _count(chunk_where, data.get("chunk_size", 1000) if chunk_size is None else chunk_size, 1, MAX_CHUNK_SIZE)
    base_seed = _count("base_seed", data.get("base_seed", 0), 0, MAX_BASE_SEED)
    timeseries = data.get("timeseries", False)
    if not isinstance(timeseries, bool):
        raise SpecError(f"timeseries: must be true or false; got {_show(timeseries)}")
    if timeseries and scenario.timeseries is None:
        raise SpecError(f"timeseries: must be false: scenario {scenario.name!r} has no per-step series")
    spec = SweepSpec(scenario, cfg, base_params, grid, zipped, seeds, base_seed, chunk, data, timeseries,
                     json.loads(json.dumps(overrides)))
    _check_points(spec, params)
    _check_memory(spec, chunk_where)
    return spec


def _check_points(spec: SweepSpec, params: dict) -> None:
    """Checks across fields that depend on the Config (e.g. t_r <= max_horizon), over every point."""
    check = spec.scenario.check_params
    if check is None:
        return
    table = points(spec)
    merged = {**params, **{axis: np.asarray(table[axis].tolist(), np.float64) for axis in spec.axes}}
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
                                f"got {_show(value)}")
    for name, allowed in bad:
        where = "grid." if name in spec.grid else "zip." if name in spec.zipped else "params."
        if name in spec.axes:  # an axis: its distinct values
            values = spec.grid.get(name, spec.zipped.get(name))
            got = sorted(set(values)) if all(np.ndim(v) == 0 for v in values) else [
                json.loads(t) for t in dict.fromkeys(json.dumps(v) for v in values)]
            got = got if len(got) > 1 else got[0]
        else:  # as given
            got = np.asarray(merged.get(name, getattr(spec.base_params, name))).tolist()
        raise SpecError(f"{where}{name}: must be {allowed}; got {_show(got)}")


# ------------------------------------------------------------------ memory of the chunk plan


def memory_budget() -> int:
    """Bytes a sweep may plan to hold at once: half of this machine's physical memory."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") // 2
    except (ValueError, OSError, AttributeError):
        return 8 * 2**30


def _gb(n: float) -> str:
    return f"{n / 2**30:.3g} GiB" if n >= 2**30 else f"{n / 2**20:.3g} MiB"


def _aval_bytes(aval) -> int:
    shape = getattr(aval, "shape", None)
    dtype = getattr(aval, "dtype", None)
    if shape is None or dtype is None:
        return 0
    try:
        return math.prod(shape) * np.dtype(dtype).itemsize
    except TypeError:  # key types and other extended dtypes
        return math.prod(shape) * 8


def _largest(jaxpr) -> int:
    """The largest array any equation of a jaxpr (and the jaxprs inside it) makes, in bytes."""
    from jax.extend.core import jaxprs_in_params

    top = 0
    for eqn in jaxpr.eqns:
        for v in eqn.outvars:
            top = max(top, _aval_bytes(v.aval))
        for sub in jaxprs_in_params(eqn.params):
            top = max(top, _largest(sub))
    return top


def step_sizes(spec: SweepSpec) -> tuple[int, int]:
    """``(record bytes, largest array bytes)`` of one step of one run of the spec's program,
    found by tracing ``init`` and ``step`` (nothing is compiled or run)."""
    import jax

    from mcjax import engine  # noqa: F401  (float64, as a run has it)

    params = jax.tree.map(lambda a: np.asarray(a)[0], point_params(spec))
    key = jax.random.PRNGKey(0)
    state = jax.eval_shape(lambda p, k: spec.scenario.init(spec.config, p, k), params, key)
    closed = jax.make_jaxpr(lambda p, s, k: spec.scenario.step(spec.config, p, s, k)[1])(params, state, key)
    record = sum(_aval_bytes(v.aval) for v in closed.jaxpr.outvars)
    return record, max(record, _largest(closed.jaxpr))


def _far_above_default(spec: SweepSpec) -> list[str]:
    """Integer Config fields at least :data:`MEASURE_FACTOR` times their scenario default."""
    out = []
    for name, s in spec.scenario.settings.items():
        value, default = getattr(spec.config, name), s.default
        if s.integer and isinstance(default, int) and value >= MEASURE_FACTOR * max(default, 1):
            out.append(name)
    return out


def _check_memory(spec: SweepSpec, chunk_where: str = "chunk_size") -> None:
    """Refuse a chunk plan that would not fit in :func:`memory_budget`, before anything is
    allocated: the rows of one chunk (and its per-step rows with ``timeseries``) from the
    declarations, and, when a count is far above its default, one batch's stacked records
    and largest arrays from a trace of the step."""
    from mcjax.engine import batch_size_for

    budget = memory_budget()
    b = batch_size_for(spec.n_runs)
    chunk = min(-(-spec.chunk_size // b) * b, -(-spec.n_runs // b) * b)
    cfg = spec.config
    F, T = len(cfg.filters), cfg.n_steps
    per_run = F * (len(spec.scenario.outputs(cfg)) + 4 + len(spec.axes)) * 8 * ROW_COPIES
    if spec.timeseries:
        per_run += F * T * (len(spec.scenario.timeseries_outputs(cfg)) + 4) * 8 * ROW_COPIES
    if chunk * per_run > budget:
        most = budget // per_run // b * b
        if most >= b:
            raise SpecError(f"{chunk_where}: a chunk of {chunk} runs would hold {_gb(chunk * per_run)} of rows, above "
                            f"the memory budget of {_gb(budget)} (half this machine's memory); allowed: "
                            f"{chunk_where} <= {most}")
        steps = max(1, int(T * budget / (b * per_run)))
        raise SpecError(f"timeseries: one batch of {b} runs would hold {_gb(b * per_run)} of per-step rows "
                        f"({T} steps x {F} filters), above the memory budget of {_gb(budget)} (half this machine's "
                        f"memory); allowed: timeseries = false, or config.n_steps <= {steps}")
    far = _far_above_default(spec)
    if not far:
        return
    import jax

    devices = len(jax.local_devices(backend="cpu"))  # batches run side by side, one per device
    record, largest = step_sizes(spec)
    runs = b * min(devices, max(1, chunk // b))
    need = runs * (T * record + STEP_COPIES * largest)
    if need <= budget:
        return
    text = (f"{runs} runs at once would need about {_gb(need)} ({T} steps x {record} B of records per run, largest "
            f"array {_gb(largest)}), above the memory budget of {_gb(budget)} (half this machine's memory)")
    if runs * T * record > need / 2:
        steps = max(1, int((budget / runs - STEP_COPIES * largest) / max(record, 1)))
        raise SpecError(f"config.n_steps: {T} steps: {text}; allowed: n_steps <= {steps} with these settings")
    shown = ", ".join(f"config.{n} = {getattr(cfg, n)} (default {spec.scenario.settings[n].default})" for n in far)
    raise SpecError(f"{shown}: {text}; allowed: smaller values (about {budget / need:.2g} times these "
                    f"or less)")


def points(spec: SweepSpec) -> pd.DataFrame:
    """One row per sweep point (product of the grid axes and the zipped block), with its
    ``point_id``."""
    names = list(spec.grid)
    factors = [[(v,) for v in spec.grid[n]] for n in names]
    if spec.zipped:
        factors.append(list(zip(*spec.zipped.values())))
    rows = [sum(combo, ()) for combo in itertools.product(*factors)] if factors else [()]
    df = pd.DataFrame(rows, columns=spec.axes)
    df.insert(0, "point_id", np.arange(len(df), dtype=np.int64))
    return df


def point_params(spec: SweepSpec):
    """Params with a leading point axis, one entry per row of :func:`points`: a swept field
    takes the axis column, every other field its base value repeated."""
    table = points(spec)
    n = len(table)
    fields = {}
    for k in spec.base_params._fields:
        if k in spec.axes:
            fields[k] = np.asarray(table[k].tolist(), np.float64)
        else:
            base = np.asarray(getattr(spec.base_params, k), np.float64)
            fields[k] = np.broadcast_to(base, (n,) + base.shape)
    return spec.base_params._replace(**fields)


def _per_run(value, n: int, filters: int, per_filter: bool, name: str, where: str) -> np.ndarray:
    value = np.asarray(value)
    want = (n, filters) if per_filter else (n,)
    if value.shape[:len(want)] != want or value.ndim != len(want):
        raise ValueError(f"{where}: output {name!r} has shape {value.shape[1:]} per run; its declaration "
                         f"({'per filter' if per_filter else 'per run'}) needs {want[1:]}")
    return value


def _check_declared(got, declared, scenario: Scenario, what: str) -> None:
    missing, extra = [k for k in declared if k not in got], [k for k in got if k not in declared]
    if missing or extra:
        raise ValueError(f"scenario {scenario.name!r}: {what} returned {sorted(got)}; undeclared: {extra}, "
                         f"declared but missing: {missing}")


def run_rows(scenario: Scenario, cfg, outputs: Mapping[str, Any], keys: Mapping[str, Any]) -> pd.DataFrame:
    """Tidy rows, one per run and filter, of a batch's reduced ``outputs`` (each (runs, F) or
    (runs,), as declared by ``scenario.outputs(cfg)``). ``keys``: per-run key columns (e.g.
    ``point_id``, ``seed_index``, swept values, a benchmark's case) — arrays of length runs or
    scalars. Columns: ``scenario``, the keys, ``filter``, then the outputs in declaration
    order. Sorted by point, seed and filter."""
    declared = scenario.outputs(cfg)
    _check_declared(outputs, declared, scenario, "reduce")
    n = len(np.asarray(next(iter(outputs.values()))))
    frames = []
    for f, name in enumerate(cfg.filters):
        cols = {"scenario": scenario.name}
        cols.update({k: (v if np.ndim(v) == 0 else np.asarray(v)) for k, v in keys.items()})
        cols["filter"] = name
        for key, out in declared.items():
            value = _per_run(outputs[key], n, len(cfg.filters), out.per_filter, key, "reduce")
            cols[key] = value[:, f] if out.per_filter else value
        frames.append(pd.DataFrame(cols, index=range(n)))
    df = pd.concat(frames, ignore_index=True)
    order = [c for c in ("point_id", "seed_index", "filter") if c in df.columns]
    return df.sort_values(order, kind="stable").reset_index(drop=True)


def chunk_keys(spec: SweepSpec, table: pd.DataFrame, start: int, n: int) -> dict:
    """``point_id``, ``seed_index`` and the swept values of runs ``start … start+n−1``."""
    runs = np.arange(start, start + n)
    point_idx = runs // spec.seeds
    keys = {"point_id": point_idx.astype(np.int64), "seed_index": (runs % spec.seeds).astype(np.int64)}
    for axis in spec.axes:
        keys[axis] = table[axis].to_numpy()[point_idx]
    return keys


def timeseries_rows(spec: SweepSpec, start: int, series: dict) -> pd.DataFrame:
    """Tidy rows (one per run, step and filter) from a chunk's per-step series, each (runs, T)
    or (runs, T, F) as declared by ``scenario.timeseries_outputs``."""
    declared = spec.scenario.timeseries_outputs(spec.config)
    _check_declared(series, declared, spec.scenario, "timeseries")
    filters = spec.config.filters
    first = np.asarray(next(iter(series.values())))
    n, T = first.shape[:2]
    runs = np.arange(start, start + n)
    shape = (n, T, len(filters))
    cols = {
        "point_id": np.broadcast_to((runs // spec.seeds)[:, None, None], shape).ravel().astype(np.int64),
        "seed_index": np.broadcast_to((runs % spec.seeds)[:, None, None], shape).ravel().astype(np.int64),
        "t": np.broadcast_to(np.arange(T)[None, :, None], shape).ravel().astype(np.int64),
        "filter": np.broadcast_to(np.asarray(filters)[None, None, :], shape).ravel(),
    }
    for key, out in declared.items():
        value = np.asarray(series[key])
        cols[key] = (value if out.per_filter else np.broadcast_to(value[..., None], shape)).ravel()
    return pd.DataFrame(cols)


def chunk_parts(spec: SweepSpec, index: int, start: int, stop: int) -> list[str]:
    """The part names chunk ``index`` (runs ``start … stop−1``) writes, one per point it touches."""
    return [f"point_id={p}/part-{index:06d}" for p in range(start // spec.seeds, (stop - 1) // spec.seeds + 1)]


def part_metadata(spec: SweepSpec, chunk_size: int) -> dict:
    """The schema metadata of every part: the scenario's declarations (outputs, params, filter
    order), the spec, config, seeds and provenance — everything ``mcjax report`` needs."""
    from mcjax import results

    return {**spec.scenario.metadata(spec.config), "spec": spec.source, "config": dataclasses.asdict(spec.config),
            "seeds": spec.seeds, "base_seed": spec.base_seed, "chunk_size": chunk_size,
            "n_points": spec.n_points, "n_runs": spec.n_runs, **results.environment_metadata()}


# ------------------------------------------------------------------ executors: who computes the chunks


class ChunkRows(NamedTuple):
    """What one chunk of a sweep produced, ready to be published as part files: its index in
    the chunk plan, its runs ``start … stop−1``, its tidy rows (:func:`run_rows`) and, when
    the spec asks for them, its per-step rows (:func:`timeseries_rows`; else None)."""

    index: int
    start: int
    stop: int
    runs: pd.DataFrame
    timeseries: pd.DataFrame | None


class ChunkError(RuntimeError):
    """A chunk failed while it was computed (on a Dask worker); the message, one line, names
    the chunk, the points it covers and the error."""


def chunk_rows(spec: SweepSpec, chunks: list[int] | None = None) -> Iterator[ChunkRows]:
    """Compute every chunk (or only ``chunks``) of a sweep in this process, in plan order, and
    yield each one's rows. The batch program is compiled once per process and Config
    (:func:`mcjax.engine.run_chunks`), so later calls for other chunks reuse it."""
    from mcjax import engine

    table = points(spec)
    for idx, start, stop, out in engine.run_chunks(spec.scenario, spec.config, point_params(spec), spec.seeds,
                                                   base_seed=spec.base_seed, chunk_size=spec.chunk_size,
                                                   chunks=None if chunks is None else set(chunks),
                                                   timeseries=spec.timeseries):
        series = None
        if spec.timeseries:
            out, series = out
        rows = run_rows(spec.scenario, spec.config, out, chunk_keys(spec, table, start, stop - start))
        yield ChunkRows(idx, start, stop, rows, None if series is None else timeseries_rows(spec, start, series))


class Executor(Protocol):
    """Computes the chunks of a sweep somewhere and hands their rows back to the caller, which
    publishes them (:func:`run_sweep`). Implementations: :class:`LocalExecutor` (this process,
    the default) and :class:`mcjax.cluster.DaskExecutor` (the workers of a Dask cluster)."""

    def map_chunks(self, spec: SweepSpec, chunks: list[int],
                   should_stop: Callable[[], bool]) -> Iterator[ChunkRows]:
        """Yield the rows of every chunk of ``chunks`` once, in any order, as each completes.
        Stop early (leaving the rest undone) when ``should_stop()`` turns True, or when the
        caller closes the iterator. A failed chunk raises (the Dask executor raises
        :class:`ChunkError`)."""
        ...


class LocalExecutor:
    """Computes the chunks in this process, one after the other, in plan order (the default;
    a chunk's batches are spread over this machine's CPU devices by the engine)."""

    def map_chunks(self, spec: SweepSpec, chunks: list[int],
                   should_stop: Callable[[], bool]) -> Iterator[ChunkRows]:
        if not should_stop():
            yield from chunk_rows(spec, chunks)


def publish_chunk(out_dir: str | Path, rows: ChunkRows, metadata: dict) -> None:
    """Write a chunk's rows as its part files (one per point it touches, in ``runs/`` and, with
    per-step rows, ``timeseries/``), each atomically (:func:`mcjax.results.write_part`:
    staging file, fsync, rename). The chunk counts as done once all its parts exist."""
    from mcjax import results

    tables = [("runs", rows.runs)] + ([("timeseries", rows.timeseries)] if rows.timeseries is not None else [])
    for name, frame in tables:
        for pid, part in frame.groupby("point_id", sort=True):  # hive layout: OUT/<table>/point_id=P/
            results.write_part(out_dir, name, part, f"part-{rows.index:06d}", metadata,
                               partition={"point_id": int(pid)})


def describe_chunk(spec: SweepSpec, index: int) -> str:
    """Chunk ``index`` in words: its runs and the points it covers, with their swept values
    (``chunk 3 (runs 300..399; point_id 3: r = 13.0)``)."""
    from mcjax.engine import chunk_plan

    start, stop = chunk_plan(spec.n_runs, spec.chunk_size)[index]
    first, last = start // spec.seeds, (stop - 1) // spec.seeds
    table = points(spec)
    shown = []
    for pid in range(first, min(last, first + 2) + 1):
        values = ", ".join(f"{axis} = {_show(np.asarray(table.at[pid, axis]).tolist())}" for axis in spec.axes)
        shown.append(f"point_id {pid}" + (f": {values}" if values else ""))
    if last > first + 2:
        shown.append(f"… point_id {last}")
    return f"chunk {index} (runs {start}..{stop - 1}; {'; '.join(shown)})"


def run_sweep(spec: SweepSpec, out_dir: str | Path | None = None, *, chunks: list[int] | None = None,
              progress: Callable[[int], None] | None = None,
              should_stop: Callable[[], bool] | None = None, executor: Executor | None = None) -> pd.DataFrame:
    """Run every chunk (or only ``chunks``) of a sweep with ``executor`` (default: this
    process, :class:`LocalExecutor`); write each chunk as its part files as soon as it
    completes, when ``out_dir`` is given (this process writes every file, whoever computed
    the rows); return the rows of the chunks run, in chunk order. ``progress(runs)`` is told
    after each chunk is written. ``should_stop()`` is asked before the first chunk and after
    each one: True stops the sweep there (the chunks done stay written). No empty staging
    folder is left behind."""
    from mcjax import engine

    plan = engine.chunk_plan(spec.n_runs, spec.chunk_size)
    todo = list(range(len(plan))) if chunks is None else [i for i in chunks if 0 <= i < len(plan)]
    stop = should_stop or (lambda: False)
    metadata = None
    done = {}
    work = (executor or LocalExecutor()).map_chunks(spec, todo, stop)
    try:
        for rows in work:
            if out_dir is not None:
                if metadata is None:
                    metadata = part_metadata(spec, plan[0][1] - plan[0][0])
                publish_chunk(out_dir, rows, metadata)
            done[rows.index] = rows.runs
            if progress is not None:
                progress(rows.stop - rows.start)
            if stop():
                break
    finally:
        close = getattr(work, "close", None)
        if close is not None:
            close()  # a remote executor cancels what is still queued or running
        if out_dir is not None:
            from mcjax import results

            results.remove_empty_staging(out_dir)
    return pd.concat([done[i] for i in sorted(done)], ignore_index=True) if done else pd.DataFrame()


# ------------------------------------------------------------------ output folder and resume

IDENTITY_FILE = "sweep.json"
#: The keys of sweep.json that make two sweeps the same for ``--resume``.
IDENTITY_KEYS = ("spec", "seeds", "base_seed", "chunk_size", "n_runs")
#: Where ``mcjax sweep`` writes when no ``--out`` is given: ``results/<spec name>``.
RESULTS_DIR = Path("results")


class OutputError(ValueError):
    """The output folder cannot be used as asked (not empty, nothing to resume, another sweep)."""


def default_out_dir(spec_path: str | Path) -> Path:
    """``results/<name>``, the name being the spec file's stem with anything but letters,
    digits, ``.``, ``_`` and ``-`` replaced and no leading dots (``...toml`` gives
    ``results/sweep``): always a folder inside ``results/``, never ``results/`` itself."""
    name = re.sub(r"[^A-Za-z0-9._-]+", "_", Path(spec_path).stem).lstrip("._-")
    return RESULTS_DIR / (name if name.strip(".") else "sweep")


def identity(spec: SweepSpec) -> dict:
    """What makes two sweeps the same for ``--resume``: spec, seeds, base seed, chunking."""
    from mcjax.engine import chunk_plan

    plan = chunk_plan(spec.n_runs, spec.chunk_size)
    return json.loads(json.dumps({"spec": spec.source, "seeds": spec.seeds, "base_seed": spec.base_seed,
                                  "chunk_size": plan[0][1] - plan[0][0], "n_runs": spec.n_runs}, default=str))


def read_identity(out_dir: str | Path) -> dict:
    """The ``sweep.json`` of an output folder; OutputError in one line, saying what to do,
    when it is missing or damaged."""
    state = Path(out_dir) / IDENTITY_FILE
    if not state.is_file():
        raise OutputError(f"nothing to resume in {out_dir}: no {IDENTITY_FILE} (start the sweep without --resume)")
    try:
        saved = json.loads(state.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise OutputError(f"{state} is damaged ({_one_line(exc)}); it records which sweep the folder holds, so the "
                          f"folder cannot be resumed: start again with --force") from None
    ok = isinstance(saved, dict) and all(k in saved for k in IDENTITY_KEYS)
    ok = ok and isinstance(saved["spec"], dict) and all(_is_int(saved[k]) for k in IDENTITY_KEYS[1:])
    ok = ok and isinstance(saved.get("set", {}), dict)
    if not ok:
        raise OutputError(f"{state} is damaged (it lacks {', '.join(IDENTITY_KEYS)}); the folder cannot be resumed: "
                          f"start again with --force")
    return saved


def _inside(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def _check_replaceable(out_dir: Path, keep: list[Path], identity_file: str = IDENTITY_FILE,
                       kind: str = "sweep") -> None:
    """``--force`` replaces only a folder that is empty or holds a previous ``kind`` of run
    (its ``identity_file``, ``sweep.json`` for a sweep) and never one that is or holds the
    current folder, a file of ``keep`` (the spec, its base) or ``results/`` itself."""
    if out_dir.is_symlink():
        raise OutputError(f"--force: {out_dir} is a symbolic link; give the folder itself as --out")
    out = out_dir.resolve()
    guarded = [Path.cwd().resolve(), RESULTS_DIR.resolve(), Path.home().resolve()]
    guarded += [Path(p).resolve() for p in keep]
    for g in guarded:
        if _inside(g, out):
            what = ("the current folder" if g == guarded[0] else "results/ itself" if g == guarded[1]
                    else "your home folder" if g == guarded[2] else str(g))
            raise OutputError(f"--force: {out_dir} is or holds {what}; it replaces only a {kind}'s own output folder "
                              f"(choose another --out)")
    if any(out.iterdir()) and not (out / identity_file).is_file():
        raise OutputError(f"--force: {out_dir} is not empty and holds no {identity_file}, so it is no {kind}'s output "
                          f"folder; --force replaces only those (choose another --out)")


def prepare_output(spec: SweepSpec, out_dir: str | Path, *, resume: bool = False, force: bool = False,
                   keep: list[Path] = (), spec_file: str | Path | None = None,
                   note: Callable[[str], None] | None = None) -> list[int] | None:
    """Make ``out_dir`` ready for ``spec``; return the chunks still to run (None: all).

    A fresh sweep needs an empty or missing folder (``force`` replaces one that holds a
    previous sweep, see :func:`_check_replaceable`; ``keep``: files it must not hold) and
    writes the identity file (with ``spec_file`` and the ``--set`` values, for resuming).
    ``resume`` needs the same identity, removes half-written staging files and returns the
    chunks whose parts are missing or damaged (:func:`check_parts`; ``note`` is told about
    each problem). Raises :class:`OutputError` otherwise."""
    from mcjax import results

    out_dir = Path(out_dir)
    ident = identity(spec)
    state = out_dir / IDENTITY_FILE
    if resume and force:
        raise OutputError("--resume and --force exclude each other")
    try:
        if resume:
            saved = read_identity(out_dir)
            if {k: saved[k] for k in IDENTITY_KEYS} != ident:
                diff = sorted(k for k in IDENTITY_KEYS if saved.get(k) != ident.get(k))
                raise OutputError(f"{out_dir} holds a different sweep ({', '.join(diff)} differ); --resume needs the "
                                  f"same spec, seeds, chunk size and --set values (leave them out to take the saved "
                                  f"ones)")
            results.clean_staging(out_dir)
            todo, problems = check_parts(spec, out_dir)
            for line in problems:
                (note or (lambda _: None))(line)
            return todo
        if out_dir.exists() and not out_dir.is_dir():
            raise OutputError(f"output folder {out_dir} is a file; choose another --out")
        if out_dir.exists() and any(out_dir.iterdir()):
            if not force:
                raise OutputError(f"output folder {out_dir} is not empty; pass --resume to finish it, --force to "
                                  f"replace it, or choose another --out")
            _check_replaceable(out_dir, list(keep))
            shutil.rmtree(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        saved = {**ident, "set": spec.overrides, "spec_file": None if spec_file is None else str(Path(spec_file).resolve())}
        tmp = out_dir / f".{IDENTITY_FILE}.tmp"
        tmp.write_text(json.dumps(saved, indent=1), encoding="utf-8")
        os.replace(tmp, state)
    except OSError as exc:
        raise OutputError(f"output folder {out_dir}: {exc.strerror or exc}") from None
    return None


def check_parts(spec: SweepSpec, out_dir: str | Path) -> tuple[list[int], list[str]]:
    """Chunks to run (again) and one line per problem found: a chunk whose part (of ``runs/``,
    or ``timeseries/`` when the spec asks for it) is missing, or damaged — unreadable, or
    not holding exactly the rows and runs it should. Damaged parts and parts that belong to
    no chunk of the plan are removed (a re-run chunk rewrites its parts under the same names)."""
    from mcjax import results
    from mcjax.engine import chunk_plan

    out_dir = Path(out_dir)
    tables = ["runs"] + (["timeseries"] if spec.timeseries else [])
    rows_per_run = {"runs": len(spec.config.filters), "timeseries": len(spec.config.filters) * spec.config.n_steps}
    have = {t: set(results.existing_parts(out_dir, t)) for t in tables}
    todo, problems, planned = [], [], {t: set() for t in tables}
    for i, (a, b) in enumerate(chunk_plan(spec.n_runs, spec.chunk_size)):
        bad = []
        for t in tables:
            for part in chunk_parts(spec, i, a, b):
                planned[t].add(part)
                point = int(part.split("/")[0].split("=")[1])
                lo, hi = max(a, point * spec.seeds) - point * spec.seeds, min(b, (point + 1) * spec.seeds) - point * spec.seeds
                if part not in have[t]:
                    bad.append(f"{t}/{part}.parquet is missing")
                    continue
                why = results.part_problem(out_dir, t, part, range(lo, hi), rows_per_run[t])
                if why:
                    bad.append(f"{t}/{part}.parquet is damaged ({why})")
                    results.remove_part(out_dir, t, part)
        if bad:
            todo.append(i)
            problems += [f"chunk {i}: {line}; re-running it" for line in bad]
    for t in tables:
        for part in sorted(have[t] - planned[t]):
            problems.append(f"{t}/{part}.parquet belongs to no chunk of this sweep; removed")
            results.remove_part(out_dir, t, part)
    return todo, problems


def missing_chunks(spec: SweepSpec, out_dir: str | Path) -> list[int]:
    """Chunks not completely on disk: some part (of ``runs/``, or ``timeseries/`` when the spec
    asks for it) is missing. Re-running one rewrites its parts under the same names."""
    from mcjax import results
    from mcjax.engine import chunk_plan

    tables = ["runs"] + (["timeseries"] if spec.timeseries else [])
    have = {t: set(results.existing_parts(out_dir, t)) for t in tables}
    return [i for i, (a, b) in enumerate(chunk_plan(spec.n_runs, spec.chunk_size))
            if not all(set(chunk_parts(spec, i, a, b)) <= have[t] for t in tables)]
