"""What the closed loop's two speed options buy, side by side: XLA's older CPU fusion emitters
(compilation) and the float32 planner (run time).

What is run. Sun et al. 2011's closed loop (``configs/sun2011.toml``: gradient planner, τ_r = 3,
t_r = 5), filters ICF / modified ICF / CIF, ``--steps`` steps, one batch of ``--runs`` runs on
one CPU device, in three variants:

* ``XLA default emitters`` — the scenario without ``compiler_options`` (XLA's defaults);
* ``older emitters`` — as shipped (``mcjax.contract.FAST_COMPILE``);
* ``older emitters, float32 planner`` — also ``plan_dtype = "float32"``.

Each round builds every variant afresh (trace, lower, compile, through the engine; no program
store) and times one call of the built program (after a first call); the variants take turns
within a round, so a drifting machine affects them alike. Prints per round and variant the
build time (wall and CPU seconds) and ms per run, then the largest difference of each run's
summary outputs from the shipped variant's (the float32 planner's runs differ by chaos near
divergence; its statistics over many runs are compared in docs/benchmarks.md).

How to run (~3 min per round on the 2-core VM)::

    python benchmarks/speed/closed_loop_options.py
    python benchmarks/speed/closed_loop_options.py --rounds 1 --runs 50 --steps 100
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MCJAX_CPU_DEVICES", "1")

import jax  # noqa: E402
import numpy as np  # noqa: E402

from mcjax import engine  # noqa: E402
from mcjax.study import load_config_file  # noqa: E402
from mcjax import configure  # noqa: E402

configure()  # JAX's 64-bit mode and CPU devices, as the CLI sets them

ROOT = Path(__file__).resolve().parents[2]


def _variants(sc, cfg) -> dict:
    """name -> (scenario, config); a new scenario object each call, so each round compiles."""
    return {
        "XLA default emitters": (dataclasses.replace(sc, compiler_options=None), cfg),
        "older emitters": (dataclasses.replace(sc), cfg),
        "older emitters, float32 planner": (dataclasses.replace(sc), dataclasses.replace(cfg, plan_dtype="float32")),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--steps", type=int, default=200)
    args = ap.parse_args(argv)
    if min(args.rounds, args.runs, args.steps) < 1:
        ap.error("--rounds, --runs and --steps must be >= 1")
    sc, base, values = load_config_file(ROOT / "configs" / "sun2011.toml")
    base = dataclasses.replace(base, filters=("icf", "modified_icf", "cif"), n_steps=args.steps,
                               warmup_steps=min(base.warmup_steps, args.steps - 1))
    points = engine.stack_points([sc.default_params(base, **values)])
    params, keys = engine.chunk_inputs(points, args.runs, 0, 0, args.runs, args.runs)
    dev = engine.devices()[:1]
    print(f"Sun et al. 2011 closed loop, {args.runs} runs x {args.steps} steps, one CPU device, "
          f"{time.strftime('%Y-%m-%d %H:%M')}")
    print(f"{'round':>5s}  {'variant':32s} {'build s':>8s} {'build CPU s':>12s} {'ms/run':>8s} {'load':>5s}")
    outs = {}
    for r in range(args.rounds):
        for name, (scenario, cfg) in _variants(sc, base).items():
            w0, c0 = time.perf_counter(), time.process_time()
            program = engine.programs(engine.compiled(scenario, cfg), (params, keys), dev, None)[0]
            w1, c1 = time.perf_counter(), time.process_time()
            jax.block_until_ready(program(params, keys))
            t = time.perf_counter()
            out = jax.tree.map(np.asarray, program(params, keys))
            per = 1e3 * (time.perf_counter() - t) / args.runs
            outs[name] = out
            print(f"{r:5d}  {name:32s} {w1 - w0:8.1f} {c1 - c0:12.1f} {per:8.1f} {os.getloadavg()[0]:5.1f}",
                  flush=True)
    ref = outs["older emitters"]
    print("\nlargest |difference| of a run's summary from the shipped variant's (last round):")
    for name, out in outs.items():
        worst = {k: float(np.nanmax(np.abs(np.asarray(out[k], float) - np.asarray(ref[k], float))))
                 for k in ("rmse", "final_error", "diverged", "lambda2_min")}
        print(f"  {name:32s} " + "  ".join(f"{k} {v:.3g}" for k, v in worst.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
