"""Peak memory of one gradient pass of ``mcjax tune``: 200 steps x 128 runs of the Sun et al. 2011
closed loop (sweeps/tune_sun2011.toml), reverse mode with jax.checkpoint over blocks of
``--block`` steps, and forward mode. Compiles each program and prints XLA's memory analysis of
the compiled program (arguments, outputs, temporaries); with ``--run`` it also runs one
gradient pass and prints the process's peak resident memory (``ru_maxrss``) before compiling,
after compiling and after the pass.

    python benchmarks/speed/tune_memory.py --modes reverse forward --block 10
    MCJAX_CPU_DEVICES=1 python benchmarks/speed/tune_memory.py --modes forward --run   # docs/tune.md
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--modes", nargs="+", default=["reverse", "forward"])
    ap.add_argument("--block", type=int, nargs="+", default=[10])
    ap.add_argument("--runs", type=int, default=128)
    ap.add_argument("--steps", type=int, default=200, help="simulation steps per run")
    ap.add_argument("--run", action="store_true", help="also run one pass and report the peak RSS")
    args = ap.parse_args()
    import resource

    import jax
    import numpy as np

    def rss() -> float:  # peak resident memory of this process so far, GiB (Linux: KiB)
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20

    from mcjax import tune
    from mcjax.base.validation import read_toml

    raw = read_toml(ROOT / "sweeps" / "tune_sun2011.toml", "spec")
    for mode in args.modes:
        for block in args.block if mode == "reverse" else [args.block[0]]:
            raw["tune"].update(gradient=mode, checkpoint_every=min(block, args.steps), train_seeds=args.runs)
            raw.setdefault("config", {})["n_steps"] = args.steps
            spec = tune.build_tune_spec(raw, ROOT / "sweeps")
            fn = tune.batch_function(spec)
            z = tune.to_unconstrained(spec.bounds, spec.initial())
            keys = tune.train_keys(spec)
            t = time.perf_counter()
            before = rss()
            compiled = fn.lower(z, keys, spec.study.base_params).compile()
            compiled_rss = rss()
            ma = compiled.memory_analysis()
            temp = getattr(ma, "temp_size_in_bytes", 0)
            arg = getattr(ma, "argument_size_in_bytes", 0)
            out = getattr(ma, "output_size_in_bytes", 0)
            print(f"{mode:8s} block {block:3d}: {spec.study.config.n_steps} steps x {args.runs} runs: temporaries "
                  f"{temp / 2**20:.1f} MiB, arguments {arg / 2**20:.2f} MiB, outputs {out / 2**20:.3f} MiB "
                  f"(compile {time.perf_counter() - t:.0f} s)", flush=True)
            if args.run:
                t = time.perf_counter()
                out = jax.block_until_ready(compiled(z, keys, spec.study.base_params))
                print(f"{mode:8s} block {block:3d}: one pass {time.perf_counter() - t:.0f} s; "
                      f"peak RSS {before:.2f} GiB "
                      f"before compiling, {compiled_rss:.2f} GiB after, {rss():.2f} GiB after the pass; mean loss "
                      f"{float(np.mean(out[0])):.4f}, finite gradients {int(np.all(np.isfinite(out[1]), 1).sum())}/"
                      f"{args.runs}", flush=True)


if __name__ == "__main__":
    main()
