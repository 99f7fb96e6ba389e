"""What the closed loop of Sun et al. 2011 costs, and what planning only when due buys.

What is run. ``configs/sun2011.toml`` (gradient planner, 10 Adam steps per plan, t_r = 5,
τ_r = 3; filters ICF / modified ICF / CIF) in three compiled variants, the same runs and
seeds, in one process:

* ``every step`` — ``plan_period = 0``, ``max_horizon = 8``: the program before this
  benchmark existed; it plans at every step (so τ_r may vary inside a batch) and rolls out
  8 steps, masking those past t_r;
* ``when due`` — ``plan_period = 3``: the planner sits in a ``lax.cond`` on the step and runs
  only on re-plan steps;
* ``when due, t_r rollout`` — also ``max_horizon = 5``: the rollout is the horizon itself
  (the shipped config).

For each: the compile-and-first-chunk time, then the wall time of ``--runs`` runs of
``--steps`` steps (compiled), ms per run, the speed-up over the first variant, and whether
every output is bit-identical to the first variant's.

How to run::

    python benchmarks/speed/closed_loop_speed.py                      # 400 runs x 200 steps (~5 min)
    python benchmarks/speed/closed_loop_speed.py --runs 200 --steps 60

Run it with ``MCJAX_CPU_DEVICES=1`` to time one core (the default uses every core).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

import numpy as np

from mcjax import engine, runtime
from mcjax.study import load_config_file
from mcjax import configure

configure()  # JAX's 64-bit mode and CPU devices, as the CLI sets them

ROOT = Path(__file__).resolve().parents[2]
VARIANTS = (("every step", dict(plan_period=0, max_horizon=8)),
            ("when due", dict(plan_period=3, max_horizon=8)),
            ("when due, t_r rollout", dict(plan_period=3, max_horizon=5)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=400)
    ap.add_argument("--steps", type=int, default=200)
    args = ap.parse_args(argv)
    sc, base, values = load_config_file(ROOT / "configs" / "sun2011.toml")
    base = dataclasses.replace(base, filters=("icf", "modified_icf", "cif"), n_steps=args.steps)
    points = engine.stack_points([sc.default_params(base, **values)])
    print(f"Sun et al. 2011 closed loop, {args.runs} runs x {args.steps} steps, {runtime.settings()['cpu_devices']} "
          f"CPU device(s), load average {os.getloadavg()[0]:.2f}")
    print(f"{'variant':24s} {'compile + 1st chunk, s':>23s} {'runs, s':>9s} {'ms/run':>8s} {'speed-up':>9s} "
          f"{'same bits':>10s}")
    ref = None
    ok = True
    for name, change in VARIANTS:
        cfg = dataclasses.replace(base, **change)
        b = engine.batch_size_for(args.runs)
        t0 = time.perf_counter()
        list(engine.run_chunks(sc, cfg, points, args.runs, chunk_size=b, chunks=[0]))
        t1 = time.perf_counter()
        outs = [o for *_, o in engine.run_chunks(sc, cfg, points, args.runs, chunk_size=args.runs)]
        t2 = time.perf_counter()
        out = {k: np.concatenate([o[k] for o in outs]) for k in outs[0]}
        per = 1e3 * (t2 - t1) / args.runs
        if ref is None:
            ref, ref_per = out, per
        same = all(np.array_equal(ref[k], out[k], equal_nan=True) for k in ref)
        ok &= same
        print(f"{name:24s} {t1 - t0:23.1f} {t2 - t1:9.1f} {per:8.1f} {ref_per / per:8.2f}x {str(same):>10s}",
              flush=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
