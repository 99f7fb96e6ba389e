"""A study's tidy rows: one row per run and filter (:func:`run_rows`, also used by the
benchmarks), the per-step rows, the part names a chunk writes and the schema metadata every
part carries. The declared outputs are checked against what ``reduce`` returned. No JAX.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Mapping

import numpy as np
import pandas as pd

from mcjax.contract import Scenario
from mcjax.study.plan import Study
from mcjax.study.sensitivity import declarations


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


def _own_kinds(scenario: Scenario) -> tuple:
    setting = getattr(scenario, "settings", {}).get("filters")
    return tuple(getattr(setting, "choices", None) or ())


def shown_filters(scenario: Scenario, cfg) -> list[str]:
    """The name each of the config's ``filters`` is shown by — the ``filter`` column, the metadata's filter
    order, the tables and the page: a built-in's or the scenario's own name as written, a filter of one's own
    (a file, a module, a plugin) by its record's name
    (:func:`mcjax.tracking.filters.registry.shown_name`); the config keeps the reference."""
    own = _own_kinds(scenario)
    if all(f in own for f in cfg.filters):
        return list(cfg.filters)
    from mcjax.tracking.filters.registry import shown_name

    return [shown_name(f, own) for f in cfg.filters]


def filter_sources(scenario: Scenario, cfg) -> dict[str, str]:
    """Shown name → where each filter of one's own came from (its file, module or plugin), as the dataset's
    metadata keeps it (``filter_sources``); empty when every filter is the scenario's own."""
    own = _own_kinds(scenario)
    if all(f in own for f in cfg.filters):
        return {}
    from mcjax.tracking.filters.registry import sources

    return sources(cfg.filters, own)


def run_rows(scenario: Scenario, cfg, outputs: Mapping[str, Any], keys: Mapping[str, Any],
             extra: Mapping[str, Any] | None = None) -> pd.DataFrame:
    """Tidy rows, one per run and filter, of a batch's reduced ``outputs`` (each (runs, F) or
    (runs,), as declared by ``scenario.outputs(cfg)``). ``keys``: per-run key columns (e.g.
    ``point_id``, ``seed_index``, swept values, a benchmark's case) — arrays of length runs or
    scalars. Columns: ``scenario``, the keys, ``filter`` (its shown name, :func:`shown_filters`), then the
    outputs in declaration order, then ``extra`` (declarations of outputs the study adds: sensitivity columns).
    Sorted by point, seed and filter."""
    declared = {**scenario.outputs(cfg), **(extra or {})}
    _check_declared(outputs, declared, scenario, "reduce")
    n = len(np.asarray(next(iter(outputs.values()))))
    frames = []
    for f, name in enumerate(shown_filters(scenario, cfg)):
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


def shown_metadata(scenario: Scenario, cfg) -> dict:
    """``scenario.metadata(cfg)`` as a dataset carries it: the filters by the names the rows show them by
    (:func:`_shown`) — what a summary of rows made without a dataset (``mcjax run``'s table, a tune's
    evaluation) reads the filters' order and words from."""
    return _shown(scenario, cfg, scenario.metadata(cfg))


def _shown(scenario: Scenario, cfg, meta: dict) -> dict:
    """The scenario's metadata with its filters by their shown names, and, for a filter of one's own, its
    record's title as its description and where it came from (``filter_sources``)."""
    sources = filter_sources(scenario, cfg)
    if not sources:
        return meta
    from mcjax.tracking.filters.registry import get

    shown = shown_filters(scenario, cfg)
    words = dict(meta.get("filter_descriptions") or {})
    for ref, name in zip(cfg.filters, shown):
        if name in sources and name not in words:
            f = get(ref)
            words[name] = f"{f.title} ({'ours' if f.reference == 'ours' else f.reference}; from {sources[name]})"
    return {**meta, "filters": shown, "filter_descriptions": words, "filter_sources": sources}


def chunk_keys(study: Study, start: int, n: int) -> dict:
    """``point_id``, ``seed_index`` and the swept values of runs ``start … start+n−1``: the
    values of the Params that ran (:meth:`~mcjax.study.plan.Study.swept_values`)."""
    from mcjax.engine import point_and_seed

    point_idx, seed_idx = point_and_seed(np.arange(start, start + n), study.seeds)
    keys = {"point_id": point_idx.astype(np.int64), "seed_index": seed_idx.astype(np.int64)}
    for axis in study.axes:
        keys[axis] = study.swept_values(axis, point_idx)
    return keys


def timeseries_rows(study: Study, start: int, series: dict) -> pd.DataFrame:
    """Tidy rows (one per run, step and filter) from a chunk's per-step series, each (runs, T)
    or (runs, T, F) as declared by ``scenario.timeseries_outputs``."""
    declared = study.scenario.timeseries_outputs(study.config)
    _check_declared(series, declared, study.scenario, "timeseries")
    filters = shown_filters(study.scenario, study.config)
    first = np.asarray(next(iter(series.values())))
    n, T = first.shape[:2]
    from mcjax.engine import point_and_seed

    point_idx, seed_idx = point_and_seed(np.arange(start, start + n), study.seeds)
    shape = (n, T, len(filters))
    cols = {
        "point_id": np.broadcast_to(point_idx[:, None, None], shape).ravel().astype(np.int64),
        "seed_index": np.broadcast_to(seed_idx[:, None, None], shape).ravel().astype(np.int64),
        "t": np.broadcast_to(np.arange(T)[None, :, None], shape).ravel().astype(np.int64),
        "filter": np.broadcast_to(np.asarray(filters)[None, None, :], shape).ravel(),
    }
    for key, out in declared.items():
        value = np.asarray(series[key])
        cols[key] = (value if out.per_filter else np.broadcast_to(value[..., None], shape)).ravel()
    return pd.DataFrame(cols)


def chunk_parts(study: Study, index: int, start: int, stop: int) -> list[str]:
    """The part names chunk ``index`` (runs ``start … stop−1``) writes, one per point it touches."""
    from mcjax.engine import points_of

    return [f"point_id={p}/part-{index:06d}" for p in points_of(start, stop, study.seeds)]


def part_metadata(study: Study, chunk_size: int) -> dict:
    """The schema metadata of every part: the scenario's declarations (outputs, params, filter
    order), the spec, config, seeds and provenance — everything ``mcjax report`` needs."""
    from mcjax.base import provenance

    meta = shown_metadata(study.scenario, study.config)
    extra = declarations(study.scenario, study.config, study.sensitivity)
    meta["outputs"] = {**meta["outputs"], **{k: o.as_json() for k, o in extra.items()}}
    ran = {**study.source, "seeds": study.seeds, "chunk_size": study.chunk_size}  # --seeds merged as --set is
    return {**meta, "spec": ran, "config": dataclasses.asdict(study.config),
            "seeds": study.seeds, "base_seed": study.base_seed, "chunk_size": chunk_size,
            "n_points": study.n_points, "n_runs": study.n_runs,
            "base_params": {k: np.asarray(v).tolist() for k, v in study.base_params._asdict().items()},
            **provenance.environment_metadata()}

