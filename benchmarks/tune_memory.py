"""Peak memory of one gradient pass of ``mcjax tune``: 200 steps x 128 runs of the Sun et al. 2011
closed loop (sweeps/tune_sun2011.toml), reverse mode with jax.checkpoint over blocks of
``--block`` steps, and forward mode. Compiles each program (does not run it) and prints XLA's
memory analysis of the compiled program (arguments, outputs, temporaries).

    python benchmarks/tune_memory.py --modes reverse forward --block 10
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--modes", nargs="+", default=["reverse", "forward"])
    ap.add_argument("--block", type=int, nargs="+", default=[10])
    ap.add_argument("--runs", type=int, default=128)
    args = ap.parse_args()
    import jax
    import numpy as np

    from mcjax import tune

    raw = tune._read_toml(ROOT / "sweeps" / "tune_sun2011.toml", "spec")
    for mode in args.modes:
        for block in args.block if mode == "reverse" else [args.block[0]]:
            raw["tune"].update(gradient=mode, checkpoint_every=block, train_seeds=args.runs)
            spec = tune.build_tune_spec(raw, ROOT / "sweeps")
            fn = tune.batch_function(spec)
            z = tune.to_unconstrained(spec.bounds, spec.initial())
            keys = tune.train_keys(spec)
            t = time.perf_counter()
            compiled = fn.lower(z, keys, spec.sweep.base_params).compile()
            ma = compiled.memory_analysis()
            temp = getattr(ma, "temp_size_in_bytes", 0)
            arg = getattr(ma, "argument_size_in_bytes", 0)
            out = getattr(ma, "output_size_in_bytes", 0)
            print(f"{mode:8s} block {block:3d}: {spec.sweep.config.n_steps} steps x {args.runs} runs: temporaries "
                  f"{temp / 2**20:.1f} MiB, arguments {arg / 2**20:.2f} MiB, outputs {out / 2**20:.3f} MiB "
                  f"(compile {time.perf_counter() - t:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
