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
"""

from __future__ import annotations

import dataclasses
import difflib
import itertools
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any, Callable

import numpy as np
import pandas as pd

from mcjax import scenarios

SPEC_KEYS = ("scenario", "base", "seeds", "base_seed", "chunk_size", "config", "params", "grid", "zip",
             "description", "timeseries")


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

    scenario: ModuleType
    config: Any
    base_params: Any
    grid: dict = field(default_factory=dict)
    zipped: dict = field(default_factory=dict)
    seeds: int = 20
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


def _build_config(scenario, table, where):
    fields = [f.name for f in dataclasses.fields(scenario.Config)]
    _check_keys(where, table, fields)
    values = {k: (tuple(v) if isinstance(v, list) else v) for k, v in table.items()}
    try:
        return scenario.Config(**values)
    except (TypeError, ValueError) as exc:
        raise SpecError(f"{where.rstrip('.')}: {exc}") from None


def _check_params(scenario, table, where):
    _check_keys(where, table, scenario.Params._fields)
    ranges = getattr(scenario, "PARAM_RANGES", {})
    for k, v in table.items():
        try:
            arr = np.asarray(v, dtype=np.float64)
        except (TypeError, ValueError):
            raise SpecError(f"{where}{k}: must be a number or a list of numbers; got {v!r}") from None
        if not np.all(np.isfinite(arr)):
            raise SpecError(f"{where}{k}: must be finite; got {v!r}")
        if k in ranges:
            lo, hi, text = ranges[k]
            if not np.all((arr >= lo) & (arr <= hi)):
                raise SpecError(f"{where}{k}: must be {text}; got {v!r}")


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


def load_config_file(path: str | Path):
    """``(scenario, Config, params dict)`` from a ``configs/*.toml`` file."""
    path = Path(path)
    data = _read_toml(path, "config file")
    _check_keys(f"{path.name}: ", data, ("scenario", "config", "params", "description", "seeds"))
    seeds = data.get("seeds", 20)
    if not isinstance(seeds, int) or isinstance(seeds, bool) or seeds < 1:
        raise SpecError(f"{path.name}: seeds: must be an integer >= 1; got {seeds!r}")
    if "scenario" not in data:
        raise SpecError(f"{path.name}: scenario: missing; allowed: {', '.join(scenarios.SCENARIOS)}")
    try:
        scenario = scenarios.get(data["scenario"])
    except ValueError as exc:
        raise SpecError(f"{path.name}: scenario: {exc}") from None
    cfg = _build_config(scenario, data.get("config", {}), f"{path.name}: config.")
    params = dict(data.get("params", {}))
    _check_params(scenario, params, f"{path.name}: params.")
    return scenario, cfg, params


def load_spec(path: str | Path, *, seeds: int | None = None, chunk_size: int | None = None,
              overrides: dict[str, Any] | None = None) -> SweepSpec:
    """Read and validate a sweep spec; raises :class:`SpecError` naming the key path."""
    path = Path(path)
    data = _read_toml(path, "sweep spec")
    for key, value in (overrides or {}).items():
        table, _, name = key.rpartition(".")
        target = data.setdefault(table, {}) if table else data
        target[name] = value
    _check_keys("", data, SPEC_KEYS)
    if "base" not in data:
        raise SpecError("base: missing; give the config file the sweep starts from")
    base = (path.parent / data["base"]).resolve()
    scenario, cfg, params = load_config_file(base)
    if "scenario" in data and data["scenario"] != scenario.NAME:
        raise SpecError(f"scenario: {data['scenario']!r} does not match the base config's {scenario.NAME!r}")
    cfg_over = data.get("config", {})
    if cfg_over:
        base_cfg = dataclasses.asdict(cfg)
        _check_keys("config.", cfg_over, list(base_cfg))
        base_cfg.update(cfg_over)
        cfg = _build_config(scenario, base_cfg, "config.")
    _check_params(scenario, data.get("params", {}), "params.")
    params.update(data.get("params", {}))
    axes = {}
    for table in ("grid", "zip"):
        raw = data.get(table, {})
        if not isinstance(raw, dict):
            raise SpecError(f"{table}: must be a table of Params axes; got {raw!r}")
        _check_keys(f"{table}.", raw, scenario.Params._fields)
        axes[table] = {k: _axis_values(f"{table}.{k}", v) for k, v in raw.items()}
        for k, v in axes[table].items():
            for value in v:
                _check_params(scenario, {k: value}, f"{table}.")
    grid, zipped = axes["grid"], axes["zip"]
    both = set(grid) & set(zipped)
    if both:
        raise SpecError(f"zip.{sorted(both)[0]}: already a grid axis; an axis goes in [grid] or [zip], not both")
    lengths = {k: len(v) for k, v in zipped.items()}
    if len(set(lengths.values())) > 1:
        raise SpecError(f"zip: axes must have equal lengths; got {lengths}")
    try:
        base_params = scenario.default_params(cfg, **params)
    except ValueError as exc:
        raise SpecError(f"params: {exc}") from None
    # the spec's seeds, else the config file's (the paper's run count), else 20
    seeds = data.get("seeds", _read_toml(base, "config file").get("seeds", 20)) if seeds is None else seeds
    chunk = data.get("chunk_size", 1000) if chunk_size is None else chunk_size
    base_seed = data.get("base_seed", 0)
    for name, value in (("seeds", seeds), ("chunk_size", chunk), ("base_seed", base_seed)):
        if not isinstance(value, int) or isinstance(value, bool) or value < (0 if name == "base_seed" else 1):
            raise SpecError(f"{name}: must be an integer >= {0 if name == 'base_seed' else 1}; got {value!r}")
    timeseries = data.get("timeseries", False)
    if not isinstance(timeseries, bool):
        raise SpecError(f"timeseries: must be true or false; got {timeseries!r}")
    if timeseries and not hasattr(scenario, "timeseries"):
        raise SpecError(f"timeseries: scenario {scenario.NAME!r} has no per-step series")
    spec = SweepSpec(scenario, cfg, base_params, grid, zipped, seeds, base_seed, chunk, data, timeseries)
    _check_points(spec, params)
    return spec


def _check_points(spec: SweepSpec, params: dict) -> None:
    """Checks across fields that depend on the Config (e.g. t_r <= max_horizon), over every point."""
    check = getattr(spec.scenario, "check_params", None)
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
    """Params with a leading point axis, one entry per row of :func:`points`."""
    table = points(spec)
    per_point = []
    for _, row in table.iterrows():
        over = {k: row[k] for k in spec.axes}
        per_point.append(spec.base_params._replace(**{k: np.asarray(v, np.float64) for k, v in over.items()}))
    from mcjax.engine import stack_points

    return stack_points(per_point)


def summary_rows(spec: SweepSpec, table: pd.DataFrame, start: int, out: dict) -> pd.DataFrame:
    """Tidy rows (one per run and filter) from a chunk's summaries."""
    cfg = spec.config
    n = len(next(iter(out.values())))
    runs = np.arange(start, start + n)
    point_idx, seed_idx = runs // spec.seeds, runs % spec.seeds
    frames = []
    for f, name in enumerate(cfg.filters):
        cols = {
            "scenario": spec.scenario.NAME,
            "point_id": point_idx.astype(np.int64),
            "seed_index": seed_idx.astype(np.int64),
            "filter": name,
        }
        for axis in spec.axes:
            cols[axis] = table[axis].to_numpy()[point_idx]
        for key, value in out.items():
            value = np.asarray(value)
            cols[key] = value[:, f] if value.ndim == 2 else value
        frames.append(pd.DataFrame(cols))
    df = pd.concat(frames, ignore_index=True)
    return df.sort_values(["point_id", "seed_index", "filter"], kind="stable").reset_index(drop=True)


def timeseries_rows(spec: SweepSpec, start: int, series: dict) -> pd.DataFrame:
    """Tidy rows (one per run, step and filter) from a chunk's per-step series: each value is
    (runs, T) (the same for every filter) or (runs, T, F)."""
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
    for key, value in series.items():
        value = np.asarray(value)
        cols[key] = (value if value.ndim == 3 else np.broadcast_to(value[..., None], shape)).ravel()
    return pd.DataFrame(cols)


def chunk_parts(spec: SweepSpec, index: int, start: int, stop: int) -> list[str]:
    """The part names chunk ``index`` (runs ``start … stop−1``) writes, one per point it touches."""
    return [f"point_id={p}/part-{index:06d}" for p in range(start // spec.seeds, (stop - 1) // spec.seeds + 1)]


def run_sweep(spec: SweepSpec, out_dir: str | Path | None = None, *, chunks: list[int] | None = None,
              progress: Callable[[int], None] | None = None, metadata: dict | None = None) -> pd.DataFrame:
    """Run every chunk (or only ``chunks``) of a sweep; write each as a part file when
    ``out_dir`` is given; return the rows of the chunks run."""
    from mcjax import engine, results

    table = points(spec)
    params = point_params(spec)
    frames = []
    for idx, start, stop, out in engine.run_chunks(spec.scenario, spec.config, params, spec.seeds,
                                                   base_seed=spec.base_seed, chunk_size=spec.chunk_size,
                                                   chunks=chunks, timeseries=spec.timeseries):
        if spec.timeseries:
            out, series = out
        df = summary_rows(spec, table, start, out)
        if out_dir is not None:
            # one file per point of the chunk (hive layout); the chunk is done when all exist
            for pid, part in df.groupby("point_id", sort=True):
                results.write_part(out_dir, "runs", part, f"part-{idx:06d}", metadata or {},
                                   partition={"point_id": int(pid)})
            if spec.timeseries:
                ts = timeseries_rows(spec, start, series)
                for pid, part in ts.groupby("point_id", sort=True):
                    results.write_part(out_dir, "timeseries", part, f"part-{idx:06d}", metadata or {},
                                       partition={"point_id": int(pid)})
        frames.append(df)
        if progress is not None:
            progress(stop - start)
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def summary_table(df: pd.DataFrame, axes: list[str]) -> pd.DataFrame:
    """Per point and filter: runs, divergences, mean RMSE (all / non-divergent), min λ2."""
    keys = ["point_id", *axes, "filter"]
    g = df.groupby(keys, sort=True)
    out = g.agg(runs=("seed_index", "size"), diverged=("diverged", "sum"),
                rmse_mean=("rmse", "mean"), mean_error=("mean_error", "mean"),
                lambda2_min=("lambda2_min", "min"))
    ok = df[~df["diverged"]].groupby(keys)["rmse"].mean().rename("rmse_ok")
    return out.join(ok).reset_index()
