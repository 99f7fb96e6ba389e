"""The plan of a study: the :class:`Study` itself (built once by :mod:`mcjax.study.spec`), its
points table and their Params (each built once), its chunk plan, and the check that the
plan fits in memory before anything is allocated.

A sweep is ``points × seeds`` runs, point-major (run r = point ``r // seeds``, seed
``r % seeds``); points are the product of the grid axes (in the order written) and the zipped
block, numbered by ``point_id`` in that order.
"""

from __future__ import annotations

import itertools
import math
import os
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from mcjax.base.validation import SpecError, show
from mcjax.contract import Scenario

#: Seeds per point when neither the spec nor the config file gives a number.
DEFAULT_SEEDS = 20
#: A count Config field this many times its scenario default makes the spec's batch program
#: get measured (traced once, not compiled) against the memory budget.
MEASURE_FACTOR = 10
#: Rows held in memory per chunk cost about this many times their raw 8-byte cells (the
#: outputs, the DataFrame, its sorted copy, the Arrow table).
ROW_COPIES = 4
#: Arrays alive at once in one step, in units of its largest array.
STEP_COPIES = 4


@dataclass(frozen=True, eq=False)
class Study:
    """One validated study, built once from a spec (:func:`mcjax.study.spec.build_spec`) or a
    config file (``mcjax run``), immutable: the scenario, its Config, the base Params, the
    swept axes, seeds, base seed and chunk size, the spec as written (``source``), the
    ``--set`` values and the output folder (None: nothing written). ``run``, ``sweep``,
    ``tune`` and the executors all take a Study.

    Built once, on first use: :attr:`points` (the table of sweep points), :attr:`params`
    (each point's Params, one array per field with a leading point axis — what the engine
    runs, and where the Parquet key columns of the swept values come from) and :attr:`plan`
    (the chunks)."""

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
    out_dir: Path | None = None
    sensitivity: Any = None    # a mcjax.study.sensitivity.Sensitivity ([sensitivity]), or None

    @property
    def axes(self) -> list[str]:
        """Every swept Params field: the grid axes, then the zipped ones."""
        return [*self.grid, *self.zipped]

    @property
    def n_points(self) -> int:
        n = math.prod(len(v) for v in self.grid.values())
        return n * (len(next(iter(self.zipped.values()))) if self.zipped else 1)

    @property
    def n_runs(self) -> int:
        return self.n_points * self.seeds

    @cached_property
    def points(self) -> pd.DataFrame:
        """One row per sweep point (product of the grid axes and the zipped block), with its
        ``point_id`` and the axes' values as written."""
        factors = [[(v,) for v in self.grid[n]] for n in self.grid]
        if self.zipped:
            factors.append(list(zip(*self.zipped.values())))
        rows = [sum(combo, ()) for combo in itertools.product(*factors)] if factors else [()]
        df = pd.DataFrame(rows, columns=self.axes)
        df.insert(0, "point_id", np.arange(len(df), dtype=np.int64))
        return df

    @cached_property
    def params(self):
        """Params with a leading point axis, one entry per row of :attr:`points`: a swept
        field takes the axis column, every other field its base value repeated."""
        n = len(self.points)
        fields = {}
        for k in self.base_params._fields:
            if k in self.axes:
                fields[k] = np.asarray(self.points[k].tolist(), np.float64)
            else:
                base = np.asarray(getattr(self.base_params, k), np.float64)
                fields[k] = np.broadcast_to(base, (n,) + base.shape)
        return self.base_params._replace(**fields)

    def point(self, point_id: int):
        """The Params of one point."""
        return type(self.base_params)(*(np.asarray(a)[point_id] for a in self.params))

    @cached_property
    def plan(self) -> list[tuple[int, int]]:
        """``[(start, stop), …]`` of the chunks (:func:`mcjax.engine.chunk_plan`)."""
        from mcjax.engine import chunk_plan

        return chunk_plan(self.n_runs, self.chunk_size)

    @property
    def chunk_runs(self) -> int:
        """Runs per chunk as planned: the chunk size rounded up to whole batches, at most the runs."""
        start, stop = self.plan[0]
        return stop - start

    def runs_in(self, chunks: list[int] | None) -> int:
        """Runs of the chunks ``chunks`` of the plan (None: every chunk)."""
        return self.n_runs if chunks is None else sum(self.plan[i][1] - self.plan[i][0] for i in chunks)

    def swept_values(self, axis: str, point_ids) -> np.ndarray:
        """The values of the swept field ``axis`` at ``point_ids``, taken from the Params that
        run (:attr:`params`): integers for an integer field, one list per point for a field
        with more than one number."""
        values = np.asarray(getattr(self.params, axis))[np.asarray(point_ids)]
        p = self.scenario.params_table[axis]
        if p.integral():
            values = values.astype(np.int64)
        if values.ndim > 1:
            out = np.empty(len(values), dtype=object)
            out[:] = [v.tolist() for v in values]
            return out
        return values


def describe_chunk(study: Study, index: int) -> str:
    """Chunk ``index`` in words: its runs and the points it covers, with their swept values
    (``chunk 3 (runs 300..399; point_id 3: r = 13.0)``)."""
    from mcjax.engine import points_of

    start, stop = study.plan[index]
    points = points_of(start, stop, study.seeds)
    first, last = points[0], points[-1]
    shown = []
    for pid in range(first, min(last, first + 2) + 1):
        values = ", ".join(f"{axis} = {show(np.asarray(study.points.at[pid, axis]).tolist())}" for axis in study.axes)
        shown.append(f"point_id {pid}" + (f": {values}" if values else ""))
    if last > first + 2:
        shown.append(f"… point_id {last}")
    return f"chunk {index} (runs {start}..{stop - 1}; {'; '.join(shown)})"


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


def step_sizes(study: Study) -> tuple[int, int]:
    """``(record bytes, largest array bytes)`` of one step of one run of the spec's program,
    found by tracing ``init`` and ``step`` (nothing is compiled or run)."""
    import jax

    from mcjax import configure

    configure()  # float64, as a run has it

    params = jax.tree.map(lambda a: np.asarray(a)[0], study.params)
    key = jax.random.PRNGKey(0)
    state = jax.eval_shape(lambda p, k: study.scenario.init(study.config, p, k), params, key)
    closed = jax.make_jaxpr(lambda p, s, k: study.scenario.step(study.config, p, s, k)[1])(params, state, key)
    record = sum(_aval_bytes(v.aval) for v in closed.jaxpr.outvars)
    return record, max(record, _largest(closed.jaxpr))


def _far_above_default(study: Study) -> list[str]:
    """Integer Config fields at least :data:`MEASURE_FACTOR` times their scenario default."""
    out = []
    for name, s in study.scenario.settings.items():
        value, default = getattr(study.config, name), s.default
        if s.integer and isinstance(default, int) and value >= MEASURE_FACTOR * max(default, 1):
            out.append(name)
    return out


def check_memory(study: Study, chunk_where: str = "chunk_size") -> None:
    """Refuse a chunk plan that would not fit in :func:`memory_budget`, before anything is
    allocated: the rows of one chunk (and its per-step rows with ``timeseries``) from the
    declarations, and, when a count is far above its default, one batch's stacked records
    and largest arrays from a trace of the step."""
    from mcjax.engine import batch_size_for

    budget = memory_budget()
    b = batch_size_for(study.n_runs)
    chunk = min(-(-study.chunk_size // b) * b, -(-study.n_runs // b) * b)
    cfg = study.config
    F, T = len(cfg.filters), cfg.n_steps
    n_sens = 0 if study.sensitivity is None else len(study.sensitivity.params) * len(study.sensitivity.outputs)
    per_run = F * (len(study.scenario.outputs(cfg)) + n_sens + 4 + len(study.axes)) * 8 * ROW_COPIES
    if study.timeseries:
        per_run += F * T * (len(study.scenario.timeseries_outputs(cfg)) + 4) * 8 * ROW_COPIES
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
    far = _far_above_default(study)
    if not far:
        return
    import jax

    devices = len(jax.local_devices(backend="cpu"))  # batches run side by side, one per device
    record, largest = step_sizes(study)
    runs = b * min(devices, max(1, chunk // b))
    need = runs * (T * record + STEP_COPIES * largest)
    if need <= budget:
        return
    text = (f"{runs} runs at once would need about {_gb(need)} ({T} steps x {record} B of records per run, largest "
            f"array {_gb(largest)}), above the memory budget of {_gb(budget)} (half this machine's memory)")
    if runs * T * record > need / 2:
        steps = max(1, int((budget / runs - STEP_COPIES * largest) / max(record, 1)))
        raise SpecError(f"config.n_steps: {T} steps: {text}; allowed: n_steps <= {steps} with these settings")
    shown = ", ".join(f"config.{n} = {getattr(cfg, n)} (default {study.scenario.settings[n].default})" for n in far)
    raise SpecError(f"{shown}: {text}; allowed: smaller values (about {budget / need:.2g} times these "
                    f"or less)")

