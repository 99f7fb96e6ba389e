"""Where the closed loop's time goes: XLA's kernels of one batch call, summed by kind.

What is run. Sun et al. 2011's closed loop (``configs/sun2011.toml``: gradient planner, τ_r fixed
at 3, t_r = 5), filters ICF / modified ICF / CIF, 200 steps, ``--runs`` runs in one compiled
call on one CPU device. The program is compiled and called once, then called once more under
``jax.profiler`` with XLA's per-kernel trace events on; the events are summed per kernel
(and per kind of kernel: the name without its number). Prints the total kernel time, the
kinds that take the most, and with ``--match TEXT`` every kernel whose name contains TEXT
with its output shape and the operation JAX named it after (to find it in the source).

How to run (sets ``XLA_FLAGS`` itself; ~1 min)::

    python benchmarks/speed/profile_closed_loop.py
    python benchmarks/speed/profile_closed_loop.py --match dynamic-update-slice

The per-kernel times are wall times of a shared machine: compare versions side by side, in
turn, more than once (docs/benchmarks.md, 2026-12-02).
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import gzip
import json
import os
import re
import sys
import tempfile
from pathlib import Path

os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --xla_cpu_enable_xprof_traceme=true".strip()
os.environ["MCJAX_CPU_DEVICES"] = "1"

import jax  # noqa: E402
import numpy as np  # noqa: E402

from mcjax import engine  # noqa: E402
from mcjax.study import load_config_file  # noqa: E402
from mcjax import configure  # noqa: E402

configure()  # JAX's 64-bit mode and CPU devices, as the CLI sets them

ROOT = Path(__file__).resolve().parents[2]


def kernel_times(trace_dir: Path) -> tuple[collections.Counter, collections.Counter]:
    """Microseconds and call counts per kernel from the perfetto trace in ``trace_dir``
    (the runtime's own events — executor, Python frames, loops that contain kernels — left out)."""
    path = sorted(trace_dir.rglob("*.trace.json.gz"))[-1]
    events = json.load(gzip.open(path))["traceEvents"]
    time, calls = collections.Counter(), collections.Counter()
    for e in events:
        name = e.get("name", "")
        if e.get("ph") != "X" or name.startswith(("$", "ThunkExecutor", "while", "conditional", "end:")):
            continue
        time[name] += e.get("dur", 0)
        calls[name] += 1
    return time, calls


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=100, help="runs in the one compiled call (default 100)")
    ap.add_argument("--top", type=int, default=25, help="kinds of kernel to print (default 25)")
    ap.add_argument("--match", default=None, help="also print every kernel whose name contains this text")
    args = ap.parse_args(argv)
    if args.runs < 1 or args.top < 1:
        ap.error("--runs and --top must be >= 1")
    sc, cfg, values = load_config_file(ROOT / "configs" / "sun2011.toml")
    cfg = dataclasses.replace(cfg, filters=("icf", "modified_icf", "cif"))
    p = sc.default_params(cfg, **values)
    params = jax.tree.map(lambda x: np.broadcast_to(np.asarray(x), (args.runs,) + np.shape(x)).copy(), p)
    keys = jax.vmap(lambda i: engine.run_key(0, i))(np.arange(args.runs))
    program = jax.jit(lambda pp, kk: engine.simulate(sc, cfg, pp, kk)).lower(params, keys).compile()
    jax.block_until_ready(program(params, keys))
    with tempfile.TemporaryDirectory() as tmp:
        with jax.profiler.trace(tmp, create_perfetto_trace=True):
            jax.block_until_ready(program(params, keys))
        time, calls = kernel_times(Path(tmp))
    kinds, kind_calls = collections.Counter(), collections.Counter()
    for name, us in time.items():
        kind = re.sub(r"\.\d+$", "", name)
        kinds[kind] += us
        kind_calls[kind] += calls[name]
    print(f"{args.runs} runs x {cfg.n_steps} steps, one call: kernels {sum(time.values()) / 1e3:.1f} ms in all")
    for kind, us in kinds.most_common(args.top):
        print(f"{us / 1e3:10.2f} ms {kind_calls[kind]:8d} calls  {kind}")
    if args.match:
        hlo = program.as_text()
        for name, us in time.most_common():
            if args.match in name:
                m = re.search(r"%" + re.escape(name) + r" = (\S+) .*?op_name=\"([^\"]*)\"", hlo)
                where = f"{m.group(1)} {m.group(2)[-100:]}" if m else ""
                print(f"{us / 1e3:10.2f} ms {calls[name]:8d} calls  {name}  {where}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
