"""A sweep started in fresh processes under different conditions, timed; the outputs checked bit-identical.
Three measurements, a subcommand each (``--help`` after one lists its options):

* ``cores`` — every core and the compilation cache. For each workload (its config as shipped:
  ``closed``, Sun et al. 2011's closed loop, ``configs/sun2011.toml``, filters ICF / modified ICF /
  CIF, 200 steps, 400 runs; ``imm``, Ren & Lv 2017's IMM-UKF, ``configs/ren2017.toml``, 2000 runs;
  ``wind``, Chen & Lu 2013, ``configs/chen2013.toml``, 4000 runs), the same runs through
  ``mcjax.engine.run_chunks`` in a fresh process with ``MCJAX_CPU_DEVICES=1``, then ``=N``
  (``--devices``, default: the cores) with an empty compilation cache, then ``=N`` with the cache
  that run filled; a chunk is a batch per device. Prints per workload the ms per run on 1 and N
  devices (the chunks after the first), their ratio, the time until the batch programs are ready on
  N devices cold (traced, compiled, loaded on the other devices) and warm (loaded) — the first
  chunk's time less its computing at that rate; starting Python and importing mcjax excluded — and
  whether all three computed the same bits.
* ``start`` — how long ``mcjax sweep SPEC`` (``--spec``, default ``sweeps/default.toml``, relative to
  the repository) takes to start computing: each round a new, empty program store
  (``MCJAX_CACHE_DIR``), one cold start, then ``--warm`` warm starts on it, each through the CLI in a
  fresh process stopped once every device has its program. Prints per start the seconds from
  launching the process to: JAX imported, the engine asking for its programs, the first device's
  program ready (it starts computing), every device's ready. ``--jax-cache``: JAX's persistent
  compilation cache instead (the store off, every program kept); ``--full``: each sweep runs to its
  end (also its total time and exit status).
* ``dask`` — the spec (``--seeds``, ``--chunk-size``) with one JAX CPU device per process, in this
  process, then on a ``LocalCluster`` of 1 and of 2 workers (``mcjax.study.dask.local_cluster``):
  the cluster's start, once cold (the workers import mcjax and compile), then ``--rounds`` times warm,
  the clusters in turn; every run's bytes checked against the local ones. Then the cost per chunk:
  many small chunks (open loop, 10 steps, ``--overhead-points`` points x 100 seeds, a chunk per point)
  warm, locally and on 1 worker, the least of ``--repeat`` timings each; the difference per chunk is
  what Dask adds; also the size of one chunk's rows pickled and a task's round trip with them.
  ``--overhead-only``: the cost per chunk only. Needs Dask (``pip install -e ".[dask]"``).

How to run (cores ~5 min; start ~1 min per round; dask ~10 min on the 2-core VM)::

    python benchmarks/speed/sweep_conditions.py cores
    python benchmarks/speed/sweep_conditions.py cores --workloads closed --runs 400
    python benchmarks/speed/sweep_conditions.py start
    python benchmarks/speed/sweep_conditions.py start --rounds 3 --warm 2 --spec sweeps/default.toml
    python benchmarks/speed/sweep_conditions.py start --rounds 3 --warm 1 --jax-cache --full
    python benchmarks/speed/sweep_conditions.py dask
    python benchmarks/speed/sweep_conditions.py dask --seeds 50 --chunk-size 100
    python benchmarks/speed/sweep_conditions.py dask --overhead-only
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
WORKLOADS = {  # name: (config, Config changes, default runs)
    "closed": ("configs/sun2011.toml", {"filters": ("icf", "modified_icf", "cif")}, 400),
    "imm": ("configs/ren2017.toml", {}, 2000),
    "wind": ("configs/chen2013.toml", {}, 4000),
}

# Children: argv[1] is the parent's launch time; each prints one line "RESULT {json}".
CORES_CHILD = r"""
import dataclasses, json, sys, time
import numpy as np
from mcjax import configure
from mcjax import engine, runtime
from mcjax.study import load_config_file

configure()  # JAX's 64-bit mode and CPU devices, as the CLI sets them

path, overrides, runs, out = sys.argv[2], json.loads(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
sc, cfg, values = load_config_file(path)
cfg = dataclasses.replace(cfg, **{k: tuple(v) if isinstance(v, list) else v for k, v in overrides.items()})
points = engine.stack_points([sc.default_params(cfg, **values)])
chunk = runtime.settings()["cpu_devices"] * engine.batch_size_for(runs)
t0 = time.perf_counter()
first = [o for *_, o in engine.run_chunks(sc, cfg, points, runs, chunk_size=chunk, chunks=[0])]
t1 = time.perf_counter()
rest = [o for *_, o in engine.run_chunks(sc, cfg, points, runs, chunk_size=chunk,
                                          chunks=list(range(1, -(-runs // chunk))))]  # the chunks after the first
t2 = time.perf_counter()
outs = first + rest
np.savez(out, **{k: np.concatenate([o[k] for o in outs]) for k in outs[0]})
print("RESULT " + json.dumps({"first_chunk_s": t1 - t0, "first_runs": min(runs, chunk), "rest_s": t2 - t1,
                              "rest_runs": runs - min(runs, chunk), "loaded": runtime.STATS["loaded"]}))
"""

START_CHILD = r"""
import json, os, sys, time
t0 = float(sys.argv[1]); full = sys.argv[2] == "full"; jax_cache = sys.argv[3]; marks = {}
import jax
marks["jax imported"] = time.time() - t0
if jax_cache:
    jax.config.update("jax_compilation_cache_dir", jax_cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
from mcjax import cli
from mcjax.engine import chunks
build = chunks.program_futures  # the name run_chunks calls

def ready(*a, **k):
    marks["programs asked"] = time.time() - t0
    futures = build(*a, **k)
    marks["first device computes"] = time.time() - t0
    for f in futures:
        f.result()
    marks["all devices ready"] = time.time() - t0
    print("RESULT " + json.dumps(marks), flush=True)
    if not full:
        os._exit(0)
    return futures

chunks.program_futures = ready
sys.argv = ["mcjax", "sweep", *sys.argv[4:]]
cli.main()
"""


def child(code: str, args: list, env: dict) -> dict:
    """Run ``code`` in a fresh Python process (``env`` added to ours, in the repository): the dict
    it printed, its seconds from launch to exit, its exit status and last error line."""
    t0 = time.time()
    r = subprocess.run([sys.executable, "-c", code, repr(t0), *map(str, args)], env={**os.environ, **env},
                       cwd=ROOT, capture_output=True, text=True, timeout=3600)
    line = next((x for x in r.stdout.splitlines() if x.startswith("RESULT ")), None)
    if line is None:
        raise SystemExit(f"the child stopped before its result (exit {r.returncode}):\n{r.stderr[-2000:]}")
    error = (r.stderr.strip().splitlines() or [""])[-1] if r.returncode else ""
    return {**json.loads(line[7:]), "wall_s": time.time() - t0, "exit": r.returncode, "error": error}


def same(a, b) -> bool:
    """Bit-identical outputs: two DataFrames, or two .npz files (NaN equal to NaN)."""
    if not isinstance(a, Path):
        return list(a.columns) == list(b.columns) and a.equals(b)
    import numpy as np

    x, y = np.load(a), np.load(b)
    return set(x.files) == set(y.files) and all(np.array_equal(x[k], y[k], equal_nan=True) for k in x.files)


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def cores(args) -> int:
    print(f"{os.cpu_count()} cores; 1 vs {args.devices} CPU devices; load average {os.getloadavg()[0]:.2f}", flush=True)
    print(f"{'workload':9s} {'runs':>6s} {'ms/run 1 dev':>13s} {'ms/run N dev':>13s} {'speed-up':>9s} "
          f"{'program ready: cold':>20s} {'warm':>6s} {'same bits':>10s}")
    ok = True
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name in args.workloads:
            config, overrides, default_runs = WORKLOADS[name]
            runs = args.runs or default_runs
            res = {}
            for kind, devices, cache in (("1", 1, "off"), ("N", args.devices, tmp / f"cache_{name}"),
                                         ("W", args.devices, tmp / f"cache_{name}")):
                res[kind] = child(CORES_CHILD, [ROOT / config, json.dumps(overrides), runs, tmp / f"{name}{kind}.npz"],
                                  {"MCJAX_CPU_DEVICES": str(devices), "MCJAX_CACHE_DIR": str(cache)})
            one, many, warm = res["1"], res["N"], res["W"]
            per1, perN = (1e3 * r["rest_s"] / r["rest_runs"] if r["rest_runs"] else float("nan") for r in (one, many))
            bits = all(same(tmp / f"{name}1.npz", tmp / f"{name}{k}.npz") for k in "NW")
            ok &= bits and warm["loaded"] == args.devices
            # time until the batch programs were ready: the first chunk's time less its computing
            cold = many["first_chunk_s"] - perN * many["first_runs"] / 1e3
            hot = warm["first_chunk_s"] - perN * warm["first_runs"] / 1e3
            print(f"{name:9s} {runs:6d} {per1:13.2f} {perN:13.2f} {per1 / perN:8.2f}x {cold:19.1f}s {hot:5.1f}s "
                  f"{str(bits):>10s}  (the warm run loaded {warm['loaded']} of {args.devices} programs)", flush=True)
    return 0 if ok else 1


def start(args) -> int:
    if args.rounds < 1 or args.warm < 0:
        raise SystemExit("--rounds must be >= 1 and --warm >= 0")
    print(f"mcjax sweep {args.spec}: seconds from launching the process, {time.strftime('%Y-%m-%d %H:%M')}, "
          f"{os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}, "
          f"{'JAX' if args.jax_cache else 'the engine'}'s cache")
    cols = ("jax imported", "programs asked", "first device computes", "all devices ready")
    cols += ("sweep done",) * args.full
    print(f"{'round':>5s}  {'start':6s} " + " ".join(f"{c:>22s}" for c in cols))
    ready = {"cold": [], "warm": []}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            cache = Path(tmp) / f"store{r}"
            for kind in ["cold"] + ["warm"] * args.warm:
                marks = child(START_CHILD, ["full" if args.full else "start", cache if args.jax_cache else "",
                                            args.spec, "--out", Path(tmp) / "out", "--force"],
                              {"MCJAX_CACHE_DIR": "off" if args.jax_cache else str(cache)})
                marks["sweep done"] = marks["wall_s"]
                ready[kind].append(marks["first device computes"])
                status = f"  exit {marks['exit']} {marks['error'][:120]}" if args.full else ""
                print(f"{r + 1:5d}  {kind:6s} " + " ".join(f"{marks[c]:22.2f}" for c in cols) + status, flush=True)
    for kind, v in ready.items():
        if v:
            print(f"{kind}: the first device computes after {min(v):.2f}-{max(v):.2f} s")
    return 0


def _echo(rows):
    """A task that returns its input (Dask's round trip, nothing computed)."""
    return rows


def dask(args) -> int:
    os.environ["MCJAX_CPU_DEVICES"] = "1"  # before mcjax starts JAX: one core per process (and per worker)
    from mcjax.study import chunk_rows, load_spec, run_sweep
    from mcjax.study.dask import DaskExecutor, DaskMissing, load_distributed, local_cluster

    try:
        distributed = load_distributed()
    except DaskMissing as e:
        raise SystemExit(str(e)) from None
    path = ROOT / args.spec
    spec = load_spec(path, seeds=args.seeds, chunk_size=args.chunk_size)
    small = load_spec(path, chunk_size=100, overrides={
        "config.planner": "none", "config.n_steps": 10, "config.warmup_steps": 2, "seeds": 100,
        "grid.comm_radius": [40e3 + 1e3 * i for i in range(args.overhead_points)]})
    print(f"spec {args.spec}: {spec.n_points} points x {spec.seeds} seeds = {spec.n_runs} runs, "
          f"{-(-spec.n_runs // args.chunk_size)} chunks of {args.chunk_size}; "
          f"small: {small.n_runs} runs in {small.n_points} chunks")

    def least(fn):
        fn()  # compiles
        return min(timed(fn)[1] for _ in range(args.repeat))

    ok = True
    small_local = least(lambda: run_sweep(small))
    rows = next(chunk_rows(small, [0]))
    size = len(pickle.dumps(rows, protocol=5))
    if not args.overhead_only:
        ref, cold = timed(lambda: run_sweep(spec))
        _, warm = timed(lambda: run_sweep(spec))
        print(f"local (this process, 1 core): cold {cold:.1f} s, warm {warm:.1f} s", flush=True)
    print(f"small sweep, local: {small_local:.2f} s; one chunk's rows: {size} bytes pickled", flush=True)
    clusters = {}
    with contextlib.ExitStack() as stack:
        for n in ((1,) if args.overhead_only else (1, 2)):
            cluster, t = timed(lambda: stack.enter_context(local_cluster(n)))
            client = stack.enter_context(distributed.Client(cluster, set_as_default=False))
            ex = clusters[n] = DaskExecutor(client)
            line = f"dask, {n} worker(s): cluster start {t:.1f} s"
            if not args.overhead_only:
                df, cold = timed(lambda: run_sweep(spec, executor=ex))
                bits = same(df, ref)
                ok &= bits
                line += f", cold {cold:.1f} s (same bytes as local: {bits})"
            if n == 1:
                small_dask = least(lambda: run_sweep(small, executor=ex))
                per_chunk = (small_dask - small_local) / small.n_points
                line += f"; small sweep {small_dask:.2f} s = {1e3 * per_chunk:.0f} ms per chunk more than local"
                # one task at a time that returns a chunk's rows: Dask's own cost per chunk, nothing computed
                trip = min(timed(lambda: client.submit(_echo, rows, pure=False).result())[1]
                           for _ in range(20 * args.repeat))
                line += f"; a task returning one chunk's rows: {1e3 * trip:.1f} ms"
            print(line, flush=True)
        if args.overhead_only:
            return 0
        # warm sweeps, 1 and 2 workers in turn, so both see the same load on a shared machine
        warm = {1: [], 2: []}
        for _ in range(args.rounds):
            for n in (1, 2):
                df, t = timed(lambda: run_sweep(spec, executor=clusters[n]))
                ok &= same(df, ref)
                warm[n].append(t)
        for n in (1, 2):
            print(f"dask, {n} worker(s), warm: least {min(warm[n]):.1f} s, median {statistics.median(warm[n]):.1f} s "
                  f"of {args.rounds} (same bytes as local: {ok})", flush=True)
        print(f"2 workers vs 1: {min(warm[1]) / min(warm[2]):.2f}x (least), "
              f"{statistics.median(warm[1]) / statistics.median(warm[2]):.2f}x (median)")
    return 0 if ok else 1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="what", required=True)
    p = sub.add_parser("cores", help="1 vs N CPU devices, cold vs warm compilation cache")
    p.add_argument("--workloads", nargs="+", choices=list(WORKLOADS), default=list(WORKLOADS))
    p.add_argument("--runs", type=int, default=None, help="runs per workload (default: per workload)")
    p.add_argument("--devices", type=int, default=os.cpu_count() or 1)
    p = sub.add_parser("start", help="mcjax sweep's start, empty vs filled program store")
    p.add_argument("--spec", default="sweeps/default.toml", help="relative to the repository")
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--warm", type=int, default=2, help="warm starts per round")
    p.add_argument("--jax-cache", action="store_true",
                   help="JAX's persistent compilation cache instead of the engine's program store")
    p.add_argument("--full", action="store_true", help="run each sweep to its end (exit status, total time)")
    p = sub.add_parser("dask", help="a Dask cluster of 1 and 2 workers vs this process; the cost per chunk")
    p.add_argument("--spec", default="sweeps/default.toml", help="relative to the repository")
    p.add_argument("--seeds", type=int, default=None)
    p.add_argument("--chunk-size", type=int, default=100)
    p.add_argument("--overhead-points", type=int, default=40)
    p.add_argument("--repeat", type=int, default=5, help="small sweeps timed this many times (the least counts)")
    p.add_argument("--overhead-only", action="store_true", help="only the cost per chunk")
    p.add_argument("--rounds", type=int, default=3, help="warm sweeps on each cluster, in turn")
    args = ap.parse_args(argv)
    return {"cores": cores, "start": start, "dask": dask}[args.what](args)


if __name__ == "__main__":
    sys.exit(main())
