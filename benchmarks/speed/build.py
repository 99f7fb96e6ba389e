"""What building a config's program costs, by phase: ``trace`` (Python: the scenario's step traced into a
jaxpr), ``lower`` (the jaxpr to StableHLO) and ``XLA`` (HLO passes and LLVM to machine code) — the build every
user pays when a config changes and no stored program fits (``MCJAX_CACHE_DIR``), every ``mcjax check``, and
the test suite. Each round builds the program afresh, as ``mcjax sweep`` does (the engine's jitted program with
the scenario's compiler options, one CPU device, no program store), then calls it twice.

Prints per round the three phases' wall seconds, the build's CPU seconds, a second call's ms per run; then
the median of each phase over the rounds, and what the program holds: its StableHLO size (lines) and, after
XLA's passes, its instructions, fusions and loops — the sizes a restructuring of the program should shrink.

How to run (the closed loop of Sun et al. 2011 as shipped: ~15 s per round on the 2-core VM)::

    python benchmarks/speed/build.py                                   # configs/sun2011.toml, 3 rounds
    python benchmarks/speed/build.py configs/lou2013.toml --rounds 5
    python benchmarks/speed/build.py --set config.planner=none        # the open loop

Build times are wall times of a shared machine: compare versions in turn, and more than once.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import os
import re
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def hlo_sizes(stablehlo: str, optimized: str) -> dict:
    """The program's size before and after XLA's passes."""
    ops = collections.Counter(m.group(1) for m in re.finditer(
        r"^\s*(?:ROOT )?%\S+ = (?:\((?:[^()]|\([^()]*\))*\)|\S+) ([a-z][\w-]*)\(", optimized, re.M))
    return {"stablehlo lines": stablehlo.count("\n"), "HLO instructions": sum(ops.values()),
            "fusions": ops["fusion"], "while loops": ops["while"], "conditionals": ops["conditional"],
            "computations": len(re.findall(r"^(?:ENTRY )?%\S+ \(", optimized, re.M))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("config", nargs="?", default=str(ROOT / "configs" / "sun2011.toml"),
                    help="a config file (default: configs/sun2011.toml, the closed loop)")
    ap.add_argument("--rounds", type=int, default=3, help="builds, each afresh (default 3)")
    ap.add_argument("--runs", type=int, default=100, help="runs in the batch the program is built for (default 100)")
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                    help="as mcjax run --set: config.planner=none, params.horizon=3, …")
    args = ap.parse_args(argv)
    if args.rounds < 1 or args.runs < 1:
        ap.error("--rounds and --runs must be >= 1")
    os.environ.setdefault("MCJAX_CPU_DEVICES", "1")  # before JAX starts: one device, one program

    import jax
    import numpy as np

    from mcjax import configure, engine
    from mcjax.base.validation import set_value
    from mcjax.study import load_spec

    configure()
    overrides = {k.strip(): set_value(v.strip()) for k, _, v in (s.partition("=") for s in args.sets)}
    spec_text = f'base = "{Path(args.config).resolve().as_posix()}"\n'
    spec_file = Path(os.environ.get("TMPDIR", "/tmp")) / f"mcjax_build_{os.getpid()}.toml"
    spec_file.write_text(spec_text, encoding="utf-8")
    try:
        study = load_spec(spec_file, seeds=args.runs, overrides=overrides)
    finally:
        spec_file.unlink()
    params, keys = engine.chunk_inputs(study.params, args.runs, 0, 0, args.runs, args.runs)
    params, keys = jax.device_put((params, keys), engine.devices()[0])
    print(f"{study.scenario.name} ({Path(args.config).name}{', ' + ', '.join(args.sets) if args.sets else ''}): "
          f"{study.config.n_agents} agents, {study.config.n_steps} steps, filters {', '.join(study.config.filters)}; "
          f"a batch of {args.runs} runs, one CPU device, JAX {jax.__version__}, load average "
          f"{os.getloadavg()[0]:.2f}, {time.strftime('%Y-%m-%d %H:%M')}")
    print(f"{'round':>5s} {'trace s':>8s} {'lower s':>8s} {'XLA s':>7s} {'build s':>8s} {'build CPU s':>12s} "
          f"{'ms/run':>7s}")
    phases = collections.defaultdict(list)
    for r in range(args.rounds):
        scenario = dataclasses.replace(study.scenario)  # a new object: nothing of the last round is reused
        fn = engine.compiled(scenario, study.config)
        c0, t0 = time.process_time(), time.perf_counter()
        traced = fn.trace(params, keys)
        t1 = time.perf_counter()
        lowered = traced.lower()
        t2 = time.perf_counter()
        program = lowered.compile()
        t3, c3 = time.perf_counter(), time.process_time()
        jax.block_until_ready(program(params, keys))
        t4 = time.perf_counter()
        jax.block_until_ready(program(params, keys))
        per = 1e3 * (time.perf_counter() - t4) / args.runs
        for name, value in (("trace", t1 - t0), ("lower", t2 - t1), ("XLA", t3 - t2), ("build", t3 - t0),
                            ("CPU", c3 - c0), ("ms/run", per)):
            phases[name].append(value)
        print(f"{r:5d} {t1 - t0:8.2f} {t2 - t1:8.2f} {t3 - t2:7.2f} {t3 - t0:8.2f} {c3 - c0:12.2f} {per:7.2f}",
              flush=True)
        sizes = hlo_sizes(lowered.as_text(), program.as_text())
        del traced, lowered, program, fn
        engine.forget()
    med = {k: statistics.median(v) for k, v in phases.items()}
    print(f"{'median':>5s} {med['trace']:8.2f} {med['lower']:8.2f} {med['XLA']:7.2f} {med['build']:8.2f} "
          f"{med['CPU']:12.2f} {med['ms/run']:7.2f}")
    print("program: " + ", ".join(f"{k} {v:,}" for k, v in sizes.items()))
    del np
    return 0


if __name__ == "__main__":
    sys.exit(main())
