"""Every core, and the compilation cache: the same sweep on 1 and on N CPU devices, cold and warm.

What is run. For each workload below, the same runs through ``mcjax.engine.run_chunks`` in fresh
subprocesses (the device count is fixed when JAX starts):

1. ``MCJAX_CPU_DEVICES=1``, then ``=N`` (default: the machine's cores), each with an empty
   compilation cache: wall time of the first chunk (compilation included) and of the rest;
2. ``=N`` again with the cache the previous run filled: the time until the batch program is
   ready (loaded from disk instead of traced and compiled);

and checks that all of them computed the same bits.

Workloads (each from its config as shipped):

* ``closed`` — Sun et al. 2011's closed loop (``configs/sun2011.toml``: gradient planner,
  τ_r fixed at 3, t_r = 5), filters ICF / modified ICF / CIF, 200 steps;
* ``imm`` — Ren & Lv 2017's consensus IMM-UKF (``configs/ren2017.toml``), 6 UUVs;
* ``wind`` — Chen & Lu 2013 (``configs/chen2013.toml``), 3 UAVs, 100 steps.

How to run::

    python benchmarks/speed/cores.py                         # all three, default run counts (~5 min)
    python benchmarks/speed/cores.py --workloads closed --runs 400

Prints one row per workload: runs, wall time per run on 1 and on N devices (compilation
excluded), their ratio, the time until the batch programs are ready on N devices with an
empty cache (tracing and compiling once, then loading the program on the other devices) and with the cache
filled (loading) — both estimated as the first chunk's time less its computing at the
measured rate —, and whether the outputs are bit-identical. Times exclude starting Python
and importing JAX and mcjax (~2 s here).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
WORKLOADS = {
    "closed": ("configs/sun2011.toml", {"filters": ("icf", "modified_icf", "cif")}, 400),
    "imm": ("configs/ren2017.toml", {}, 2000),
    "wind": ("configs/chen2013.toml", {}, 4000),
}

CHILD = r"""
import dataclasses, json, sys, time
import numpy as np
from mcjax import engine, runtime
from mcjax.study import load_config_file
from mcjax import configure

configure()  # JAX's 64-bit mode and CPU devices, as the CLI sets them

path, overrides, runs, out = sys.argv[1], json.loads(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
sc, cfg, values = load_config_file(path)
cfg = dataclasses.replace(cfg, **{k: tuple(v) if isinstance(v, list) else v for k, v in overrides.items()})
points = engine.stack_points([sc.default_params(cfg, **values)])
b = engine.batch_size_for(runs)
n_dev = runtime.settings()["cpu_devices"]
t0 = time.perf_counter()
first = [o for *_, o in engine.run_chunks(sc, cfg, points, runs, chunk_size=n_dev * b, chunks=[0])]
t1 = time.perf_counter()
rest = [o for *_, o in engine.run_chunks(sc, cfg, points, runs, chunk_size=n_dev * b)][1:]
t2 = time.perf_counter()
outs = first + rest
np.savez(out, **{k: np.concatenate([o[k] for o in outs]) for k in outs[0]})
done_first = min(runs, n_dev * b)
print(json.dumps({"devices": n_dev, "first_chunk_s": t1 - t0, "first_runs": done_first, "rest_s": t2 - t1,
                  "rest_runs": runs - done_first, "loaded": runtime.STATS["loaded"]}))
"""


def child(config: str, overrides: dict, runs: int, devices: int, cache: str, out: Path) -> dict:
    env = {**os.environ, "MCJAX_CPU_DEVICES": str(devices), "MCJAX_CACHE_DIR": cache}
    r = subprocess.run([sys.executable, "-c", CHILD, str(ROOT / config), json.dumps(overrides), str(runs), str(out)],
                       env=env, capture_output=True, text=True, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def same(a: Path, b: Path) -> bool:
    import numpy as np

    x, y = np.load(a), np.load(b)
    return set(x.files) == set(y.files) and all(np.array_equal(x[k], y[k], equal_nan=True) for k in x.files)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workloads", nargs="+", choices=list(WORKLOADS), default=list(WORKLOADS))
    ap.add_argument("--runs", type=int, default=None, help="runs per workload (default: per workload)")
    ap.add_argument("--devices", type=int, default=os.cpu_count() or 1)
    args = ap.parse_args(argv)
    print(f"{os.cpu_count()} cores; 1 vs {args.devices} CPU devices; load average {os.getloadavg()[0]:.2f}", flush=True)
    print(f"{'workload':9s} {'runs':>6s} {'ms/run 1 dev':>13s} {'ms/run N dev':>13s} {'speed-up':>9s} "
          f"{'program ready: cold':>20s} {'warm':>6s} {'same bits':>10s}")
    ok = True
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for name in args.workloads:
            config, overrides, default_runs = WORKLOADS[name]
            runs = args.runs or default_runs
            one = child(config, overrides, runs, 1, "off", tmp / f"{name}1.npz")
            cache = str(tmp / f"cache_{name}")
            many = child(config, overrides, runs, args.devices, cache, tmp / f"{name}N.npz")
            warm = child(config, overrides, runs, args.devices, cache, tmp / f"{name}W.npz")
            per1 = 1e3 * one["rest_s"] / max(one["rest_runs"], 1)
            perN = 1e3 * many["rest_s"] / max(many["rest_runs"], 1)
            bits = same(tmp / f"{name}1.npz", tmp / f"{name}N.npz") and same(tmp / f"{name}1.npz", tmp / f"{name}W.npz")
            ok &= bits and warm["loaded"] == args.devices
            # time until the batch programs were ready: the first chunk's time less its computing
            cold = many["first_chunk_s"] - perN * many["first_runs"] / 1e3
            hot = warm["first_chunk_s"] - perN * warm["first_runs"] / 1e3
            print(f"{name:9s} {runs:6d} {per1:13.2f} {perN:13.2f} {per1 / perN:8.2f}x {cold:19.1f}s {hot:5.1f}s "
                  f"{str(bits):>10s}  (the warm run loaded {warm['loaded']} of {args.devices} programs)", flush=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
