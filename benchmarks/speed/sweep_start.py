"""How long `mcjax sweep` takes to start computing: with an empty program store (the batch
program is traced and compiled) and again with it filled (the program is loaded from disk).

What is run. ``mcjax sweep SPEC`` (default: ``sweeps/default.toml``, Sun et al. 2011's closed
loop with three filters; every CPU core, as shipped) in a fresh Python process each time,
through the CLI's own entry point, stopped once the engine has the batch program on every
device. The first device starts computing as soon as its program is there (the others' are
still loading in the background). Each round uses a new, empty program
store (``MCJAX_CACHE_DIR`` pointed at a temporary folder): one cold start, then ``--warm``
warm starts on the store the cold one filled.

Prints per start the seconds from launching the process to: JAX imported, the engine asking
for its programs (mcjax imported, spec read, first inputs made), the first device's program
ready (its first batch starts), and every device's program ready. Python's own start-up is included: it is what a researcher waits for.

``--jax-cache`` measures JAX's own persistent compilation cache instead of the engine's program
store (the store turned off, ``MCJAX_CACHE_DIR=off``; JAX's cache switched on in a new folder
per round, every program kept: ``jax_persistent_cache_min_compile_time_secs = 0``). ``--full``
lets each sweep run to its end and prints its exit status and total time too (a program loaded
from a cache must also run).

How to run (~1 min per round on the 2-core VM)::

    python benchmarks/speed/sweep_start.py
    python benchmarks/speed/sweep_start.py --rounds 3 --warm 2 --spec sweeps/default.toml
    python benchmarks/speed/sweep_start.py --rounds 3 --warm 1 --jax-cache --full
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# Run in the child: time marks against the parent's launch time (argv[1]), then the CLI.
CHILD = r"""
import json, os, sys, time
t0 = float(sys.argv[1]); full = sys.argv[2] == "full"; jax_cache = sys.argv[3]; marks = {}
import jax
marks["jax imported"] = time.time() - t0
if jax_cache:
    jax.config.update("jax_compilation_cache_dir", jax_cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
from mcjax import cli, engine
build = engine.program_futures

def ready(*a, **k):
    marks["programs asked"] = time.time() - t0
    futures = build(*a, **k)
    marks["first device computes"] = time.time() - t0
    for f in futures:
        f.result()
    marks["all devices ready"] = time.time() - t0
    print("MARKS " + json.dumps(marks), flush=True)
    if not full:
        os._exit(0)
    return futures

engine.program_futures = ready
sys.argv = ["mcjax", "sweep", *sys.argv[4:]]
cli.main()
"""


def start(spec: str, out: Path, cache: Path, jax_cache: bool = False, full: bool = False) -> dict:
    env = {**os.environ, "MCJAX_CACHE_DIR": "off" if jax_cache else str(cache)}
    t0 = time.time()
    r = subprocess.run([sys.executable, "-c", CHILD, repr(t0), "full" if full else "start",
                        str(cache) if jax_cache else "", spec, "--out", str(out), "--force"],
                       env=env, cwd=ROOT, capture_output=True, text=True, timeout=1800)
    line = next((x for x in r.stdout.splitlines() if x.startswith("MARKS ")), None)
    if line is None:
        raise SystemExit(f"the sweep did not reach its programs (exit {r.returncode}):\n{r.stderr[-2000:]}")
    marks = json.loads(line[6:])
    if full:
        marks["sweep done"] = time.time() - t0
        marks["exit"] = r.returncode
        marks["error"] = (r.stderr.strip().splitlines() or [""])[-1] if r.returncode else ""
    return marks


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spec", default="sweeps/default.toml")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--warm", type=int, default=2, help="warm starts per round")
    ap.add_argument("--jax-cache", action="store_true",
                    help="JAX's persistent compilation cache instead of the engine's program store")
    ap.add_argument("--full", action="store_true", help="run each sweep to its end (exit status, total time)")
    args = ap.parse_args(argv)
    if args.rounds < 1 or args.warm < 0:
        ap.error("--rounds must be >= 1 and --warm >= 0")
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
                marks = start(args.spec, Path(tmp) / "out", cache, args.jax_cache, args.full)
                ready[kind].append(marks["first device computes"])
                status = f"  exit {marks['exit']} {marks['error'][:120]}" if args.full else ""
                print(f"{r + 1:5d}  {kind:6s} " + " ".join(f"{marks[c]:22.2f}" for c in cols) + status, flush=True)
    for kind, v in ready.items():
        if v:
            print(f"{kind}: the first device computes after {min(v):.2f}-{max(v):.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
