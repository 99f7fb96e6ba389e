"""A sweep's runs, chunked: runs are ordered point-major (run r is point ``r // n_seeds``, seed
``r % n_seeds`` — :func:`point_and_seed`, the one place that says so) and cut into chunks of one
fixed, batch-aligned size, the last padded and trimmed, so one compiled program serves every chunk
and memory is bounded by the chunk; the chunks' batches are dispatched to the devices in turn."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Iterator

import jax
import numpy as np

from mcjax import runtime
from mcjax.contract import Scenario
from mcjax.engine.compilation import compiled, devices, program_futures, store_label, user_module
from mcjax.engine.keys import run_keys


def stack_points(points: list) -> object:
    """Stack a list of Params (one per sweep point) into one Params with a point axis."""
    return jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *points)


#: Runs per compiled call. XLA's CPU code for a batch of B runs can differ in the last bit
#: between batch sizes and between lanes of one batch (vectorised vs remainder loops,
#: reduction tiling), so every sweep runs the same B-run program on B-aligned slices of the
#: run index: results are then bit-identical whatever the chunk size. Per-run cost on the
#: CPU is flat from about 100 runs per call up (measured; docs/benchmarks.md).
BATCH_SIZE = 100


def batch_size_for(n_runs: int) -> int:
    """The compiled batch of a sweep of ``n_runs`` runs (fixed by the sweep, not the chunk)."""
    return max(1, min(BATCH_SIZE, n_runs))


def chunk_plan(n_runs: int, chunk_size: int) -> list[tuple[int, int]]:
    """``[(start, stop), …]`` of the chunks covering ``n_runs`` runs. The chunk size is rounded
    up to a multiple of the compiled batch, so chunk boundaries stay batch-aligned."""
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be >= 1; got {chunk_size}")
    b = batch_size_for(n_runs)
    size = -(-chunk_size // b) * b
    return [(s, min(s + size, n_runs)) for s in range(0, n_runs, size)]


def point_and_seed(runs, n_seeds: int):
    """``(point index, seed index)`` of each run index of ``runs`` (an int or an array): runs are
    point-major, run r = point ``r // n_seeds``, seed ``r % n_seeds``."""
    return runs // n_seeds, runs % n_seeds


def points_of(start: int, stop: int, n_seeds: int) -> range:
    """The point indices that runs ``start … stop−1`` touch (in order)."""
    return range(point_and_seed(start, n_seeds)[0], point_and_seed(stop - 1, n_seeds)[0] + 1)


def chunk_inputs(point_params, n_seeds: int, base_seed: int, start: int, stop: int, size: int):
    """Params and keys of runs ``start … stop−1``, padded to ``size`` by repeating the last run."""
    runs = np.arange(start, stop)
    runs = np.concatenate([runs, np.full(size - len(runs), stop - 1)])
    point_idx, seed_idx = point_and_seed(runs, n_seeds)
    params = jax.tree.map(lambda a: np.asarray(a)[point_idx], point_params)
    keys = run_keys(base_seed, seed_idx)
    return params, keys


def run_chunks(scenario: Scenario, cfg, point_params, n_seeds: int, *, base_seed: int = 0,
               chunk_size: int = 1000, chunks: list[int] | None = None,
               records: bool = False, timeseries: bool = False,
               sensitivity=None) -> Iterator[tuple[int, int, int, dict]]:
    """Run a sweep chunk by chunk; yields ``(chunk_index, start, stop, outputs)`` with the
    outputs trimmed to the chunk's real runs and converted to numpy.

    ``point_params``: Params with a leading point axis; ``chunks``: only those (resuming);
    ``timeseries`` as in :func:`simulate`; ``sensitivity`` adds the :func:`derivatives`.
    Each chunk is consecutive calls of one compiled :data:`BATCH_SIZE`-run program (the last
    padded by repeating the chunk's last run), sent to the devices in turn (one calling thread
    per device): memory is bounded by the chunk, the numbers depend on neither it nor the devices.
    """
    runtime.configure()
    n_points = int(jax.tree.leaves(point_params)[0].shape[0])
    n_runs = n_points * n_seeds
    b = batch_size_for(n_runs)
    plan = chunk_plan(n_runs, chunk_size)
    # as many devices as the largest chunk has batches (a one-batch sweep compiles once)
    devs = devices(scenario)[:max(1, max(-(-(e - s) // b) for s, e in plan))]
    fns = [compiled(scenario, cfg, records, timeseries)] + (
        [] if sensitivity is None else [compiled(scenario, cfg, sensitivity=sensitivity)])
    programs = None
    # one dispatching thread per device (from one thread: CPU/wall 1.05 with two devices, measured)
    lanes = [ThreadPoolExecutor(1, thread_name_prefix=f"mcjax-device-{i}") for i in range(len(devs))]

    def call(futures, dev, params, keys):  # this device's programs: they may still be loading
        params, keys = jax.device_put(params, dev), jax.device_put(keys, dev)
        out, *extra = [jax.tree.map(np.asarray, f.result()(params, keys)) for f in futures]
        for d in extra:  # the derivatives join the outputs
            out = (out[0] | d, out[1]) if timeseries else out | d
        return out

    try:
        for idx, (start, stop) in enumerate(plan):
            if chunks is not None and idx not in chunks:
                continue
            parts = []
            for k, s in enumerate(range(start, stop, b)):
                e = min(s + b, stop)
                params, keys = chunk_inputs(point_params, n_seeds, base_seed, s, e, b)
                if programs is None:
                    programs = [program_futures(fn, (params, keys), devs, store_label(scenario, cfg, *flags),
                                                user_module(scenario))
                                for fn, flags in zip(fns, [(records, timeseries), (False, False, sensitivity)])]
                d = k % len(devs)
                parts.append((e - s, lanes[d].submit(call, [p[d] for p in programs], devs[d], params, keys)))
            parts = [(m, f.result()) for m, f in parts]
            out = jax.tree.map(lambda *xs: np.concatenate([x[:m] for (m, _), x in zip(parts, xs)]),
                               *[o for _, o in parts])
            yield idx, start, stop, out
    finally:
        for lane in lanes:
            lane.shutdown(wait=True, cancel_futures=True)
