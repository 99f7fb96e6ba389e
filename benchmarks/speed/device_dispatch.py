"""Do the CPU devices compute at once? The closed loop of Sun et al. 2011, case 2, per chunk size.

What is run. ``configs/sun2011.toml`` with the gradient planner, ICF (read as "priors") /
modified ICF / CIF, 200 steps: first a ``--warmup``-run sweep (compiles, or loads the programs
from the persistent cache), then ``--runs`` runs once for each ``--chunks`` size, on as many
CPU devices as the process has (``MCJAX_CPU_DEVICES``). Prints ms per run and the process's
CPU seconds per wall second: about 1 when the devices run one after the other, about the
device count when they run at once.

How to run (the peer is the one-device run, in a second process)::

    MCJAX_CPU_DEVICES=1 python benchmarks/speed/device_dispatch.py
    python benchmarks/speed/device_dispatch.py                  # every core
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from divergence_sun2011 import case_params, setup

from mcjax import engine, runtime
from mcjax import configure

configure()  # JAX's 64-bit mode and CPU devices, as the CLI sets them

ROOT = Path(__file__).resolve().parents[2]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=400)
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--chunks", type=int, nargs="+", default=[200, 400])
    args = ap.parse_args(argv)
    sc, cfg, params = setup(ROOT / "configs" / "sun2011.toml", "gradient", "priors")
    point = engine.stack_points([case_params(sc, cfg, params, "case2")])
    list(engine.run_chunks(sc, cfg, point, args.warmup, chunk_size=args.warmup))
    for chunk in args.chunks:
        c0, t0 = time.process_time(), time.perf_counter()
        list(engine.run_chunks(sc, cfg, point, args.runs, chunk_size=chunk, base_seed=1))
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        print(f"devices {runtime.settings()['cpu_devices']}, chunk {chunk}: {wall / args.runs * 1e3:.1f} ms per run, "
              f"CPU s per wall s {cpu / wall:.2f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
