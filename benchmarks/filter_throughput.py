"""Filter throughput: mcjax (one batched, compiled call) vs a per-run numpy loop.

The five filters of docs/equations.md run on the open-loop leader–follower data of Sun et al. 2011
(5 UAVs, 200 steps, range–bearing, comm range 100 km) over B runs. mcjax runs the B runs in
one call of :func:`mcjax.filters.run_filter` (float64, every run with its own
measurements, sensor positions and graph); the peer is ``benchmarks/numpy_peer.py``, a
plain-numpy implementation of the same equations, looping over runs as a MATLAB-style
study would. Both are timed in this one process; the peer's cost per run does not depend
on B, so it is measured on ``--peer-runs`` runs and reported per agent-step.

    python benchmarks/filter_throughput.py                 # B = 1, 100, 1000, 10000
    python benchmarks/filter_throughput.py --batches 1 100 --filters modified_icf

Prints a markdown table: agent-steps per second for each, the ratio, and compile time
(first call minus second call).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
import numpy_peer  # noqa: E402

KM = 1e3
FILTERS = ("cif", "icf", "modified_icf", "kcf", "local")


def make_runs(n_runs: int, steps: int, seed: int = 0):
    """``n_runs`` independent open-loop runs of Sun et al. 2011's set-up (numpy simulator)."""
    rng = np.random.default_rng(seed)
    positions = np.array([[20, 150], [80, 150], [130, 200], [130, 100], [180, 150]]) * KM
    heading = np.full(5, np.arctan2(-1000.0, 200.0))
    runs = [numpy_peer.simulate_open_loop_numpy(
        rng, steps, positions, heading, 800.0, np.array([200 * KM, 200.0, 180 * KM, -1000.0]),
        1.0, 50.0, 10.0, 0.017, 120 * KM, 100 * KM) for _ in range(n_runs)]
    z, s, a, truth = (np.stack(x) for x in zip(*runs))
    F, Q = numpy_peer.cv_matrices(1.0, 50.0)
    common = dict(P0=np.diag([1e4, 1e2, 1e4, 1e2]), F=F, Q=Q, R=np.diag([10.0**2, 0.017**2]))
    return z, s, a, truth, common


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 100, 1000, 10000], help="batch sizes B")
    ap.add_argument("--filters", nargs="+", default=list(FILTERS), choices=FILTERS)
    ap.add_argument("--steps", type=int, default=200, help="time steps per run (paper: 200)")
    ap.add_argument("--peer-runs", type=int, default=20, help="runs timed for the numpy peer")
    ap.add_argument("--distinct", type=int, default=200, help="distinct simulated runs (tiled up to B)")
    args = ap.parse_args(argv)

    from mcjax.filters import run_filter

    n_agents = 5
    distinct = max(args.peer_runs, min(args.distinct, max(args.batches)))
    z, s, a, truth, common = make_runs(distinct, args.steps)
    x0 = truth[0, 0]  # every run starts from the same true state (Sun et al. 2011 §5)

    print(f"# filter throughput: {n_agents} agents x {args.steps} steps per run, float64")
    print("| filter | B | mcjax agent-steps/s | numpy loop agent-steps/s | ratio | mcjax compile s |")
    print("|---|---:|---:|---:|---:|---:|")
    for kind in args.filters:
        t = time.perf_counter()
        for r in range(args.peer_runs):
            numpy_peer.run_filter_numpy(kind, z[r], s[r], a[r], x0, **common)
        peer_rate = args.peer_runs * args.steps * n_agents / (time.perf_counter() - t)
        for B in args.batches:
            idx = np.arange(B) % distinct
            batch = dict(measurements=z[idx], sensor_positions=s[idx], adjacency=a[idx])
            t = time.perf_counter()
            run_filter(kind, **batch, x0=x0, **common)
            first = time.perf_counter() - t
            t = time.perf_counter()
            run_filter(kind, **batch, x0=x0, **common)
            second = time.perf_counter() - t
            rate = B * args.steps * n_agents / second
            print(f"| {kind} | {B} | {rate:,.0f} | {peer_rate:,.0f} | {rate / peer_rate:,.1f} | "
                  f"{max(first - second, 0.0):.2f} |", flush=True)


if __name__ == "__main__":
    main()
