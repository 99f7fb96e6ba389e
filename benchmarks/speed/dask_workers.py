"""A sweep on a Dask cluster of 1 and of 2 worker processes, against this process; and the cost per chunk.

What is run (everything with one JAX CPU device per process, ``MCJAX_CPU_DEVICES=1``, so a
worker is one core and "2 workers" means twice the cores of "1 worker"):

1. **Speed.** The spec (default ``sweeps/default.toml``, seeds and chunk size as given) in
   this process (the local executor), then on a ``LocalCluster`` of 1 worker and one of 2
   workers (:func:`mcjax.study.dask.local_cluster`), both kept running. On each cluster the
   sweep runs once *cold* (the workers import mcjax and compile the batch program: what one
   ``mcjax sweep --executor dask --workers N`` costs, less starting the cluster, printed on
   its own), then ``--rounds`` times *warm* (programs compiled: what each further sweep of
   the same spec costs), the two clusters in turn so that both see the same load on a shared
   machine. Checks that every run gave the same bytes as the local one.
2. **Cost per chunk.** A sweep of many small chunks (the same config, open loop, 10 steps:
   ``--overhead-points`` points x 100 seeds, one chunk of 100 runs per point) warm, locally and
   on 1 worker, each the least of ``--repeat`` timings: the difference divided by the number
   of chunks is what Dask adds per chunk (the task sent, the rows pickled and sent back; no
   ``--out``, so nothing is written). Also prints the size of one chunk's rows as sent.

How to run::

    python benchmarks/speed/dask_workers.py                        # ~10 min on a 2-core machine
    python benchmarks/speed/dask_workers.py --seeds 50 --chunk-size 100
    python benchmarks/speed/dask_workers.py --overhead-only          # the cost per chunk only (~1 min)

Needs Dask (``pip install -e ".[dask]"``).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import pickle
import statistics
import time
from pathlib import Path

os.environ["MCJAX_CPU_DEVICES"] = "1"  # before mcjax starts JAX: one core per process

ROOT = Path(__file__).resolve().parents[2]


def _echo(rows):
    """A task that returns its input (Dask's round trip, nothing computed)."""
    return rows


def _timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def main() -> None:
    import distributed
    import pandas as pd

    from mcjax.study.dask import DaskExecutor, local_cluster
    from mcjax.study import chunk_rows, load_spec, run_sweep

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spec", default=str(ROOT / "sweeps" / "default.toml"))
    ap.add_argument("--seeds", type=int, default=None)
    ap.add_argument("--chunk-size", type=int, default=100)
    ap.add_argument("--overhead-points", type=int, default=40)
    ap.add_argument("--repeat", type=int, default=5, help="small sweeps timed this many times (the least counts)")
    ap.add_argument("--overhead-only", action="store_true", help="only the cost per chunk")
    ap.add_argument("--rounds", type=int, default=3, help="warm sweeps on each cluster, in turn")
    args = ap.parse_args()

    spec = load_spec(args.spec, seeds=args.seeds, chunk_size=args.chunk_size)
    small = load_spec(args.spec, chunk_size=100, overrides={
        "config.planner": "none", "config.n_steps": 10, "config.warmup_steps": 2, "seeds": 100,
        "grid.comm_radius": [40e3 + 1e3 * i for i in range(args.overhead_points)]})
    n_chunks = -(-spec.n_runs // args.chunk_size)
    print(f"spec {args.spec}: {spec.n_points} points x {spec.seeds} seeds = {spec.n_runs} runs, "
          f"{n_chunks} chunks of {args.chunk_size}; small: {small.n_runs} runs in {small.n_points} chunks")

    def least(fn):
        fn()  # compiles
        return min(_timed(fn)[1] for _ in range(args.repeat))

    small_local = least(lambda: run_sweep(small))
    rows = next(chunk_rows(small, [0]))
    size = len(pickle.dumps(rows, protocol=5))
    if not args.overhead_only:
        ref, cold = _timed(lambda: run_sweep(spec))
        _, warm = _timed(lambda: run_sweep(spec))
        print(f"local (this process, 1 core): cold {cold:.1f} s, warm {warm:.1f} s", flush=True)
    print(f"small sweep, local: {small_local:.2f} s; one chunk's rows: {size} bytes pickled", flush=True)
    clusters = {}
    with contextlib.ExitStack() as stack:
        for n in ((1,) if args.overhead_only else (1, 2)):
            cluster, start = _timed(lambda: stack.enter_context(local_cluster(n)))
            client = stack.enter_context(distributed.Client(cluster, set_as_default=False))
            ex = clusters[n] = DaskExecutor(client)
            line = f"dask, {n} worker(s): cluster start {start:.1f} s"
            if not args.overhead_only:
                df, cold = _timed(lambda: run_sweep(spec, executor=ex))
                pd.testing.assert_frame_equal(df, ref, check_exact=True)
                line += f", cold {cold:.1f} s (same bytes as local)"
            if n == 1:
                small_dask = least(lambda: run_sweep(small, executor=ex))
                per_chunk = (small_dask - small_local) / small.n_points
                line += f"; small sweep {small_dask:.2f} s = {1e3 * per_chunk:.0f} ms per chunk more than local"
                # one task at a time that returns a chunk's rows: Dask's own cost per chunk, nothing computed
                trip = min(_timed(lambda: client.submit(_echo, rows, pure=False).result())[1]
                           for _ in range(20 * args.repeat))
                line += f"; a task returning one chunk's rows: {1e3 * trip:.1f} ms"
            print(line, flush=True)
        if args.overhead_only:
            return
        # warm sweeps, 1 and 2 workers in turn, so both see the same load on a shared machine
        warm = {1: [], 2: []}
        for _ in range(args.rounds):
            for n in (1, 2):
                df, t = _timed(lambda: run_sweep(spec, executor=clusters[n]))
                pd.testing.assert_frame_equal(df, ref, check_exact=True)
                warm[n].append(t)
        for n in (1, 2):
            print(f"dask, {n} worker(s), warm: least {min(warm[n]):.1f} s, median {statistics.median(warm[n]):.1f} s "
                  f"of {args.rounds} (same bytes as local)", flush=True)
        print(f"2 workers vs 1: {min(warm[1]) / min(warm[2]):.2f}x (least), "
              f"{statistics.median(warm[1]) / statistics.median(warm[2]):.2f}x (median)")


if __name__ == "__main__":
    main()
