"""Filter throughput: mcjax (one batched, compiled call) vs three peers, side by side.

The five filters of docs/equations.md run on the open-loop leader–follower data of Sun et al. 2011
(5 UAVs, 200 steps, range–bearing, comm range 100 km) over B runs, float64. mcjax runs the B
runs in one call of :func:`mcjax.tracking.filters.run_filter` (every run with its own measurements,
sensor positions and graph). The peers, all timed in this one process:

* ``filterpy``: a per-run loop of filterpy's ``ExtendedKalmanFilter``, one object per agent
  (local filter only; filterpy has no consensus filters);
* ``numpy``: ``benchmarks/peers/numpy_peer.py``, plain numpy, one run at a time;
* ``numba``: ``benchmarks/peers/numba_peer.py``, an ``@njit(parallel=True)`` kernel with ``prange``
  over runs (local filter and modified ICF), ``--threads`` threads (default 2). numba is a
  benchmark-only dependency: ``pip install -e .[bench]``.

The loop peers' cost per run does not depend on B, so they are timed on ``--peer-runs`` runs.
Every timing is the median of ``--repeats`` calls (after a first, compiling call for mcjax
and numba), with outputs allocated inside the timed call for every engine. Before timing, the
filterpy and numba peers are checked against mcjax on a tiny batch (max error relative to each
component's scale, must be ≤ 1e-9).

    python benchmarks/speed/filter_throughput.py                      # local, modified_icf; B = 1000, 10000
    python benchmarks/speed/filter_throughput.py --filters cif icf modified_icf kcf local --batches 1000
    git show REV:mcjax/tracking/filters/batched.py > /tmp/batched_rev.py     # an older pure-JAX kernel beside today's
    python benchmarks/speed/filter_throughput.py --no-variants --baseline /tmp/batched_rev.py

Prints a markdown table: ns per agent-step for each engine. "mcjax" is ``run_filter`` as a user
calls it: for the local filter and the modified ICF in float64 that is the native kernels
(``mcjax/tracking/filters/native_kernels.cc`` through XLA's FFI) when the machine has a C++ compiler,
else the pure-JAX kernels (the first lines say which). Beside it: mcjax with its outputs
copied to C order (``np.ascontiguousarray``, the peers' layout; the pure-JAX kernels return
views of batch-last buffers), the pure-JAX kernels (always timed) and, unless
``--no-variants``, the pure-JAX kernels with the batch split over every CPU device
(``recorded.SPLIT_OVER_DEVICES``; off by default) and the general vmap path that ran these
filters before the structure-of-arrays kernels; the speed ratios (filterpy time / mcjax time,
mcjax time / numba time, pure-JAX time / numba time), the floating-point operations per
agent-step counted by hand (docs/filter_speed.md) and mcjax's resulting GFLOP/s, and the load
average (``os.getloadavg()``) at the end of each row.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the peers live in benchmarks/peers/, not in mcjax
from benchmarks.peers import numpy_peer  # noqa: E402
from benchmarks.peers.filterpy_peer import filterpy_local, make_runs, max_relative_error  # noqa: E402

FILTERS = ("cif", "icf", "modified_icf", "kcf", "local")
NUMBA_FILTERS = ("local", "modified_icf")
#: Floating-point operations per agent-step (t > 0, a valid measurement, n = 5, L = 1, dense F
#: and Q), counted by hand in docs/filter_speed.md: (the numba peer's equations, the equations mcjax
#: computes); ``~`` marks an estimate. Both local EKFs are in moment form (the numpy peer's: 506).
FLOPS = {"local": (357, 357), "modified_icf": (656, 656), "cif": ("~150", "~150"),
         "icf": ("~650", "~650"), "kcf": ("~750", "~750")}


def median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def interleaved_times(fns, repeats):
    """Median seconds of each of ``fns``, timed in ``repeats`` rounds of one call each, in turn
    (so a change of the machine's load reaches every engine alike)."""
    times = [[] for _ in fns]
    for _ in range(repeats):
        for i, fn in enumerate(fns):
            t = time.perf_counter()
            fn()
            times[i].append(time.perf_counter() - t)
    return [float(np.median(t)) for t in times]


def load_baseline(path):
    """A copy of an older ``mcjax/tracking/filters/batched.py`` (e.g. ``git show REV:mcjax/tracking/filters/batched.py``)
    loaded as a module, to time beside the current pure-JAX kernels."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("batched_baseline", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def check_peers(kinds, numba_peer, run_filter, tol=1e-9):
    """filterpy and numba against mcjax on 3 runs x 60 steps; prints the errors, returns ok."""
    z, s, a, truth, common = make_runs(3, 60, seed=1)
    x0 = truth[0, 0]
    ok = True
    for kind in kinds:
        xm, Pm = run_filter(kind, measurements=z, sensor_positions=s, adjacency=a, x0=x0, **common)
        peers = {}
        if kind == "local":
            ref = [filterpy_local(z[r], s[r], x0, **common) for r in range(len(z))]
            peers["filterpy"] = (np.stack([r[0] for r in ref]), np.stack([r[1] for r in ref]))
        if numba_peer is not None and kind in NUMBA_FILTERS:
            peers["numba"] = numba_peer.run_filter_numba(kind, z, s, a, x0, **common)
        for name, (xp, Pp) in peers.items():
            err = max_relative_error(xp, Pp, xm, Pm)
            ok &= err <= tol
            print(f"# check {kind:13s} {name:8s} vs mcjax: max relative error {err:.1e} "
                  f"({'ok' if err <= tol else 'FAIL'}, tolerance {tol:g}); largest position difference "
                  f"{position_difference(xp, xm):.1e} m")
        if numba_peer is not None and kind in NUMBA_FILTERS:
            # what the problem itself does with rounding: every measurement moved by one unit in
            # its last place, the same (numba) code run again
            xu, _ = numba_peer.run_filter_numba(kind, np.nextafter(z, np.inf), s, a, x0, **common)
            print(f"# check {kind:13s} numba on measurements moved by one unit in the last place: largest "
                  f"position change {position_difference(xu, peers['numba'][0]):.1e} m (the floor on any "
                  f"agreement between two correct float64 codes)")
    return ok


def position_difference(est, ref_est):
    """Largest absolute difference of the estimated positions (components 0 and 2), metres."""
    return float(np.max(np.abs(np.asarray(est)[..., [0, 2]] - np.asarray(ref_est)[..., [0, 2]])))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batches", type=int, nargs="+", default=[1000, 10000], help="batch sizes B")
    ap.add_argument("--filters", nargs="+", default=list(NUMBA_FILTERS), choices=FILTERS)
    ap.add_argument("--steps", type=int, default=200, help="time steps per run (paper: 200)")
    ap.add_argument("--peer-runs", type=int, default=10, help="runs timed for the numpy and filterpy loops")
    ap.add_argument("--distinct", type=int, default=200, help="distinct simulated runs (tiled up to B)")
    ap.add_argument("--repeats", type=int, default=5, help="timed calls per engine (median reported)")
    ap.add_argument("--threads", type=int, default=2, help="numba threads")
    ap.add_argument("--no-variants", action="store_true",
                    help="skip the mcjax variants: the other device choice (split over every CPU device, "
                         "or one device), and the general (vmap) path of before")
    ap.add_argument("--baseline", type=Path, default=None,
                    help="a copy of an older mcjax/tracking/filters/batched.py: its pure-JAX kernels, today's and numba "
                         "are then also timed interleaved, --repeats rounds (one line per row)")
    ap.add_argument("--general-max-batch", type=int, default=1000,
                    help="largest B timed through the general path (it is slow)")
    args = ap.parse_args(argv)

    import jax

    from mcjax import configure
    from mcjax.tracking.filters import recorded, run_filter

    configure()  # JAX's 64-bit mode and CPU devices, as the CLI sets them
    try:
        import numba

        from benchmarks.peers import numba_peer
        numba.set_num_threads(args.threads)
    except ImportError:
        numba_peer = None
        print("# numba not installed (pip install -e .[bench]): no numba column")

    n_agents = 5
    print(f"# {time.strftime('%Y-%m-%d %H:%M')}, {os.cpu_count()} CPUs, load average {os.getloadavg()}, "
          f"{len(jax.local_devices())} CPU device(s), numba threads "
          f"{args.threads if numba_peer else '-'}, jax {jax.__version__}")
    if not check_peers(args.filters, numba_peer, run_filter):
        raise SystemExit("a peer disagrees with mcjax beyond 1e-9")

    distinct = max(args.peer_runs, min(args.distinct, max(args.batches)))
    z, s, a, truth, common = make_runs(distinct, args.steps)
    x0 = truth[0, 0]
    per_run = args.steps * n_agents

    print(f"# filter throughput: {n_agents} agents x {args.steps} steps per run, float64; ns per agent-step, "
          f"median of {args.repeats}")
    from mcjax.tracking.filters.recorded import SPLIT_OVER_DEVICES as split
    other = "1 device" if split else f"{len(jax.local_devices())} devices"
    from mcjax.tracking.filters import native
    engine = "native kernels" if native.available() else f"pure-JAX kernels ({native.STATUS['reason']})"
    print(f"# mcjax's default for local and modified_icf here: {engine}")
    print(f"| filter | B | mcjax ns | mcjax C-ordered ns | mcjax pure JAX ns | mcjax pure JAX {other} ns | "
          "mcjax general path ns | filterpy ns | numpy ns | numba ns | filterpy/mcjax | mcjax/numba | "
          "pure JAX/numba | flops peers / mcjax | mcjax GFLOP/s | numba GFLOP/s | load |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for kind in args.filters:
        r_ = range(args.peer_runs)
        ns_numpy = median_time(lambda: [numpy_peer.run_filter_numpy(kind, z[r], s[r], a[r], x0, **common)
                                        for r in r_], args.repeats) / (args.peer_runs * per_run) * 1e9
        ns_fp = math.nan
        if kind == "local":
            ns_fp = median_time(lambda: [filterpy_local(z[r], s[r], x0, **common) for r in r_],
                                args.repeats) / (args.peer_runs * per_run) * 1e9
        for B in args.batches:
            idx = np.arange(B) % distinct
            batch = dict(measurements=z[idx], sensor_positions=s[idx], adjacency=a[idx])
            t = time.perf_counter()
            run_filter(kind, **batch, x0=x0, **common)
            compile_s = time.perf_counter() - t
            ns_mcjax = median_time(lambda: run_filter(kind, **batch, x0=x0, **common), args.repeats) / (B * per_run) * 1e9
            # run_filter may return views of batch-last buffers; the peers return C-ordered arrays
            ns_c = median_time(lambda: [np.ascontiguousarray(v) for v in run_filter(kind, **batch, x0=x0, **common)],
                               args.repeats) / (B * per_run) * 1e9
            ns_one = ns_general = ns_jax = math.nan
            if recorded.batched_kernel(kind):  # the pure-JAX kernels (always; the default without a compiler)
                saved = recorded.USE_NATIVE
                try:
                    recorded.USE_NATIVE = False
                    run_filter(kind, **batch, x0=x0, **common)
                    ns_jax = median_time(lambda: run_filter(kind, **batch, x0=x0, **common),
                                         args.repeats) / (B * per_run) * 1e9
                finally:
                    recorded.USE_NATIVE = saved
            if not args.no_variants and recorded.batched_kernel(kind):
                saved = recorded.SPLIT_OVER_DEVICES, recorded.BATCHED_KERNELS, recorded.USE_NATIVE
                recorded.USE_NATIVE = False  # the variants are of the pure-JAX path
                try:
                    recorded.SPLIT_OVER_DEVICES = not saved[0]  # the other device choice
                    run_filter(kind, **batch, x0=x0, **common)
                    ns_one = median_time(lambda: run_filter(kind, **batch, x0=x0, **common),
                                         args.repeats) / (B * per_run) * 1e9
                    recorded.SPLIT_OVER_DEVICES = saved[0]
                    recorded.BATCHED_KERNELS = {}  # the general path (vmap of steps.filter_step)
                    if B <= args.general_max_batch:
                        run_filter(kind, **batch, x0=x0, **common)
                        ns_general = median_time(lambda: run_filter(kind, **batch, x0=x0, **common),
                                                 args.repeats) / (B * per_run) * 1e9
                finally:
                    recorded.SPLIT_OVER_DEVICES, recorded.BATCHED_KERNELS, recorded.USE_NATIVE = saved
            ns_numba = math.nan
            if numba_peer is not None and kind in NUMBA_FILTERS:
                numba_peer.run_filter_numba(kind, *(v[:2] for v in batch.values()), x0, **common)
                ns_numba = median_time(lambda: numba_peer.run_filter_numba(kind, *batch.values(), x0, **common),
                                       args.repeats) / (B * per_run) * 1e9
            f_peer, f_mcjax = FLOPS[kind]
            gflops = f"{f_mcjax / ns_mcjax:.2f}" if isinstance(f_mcjax, int) else "–"
            gflops_nb = "–" if math.isnan(ns_numba) else f"{f_peer / ns_numba:.2f}"
            fmt = lambda v: "–" if math.isnan(v) else f"{v:,.0f}"  # noqa: E731
            ratio_fp = "–" if math.isnan(ns_fp) else f"{ns_fp / ns_mcjax:,.0f}"
            ratio_nb = "–" if math.isnan(ns_numba) else f"{ns_mcjax / ns_numba:.2f}"
            ratio_jax = "–" if math.isnan(ns_numba) or math.isnan(ns_jax) else f"{ns_jax / ns_numba:.2f}"
            print(f"| {kind} | {B:,} | {fmt(ns_mcjax)} | {fmt(ns_c)} | {fmt(ns_jax)} | {fmt(ns_one)} | {fmt(ns_general)} | {fmt(ns_fp)} | {fmt(ns_numpy)} | {fmt(ns_numba)} | "
                  f"{ratio_fp} | {ratio_nb} | {ratio_jax} | {f_peer} / {f_mcjax} | {gflops} | {gflops_nb} | {os.getloadavg()[0]:.1f} |", flush=True)
            print(f"#   {kind} B={B}: first mcjax call (compilation included) {compile_s:.1f} s", flush=True)
            if args.baseline is not None and recorded.batched_kernel(kind) and numba_peer is not None:
                saved = recorded.USE_NATIVE, recorded.batched
                try:
                    recorded.USE_NATIVE = False
                    current, base = recorded.batched, load_baseline(args.baseline)

                    def jax_with(module):
                        def call():
                            recorded.batched = module
                            return run_filter(kind, **batch, x0=x0, **common)
                        return call
                    jax_with(base)()  # compiles the baseline's program
                    t_new, t_old, t_nb = interleaved_times(
                        [jax_with(current), jax_with(base),
                         lambda: numba_peer.run_filter_numba(kind, *batch.values(), x0, **common)], args.repeats)
                finally:
                    recorded.USE_NATIVE, recorded.batched = saved
                ns = [v / (B * per_run) * 1e9 for v in (t_new, t_old, t_nb)]
                print(f"#   {kind} B={B}, interleaved, median of {args.repeats} rounds: pure JAX {ns[0]:,.0f} ns, "
                      f"baseline pure JAX {ns[1]:,.0f} ns, numba {ns[2]:,.0f} ns; pure JAX / numba {ns[0] / ns[2]:.2f}, "
                      f"baseline / numba {ns[1] / ns[2]:.2f}; load {os.getloadavg()[0]:.1f}", flush=True)
            del batch


if __name__ == "__main__":
    main()
