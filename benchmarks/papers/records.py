"""Every run's records of one design point of a config file: the one way the paper figure scripts
of this folder set up their runs (the claims themselves run through `mcjax check`).

    from records import run_records      # a script in benchmarks/papers/ imports it by name
    runs = run_records(ROOT / "configs" / "ren2017.toml", 1000, config_over={"schedule": "markov"})
    runs.records.error                   # (runs, steps, ...): the scenario's per-step records
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np

from mcjax import configure, engine
from mcjax.study import load_config_file

configure()  # JAX's 64-bit mode and CPU devices, as the CLI sets them


class Runs(NamedTuple):
    """The scenario, Config and Params of the point, every run's records (numpy, run axis first)
    and the wall time including compilation."""

    scenario: Any
    config: Any
    params: Any
    records: Any
    seconds: float


def run_records(config: str | Path, runs: int, *, config_over: dict | None = None, params_over: dict | None = None,
                base_seed: int = 0, first: int = 0) -> Runs:
    """``runs`` seeds of the config file's point — seed indices ``first``, ``first + 1``, … of
    ``base_seed``, the runs a sweep of that base seed draws — with ``config_over`` / ``params_over``
    over its values, keeping every step's records."""
    scenario, cfg, values = load_config_file(config)
    cfg = dataclasses.replace(cfg, **(config_over or {}))
    p = scenario.default_params(cfg, **{**values, **(params_over or {})})
    t0 = time.perf_counter()
    size = runs if first % runs == 0 else 1   # chunks of the plan that hold exactly the runs asked for
    chunks = [o for *_, o in engine.run_chunks(scenario, cfg, engine.stack_points([p]), first + runs,
                                               base_seed=base_seed, chunk_size=size, records=True,
                                               chunks=list(range(first // size, (first + runs) // size)))]
    records = jax.tree.map(lambda *xs: np.concatenate([np.asarray(x) for x in xs]), *chunks)
    return Runs(scenario, cfg, p, records, time.perf_counter() - t0)
