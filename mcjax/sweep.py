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
import shutil
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, NamedTuple

import numpy as np
import pandas as pd

from mcjax import scenarios
from mcjax.contract import Scenario

SPEC_KEYS = ("scenario", "base", "seeds", "base_seed", "chunk_size", "config", "params", "grid", "zip",
             "description", "timeseries")
CONFIG_FILE_KEYS = ("scenario", "config", "params", "description", "seeds")
#: Seeds per point when neither the spec nor the config file gives a number.
DEFAULT_SEEDS = 20


class SpecError(ValueError):
    """A sweep spec or config file is invalid; the message names the key path."""


def _suggest(key, allowed):
    close = difflib.get_close_matches(key, allowed, n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _check_keys(where, table, allowed):
    for key in table:
        if key not in allowed:
            raise SpecError(f"{where}{key}: unknown key{_suggest(key, allowed)}; allowed: {', '.join(allowed)}")


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
    _check_keys(where, table, list(scenario.settings))
    values = {k: (tuple(v) if isinstance(v, list) else v) for k, v in table.items()}
    try:
        return scenario.Config(**values)
    except (TypeError, ValueError) as exc:
        raise SpecError(f"{where.rstrip('.')}: {exc}") from None


def _check_params(scenario: Scenario, cfg, table: dict, where: str) -> None:
    """Every value against its declaration (range, shape for ``cfg.n_agents`` agents)."""
    _check_keys(where, table, list(scenario.params_table))
    for k, v in table.items():
        msg = scenario.params_table[k].problem(v, cfg.n_agents)
        if msg:
            raise SpecError(f"{where}{k}: {msg}")


def _axis_values(where: str, v) -> list:
    """An axis given as a list, or as ``{linspace = [a, b, n]}`` / ``{logspace = [a, b, n]}``."""
    if isinstance(v, dict):
        if len(v) != 1 or next(iter(v)) not in ("linspace", "logspace"):
            raise SpecError(f"{where}: a range must be {{linspace = [start, stop, count]}} or "
                            f"{{logspace = [start, stop, count]}}; got {v!r}")
        kind, args = next(iter(v.items()))
        if (not isinstance(args, list) or len(args) != 3 or not isinstance(args[2], int)
                or isinstance(args[2], bool) or args[2] < 1):
            raise SpecError(f"{where}.{kind}: must be [start, stop, count] with an integer count >= 1; got {args!r}")
        a, b, n = args
        if kind == "logspace":
            if not (a > 0 and b > 0):
                raise SpecError(f"{where}.logspace: start and stop must be > 0; got {args!r}")
            return np.geomspace(a, b, n).tolist()
        return np.linspace(a, b, n).tolist()
    if not isinstance(v, list) or not v:
        raise SpecError(f"{where}: must be a non-empty list of values or a linspace/logspace range; got {v!r}")
    return v


def _read_toml(path: Path, what: str) -> dict:
    try:
        return tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise SpecError(f"{what} not found: {path}") from None
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{path}: not valid TOML: {exc}") from None


class ConfigFile(NamedTuple):
    """A ``configs/*.toml`` file, read once and validated."""

    scenario: Scenario
    config: Any          # the scenario's Config
    params: dict         # Params values given by the file
    seeds: int | None    # the paper's run count, if the file gives one
    path: Path


def read_config_file(path: str | Path) -> ConfigFile:
    """Read and validate a config file (scenario, ``[config]``, ``[params]``, ``seeds``)."""
    path = Path(path)
    data = _read_toml(path, "config file")
    _check_keys(f"{path.name}: ", data, CONFIG_FILE_KEYS)
    seeds = data.get("seeds")
    if seeds is not None and (not isinstance(seeds, int) or isinstance(seeds, bool) or seeds < 1):
        raise SpecError(f"{path.name}: seeds: must be an integer >= 1; got {seeds!r}")
    if "scenario" not in data:
        raise SpecError(f"{path.name}: scenario: missing; allowed: {', '.join(scenarios.known())}")
    try:
        scenario = scenarios.get(data["scenario"], base_dir=path.parent)
    except (ValueError, ImportError) as exc:  # unknown name, missing file or module; a bug inside a
        raise SpecError(f"{path.name}: scenario: {exc}") from None  # scenario keeps its traceback
    cfg = _build_config(scenario, data.get("config", {}), f"{path.name}: config.")
    params = dict(data.get("params", {}))
    _check_params(scenario, cfg, params, f"{path.name}: params.")
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
    return build_spec(_read_toml(path, "sweep spec"), path.parent, seeds=seeds, chunk_size=chunk_size,
                      overrides=overrides)


def build_spec(data: dict, base_dir: str | Path, *, seeds: int | None = None, chunk_size: int | None = None,
               overrides: dict[str, Any] | None = None) -> SweepSpec:
    """Validate a sweep spec given as a dict (the TOML's tables); ``base`` is relative to
    ``base_dir``. ``overrides`` maps key paths (``"params.comm_radius"``) to values."""
    data = json.loads(json.dumps(data))  # a deep copy: the overrides never touch the caller's dict
    for key, value in (overrides or {}).items():
        table, _, name = key.rpartition(".")
        target = data.setdefault(table, {}) if table else data
        if not isinstance(target, dict):
            raise SpecError(f"{table}: must be a table to set {name!r} in; got {target!r}")
        target[name] = value
    _check_keys("", data, SPEC_KEYS)
    if "base" not in data:
        raise SpecError("base: missing; give the config file the sweep starts from")
    base = read_config_file((Path(base_dir) / data["base"]).resolve())
    scenario, cfg, params = base.scenario, base.config, dict(base.params)
    if "scenario" in data and data["scenario"] != scenario.name:
        raise SpecError(f"scenario: {data['scenario']!r} does not match the base config's {scenario.name!r}")
    cfg_over = data.get("config", {})
    if cfg_over:
        _check_keys("config.", cfg_over, list(scenario.settings))
        cfg = _build_config(scenario, {**dataclasses.asdict(cfg), **cfg_over}, "config.")
    spec_params = data.get("params", {})
    _check_params(scenario, cfg, spec_params, "params.")
    params.update(spec_params)
    if cfg_over:  # the base file's values again, against the final Config (e.g. a new n_agents)
        _check_params(scenario, cfg, params, f"{base.path.name}: params.")
    axes = {}
    for table in ("grid", "zip"):
        raw = data.get(table, {})
        if not isinstance(raw, dict):
            raise SpecError(f"{table}: must be a table of Params axes; got {raw!r}")
        _check_keys(f"{table}.", raw, list(scenario.params_table))
        axes[table] = {k: _axis_values(f"{table}.{k}", v) for k, v in raw.items()}
        for k, v in axes[table].items():
            for value in v:
                _check_params(scenario, cfg, {k: value}, f"{table}.")
    grid, zipped = axes["grid"], axes["zip"]
    both = set(grid) & set(zipped)
    if both:
        raise SpecError(f"zip.{sorted(both)[0]}: already a grid axis; an axis goes in [grid] or [zip], not both")
    lengths = {k: len(v) for k, v in zipped.items()}
    if len(set(lengths.values())) > 1:
        raise SpecError(f"zip: axes must have equal lengths; got {lengths}")
    base_params = scenario.default_params(cfg, **params)
    # the spec's seeds, else the config file's (the paper's run count), else DEFAULT_SEEDS
    if seeds is None:
        seeds = data.get("seeds", base.seeds if base.seeds is not None else DEFAULT_SEEDS)
    chunk = data.get("chunk_size", 1000) if chunk_size is None else chunk_size
    base_seed = data.get("base_seed", 0)
    for name, value in (("seeds", seeds), ("chunk_size", chunk), ("base_seed", base_seed)):
        if not isinstance(value, int) or isinstance(value, bool) or value < (0 if name == "base_seed" else 1):
            raise SpecError(f"{name}: must be an integer >= {0 if name == 'base_seed' else 1}; got {value!r}")
    timeseries = data.get("timeseries", False)
    if not isinstance(timeseries, bool):
        raise SpecError(f"timeseries: must be true or false; got {timeseries!r}")
    if timeseries and scenario.timeseries is None:
        raise SpecError(f"timeseries: scenario {scenario.name!r} has no per-step series")
    spec = SweepSpec(scenario, cfg, base_params, grid, zipped, seeds, base_seed, chunk, data, timeseries)
    _check_points(spec, params)
    return spec


def _check_points(spec: SweepSpec, params: dict) -> None:
    """Checks across fields that depend on the Config (e.g. t_r <= max_horizon), over every point."""
    check = spec.scenario.check_params
    if check is None:
        return
    table = points(spec)
    merged = {**params, **{axis: table[axis].to_numpy() for axis in spec.axes}}
    for name, allowed in check(spec.config, merged):
        where = "grid." if name in spec.grid else "zip." if name in spec.zipped else "params."
        got = np.asarray(merged.get(name, getattr(spec.base_params, name)))
        if name in spec.axes or got.ndim == 0:  # an axis: its distinct values over the points
            got = sorted(set(np.atleast_1d(got).tolist()))
            got = got if len(got) > 1 else got[0]
        else:  # a vector or matrix param: as given
            got = got.tolist()
        raise SpecError(f"{where}{name}: must be {allowed}; got {got!r}")


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
            **results.environment_metadata()}


def run_sweep(spec: SweepSpec, out_dir: str | Path | None = None, *, chunks: list[int] | None = None,
              progress: Callable[[int], None] | None = None) -> pd.DataFrame:
    """Run every chunk (or only ``chunks``) of a sweep; write each as a part file when
    ``out_dir`` is given; return the rows of the chunks run."""
    from mcjax import engine, results

    table = points(spec)
    params = point_params(spec)
    metadata = None
    frames = []
    for idx, start, stop, out in engine.run_chunks(spec.scenario, spec.config, params, spec.seeds,
                                                   base_seed=spec.base_seed, chunk_size=spec.chunk_size,
                                                   chunks=chunks, timeseries=spec.timeseries):
        if spec.timeseries:
            out, series = out
        df = run_rows(spec.scenario, spec.config, out, chunk_keys(spec, table, start, stop - start))
        if out_dir is not None:
            if metadata is None:
                plan = engine.chunk_plan(spec.n_runs, spec.chunk_size)
                metadata = part_metadata(spec, plan[0][1] - plan[0][0])
            # one file per point of the chunk (hive layout); the chunk is done when all exist
            for pid, part in df.groupby("point_id", sort=True):
                results.write_part(out_dir, "runs", part, f"part-{idx:06d}", metadata,
                                   partition={"point_id": int(pid)})
            if spec.timeseries:
                ts = timeseries_rows(spec, start, series)
                for pid, part in ts.groupby("point_id", sort=True):
                    results.write_part(out_dir, "timeseries", part, f"part-{idx:06d}", metadata,
                                       partition={"point_id": int(pid)})
        frames.append(df)
        if progress is not None:
            progress(stop - start)
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


# ------------------------------------------------------------------ output folder and resume

IDENTITY_FILE = "sweep.json"


class OutputError(ValueError):
    """The output folder cannot be used as asked (not empty, nothing to resume, another sweep)."""


def identity(spec: SweepSpec) -> dict:
    """What makes two sweeps the same for ``--resume``: spec, seeds, base seed, chunking."""
    from mcjax.engine import chunk_plan

    plan = chunk_plan(spec.n_runs, spec.chunk_size)
    return json.loads(json.dumps({"spec": spec.source, "seeds": spec.seeds, "base_seed": spec.base_seed,
                                  "chunk_size": plan[0][1] - plan[0][0], "n_runs": spec.n_runs}, default=str))


def missing_chunks(spec: SweepSpec, out_dir: str | Path) -> list[int]:
    """Chunks not completely on disk: some part (of ``runs/``, or ``timeseries/`` when the spec
    asks for it) is missing. Re-running one rewrites its parts under the same names."""
    from mcjax import results
    from mcjax.engine import chunk_plan

    tables = ["runs"] + (["timeseries"] if spec.timeseries else [])
    have = {t: set(results.existing_parts(out_dir, t)) for t in tables}
    return [i for i, (a, b) in enumerate(chunk_plan(spec.n_runs, spec.chunk_size))
            if not all(set(chunk_parts(spec, i, a, b)) <= have[t] for t in tables)]


def prepare_output(spec: SweepSpec, out_dir: str | Path, *, resume: bool = False,
                   force: bool = False) -> list[int] | None:
    """Make ``out_dir`` ready for ``spec``; return the chunks still to run (None: all).

    A fresh sweep needs an empty or missing folder (``force`` deletes it first) and writes
    the identity file; ``resume`` needs the same identity and returns the missing chunks
    after removing half-written staging files. Raises :class:`OutputError` otherwise."""
    from mcjax import results

    out_dir = Path(out_dir)
    ident = identity(spec)
    state = out_dir / IDENTITY_FILE
    if resume and force:
        raise OutputError("--resume and --force exclude each other")
    if resume:
        if not state.exists():
            raise OutputError(f"nothing to resume in {out_dir}: no {IDENTITY_FILE} (start the sweep without --resume)")
        saved = json.loads(state.read_text())
        if saved != ident:
            diff = sorted(k for k in ident if saved.get(k) != ident.get(k))
            raise OutputError(f"{out_dir} holds a different sweep ({', '.join(diff)} differ); --resume needs the "
                              f"same spec, seeds and chunk size")
        results.clean_staging(out_dir)
        return missing_chunks(spec, out_dir)
    if out_dir.exists() and any(out_dir.iterdir()):
        if not force:
            raise OutputError(f"output folder {out_dir} is not empty; pass --resume to finish it, --force to "
                              f"replace it, or choose another --out")
        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    state.write_text(json.dumps(ident, indent=1))
    return None
