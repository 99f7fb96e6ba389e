"""What Sun et al. 2011's closed loop costs (``configs/sun2011.toml``: gradient planner, 10 Adam steps per
plan, τ_r = 3, t_r = 5; filters ICF / modified ICF / CIF; ``--runs`` runs of ``--steps`` steps), in
one process. Six measurements, a subcommand each:

* ``due`` — what planning only when due buys: ``every step`` (``plan_period = 0``, ``max_horizon = 8``:
  plans at every step, rolls out 8 steps masking those past t_r), ``when due`` (``plan_period = 3``: the
  planner in a ``lax.cond``, run on re-plan steps only), ``when due, t_r rollout`` (also
  ``max_horizon = 5``: as shipped), the same runs and seeds. Prints per variant the compile-and-first-
  chunk time, the runs' time (compiled), ms per run, the speed-up over the first variant and whether
  every output is bit-identical to its.
* ``options`` — ``older emitters`` (as shipped, ``mcjax.contract.FAST_COMPILE``), ``float32 planner``
  (``plan_dtype = "float32"``), ``3 steps of 1.0, float32`` (also ``plan_iterations = 3``, ``plan_learning_rate
  = 1.0``: ``sweeps/sun2011_planner_budget.toml``), one batch of all runs on one device. Each of ``--rounds`` rounds
  builds every variant afresh (trace, lower, compile; no program store) and times one call after a
  first, the variants in turn. Prints per round and variant the build's wall and CPU seconds and ms
  per run, then each run summary's largest difference from the shipped variant's (the float32
  planner's runs differ by chaos near divergence; docs/benchmarks.md compares their statistics).
* ``dispatch`` — do the CPU devices compute at once? As shipped: a ``--warmup``-run sweep (compiles
  or loads the programs), then the runs once per ``--chunks`` size. Prints ms per run and the
  process's CPU seconds per wall second (~1 when the devices take turns, ~their count when not).
* ``faults`` — the fault model's cost: ``off`` (no fault draws in the program), ``on, rates 0``, ``on,
  faults drawn`` (link loss 0.2 in bursts of 5, agent loss 0.002 per UAV and step, sensor dropout
  0.05): each run once, then timed ``--repeats`` times in turn, the best of each and its ratio to off.
* ``bound`` — the cost of the Cramér–Rao bound (``bound = "on"``), then with NEES and NIS (``consistency``).
* ``profile`` — where the time goes: the runs in one call on one device (compiled by ``jax.jit``
  without the scenario's compiler options), called once, then once more under ``jax.profiler`` with
  XLA's per-kernel trace events on (sets ``XLA_FLAGS``). Prints the kernels' total time, the
  ``--top`` kinds of kernel (the name less its number) by time and, with ``--match TEXT``, every
  kernel whose name contains TEXT with its output shape and the JAX operation it comes from.
  ``--agents N`` profiles a team of N UAVs (the paper's five, the rest in the scenario's default
  layout) and ``--filters`` runs only the filters named (``profile --runs 50 --steps 50 --agents 100
  --filters modified_icf``: where a 100-UAV closed-loop run goes, docs/benchmarks.md).

CPU devices: ``MCJAX_CPU_DEVICES`` (default every core; ``options`` 1 unless set; ``profile`` 1).
How to run (``due`` ~5 min, ``options`` ~3 min per round, ``profile`` ~1 min on the 2-core VM)::

    python benchmarks/speed/closed_loop.py due                          # 400 runs x 200 steps
    python benchmarks/speed/closed_loop.py due --runs 200 --steps 60
    python benchmarks/speed/closed_loop.py options                      # 2 rounds, 100 runs x 200 steps
    python benchmarks/speed/closed_loop.py options --rounds 1 --runs 50 --steps 100
    MCJAX_CPU_DEVICES=1 python benchmarks/speed/closed_loop.py dispatch  # one device, beside
    python benchmarks/speed/closed_loop.py dispatch                     # every core
    python benchmarks/speed/closed_loop.py profile                      # 100 runs
    python benchmarks/speed/closed_loop.py profile --match dynamic-update-slice
    python benchmarks/speed/closed_loop.py faults --runs 300

Per-kernel times are wall times of a shared machine: compare versions in turn, more than once.
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
import time
from pathlib import Path

import jax
import numpy as np

from mcjax import configure
from mcjax import engine, runtime
from mcjax.study import load_config_file

ROOT = Path(__file__).resolve().parents[2]
#: the fault rates of the "faults drawn" variant (per step; agent loss per UAV)
FAULTS = dict(link_loss=0.2, link_burst=5.0, agent_loss_rate=0.002, sensor_dropout=0.05)
VARIANTS = {  # measurement: (name, Scenario changes, Config changes) per variant
    "due": (("every step", {}, dict(plan_period=0, max_horizon=8)),
            ("when due", {}, dict(plan_period=3, max_horizon=8)),
            ("when due, t_r rollout", {}, dict(plan_period=3, max_horizon=5))),
    "options": (("older emitters", {}, {}), ("older emitters, float32 planner", {}, dict(plan_dtype="float32")),
                ("3 steps of 1.0, float32", {}, dict(plan_dtype="float32", plan_iterations=3, plan_learning_rate=1.0))),
    "dispatch": (("as shipped", {}, {}),),
    "faults": (("off", {}, {}), ("on, rates 0", {}, dict(faults="on")), ("on, faults drawn", {}, dict(faults="on"))),
    "bound": (("off", {}, {}), ("bound", {}, dict(bound="on")), ("both", {}, dict(bound="on", consistency="on"))),
    "profile": (("as shipped", {}, {}),),
}


def variants(what: str, sc, cfg) -> list:
    """(name, scenario, config) per variant; new scenario objects each call, so each call compiles anew."""
    return [(name, dataclasses.replace(sc, **s), dataclasses.replace(cfg, **c)) for name, s, c in VARIANTS[what]]


def run(sc, cfg, points, runs: int, chunk: int, **kw) -> tuple[dict, float, float]:
    """``runs`` runs through the engine in chunks of ``chunk``: the outputs, wall and CPU seconds."""
    c0, t0 = time.process_time(), time.perf_counter()
    outs = [o for *_, o in engine.run_chunks(sc, cfg, points, runs, chunk_size=chunk, **kw)]
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {k: np.concatenate([o[k] for o in outs]) for k in outs[0]}, wall, cpu


def due(args, sc, base, points) -> int:
    print(f"{'variant':24s} {'compile + 1st chunk, s':>23s} {'runs, s':>9s} {'ms/run':>8s} {'speed-up':>9s} "
          f"{'same bits':>10s}")
    ref, ok = None, True
    for name, scenario, cfg in variants("due", sc, base):
        first = run(scenario, cfg, points, args.runs, engine.batch_size_for(args.runs), chunks=[0])[1]
        out, wall, _ = run(scenario, cfg, points, args.runs, args.runs)
        per = 1e3 * wall / args.runs
        if ref is None:
            ref, ref_per = out, per
        same = all(np.array_equal(ref[k], out[k], equal_nan=True) for k in ref)
        ok &= same
        print(f"{name:24s} {first:23.1f} {wall:9.1f} {per:8.1f} {ref_per / per:8.2f}x {str(same):>10s}", flush=True)
    return 0 if ok else 1


def options(args, sc, base, points) -> int:
    params, keys = engine.chunk_inputs(points, args.runs, 0, 0, args.runs, args.runs)
    dev = engine.devices()[:1]
    print(f"{'round':>5s}  {'variant':32s} {'build s':>8s} {'build CPU s':>12s} {'ms/run':>8s} {'load':>5s}")
    outs = {}
    for r in range(args.rounds):
        for name, scenario, cfg in variants("options", sc, base):
            w0, c0 = time.perf_counter(), time.process_time()
            program = engine.programs(engine.compiled(scenario, cfg), (params, keys), dev, None)[0]
            w1, c1 = time.perf_counter(), time.process_time()
            jax.block_until_ready(program(params, keys))
            t = time.perf_counter()
            outs[name] = jax.tree.map(np.asarray, program(params, keys))
            per = 1e3 * (time.perf_counter() - t) / args.runs
            print(f"{r:5d}  {name:32s} {w1 - w0:8.1f} {c1 - c0:12.1f} {per:8.1f} {os.getloadavg()[0]:5.1f}",
                  flush=True)
    ref = outs["older emitters"]
    print("\nlargest |difference| of a run's summary from the shipped variant's (last round):")
    for name, out in outs.items():
        worst = {k: float(np.nanmax(np.abs(np.asarray(out[k], float) - np.asarray(ref[k], float))))
                 for k in ("rmse", "final_error", "diverged", "lambda2_min")}
        print(f"  {name:32s} " + "  ".join(f"{k} {v:.3g}" for k, v in worst.items()))
    return 0


def dispatch(args, sc, base, points) -> int:
    (_, scenario, cfg), = variants("dispatch", sc, base)
    run(scenario, cfg, points, args.warmup, args.warmup)
    for chunk in args.chunks:
        _, wall, cpu = run(scenario, cfg, points, args.runs, chunk, base_seed=1)
        print(f"devices {runtime.settings()['cpu_devices']}, chunk {chunk}: {wall / args.runs * 1e3:.1f} ms per run, "
              f"CPU s per wall s {cpu / wall:.2f}", flush=True)
    return 0


def timed(args, sc, base, points) -> int:
    """The cost of an option (``faults``, ``bound``): every variant compiled and run once, then timed
    ``--repeats`` times in turn; the best of each, and its ratio to the first (the option off)."""
    cases = []
    for name, scenario, cfg in variants(args.what, sc, base):
        p = points if name != "on, faults drawn" else points._replace(
            **{k: np.full_like(np.asarray(getattr(points, k)), v) for k, v in FAULTS.items()})
        run(scenario, cfg, p, args.runs, args.runs)
        cases.append((name, scenario, cfg, p, []))
    for _ in range(args.repeats):
        for name, scenario, cfg, p, times in cases:
            times.append(run(scenario, cfg, p, args.runs, args.runs)[1] / args.runs)
    off = min(cases[0][4])
    for name, *_, times in cases:
        print(f"{name:18s} {1e3 * min(times):7.2f} ms/run   {min(times) / off:.3f}x", flush=True)
    return 0


def kernel_times(trace_dir: Path) -> tuple[collections.Counter, collections.Counter]:
    """Microseconds and call counts per kernel from the perfetto trace in ``trace_dir``
    (the runtime's own events — executor, Python frames, loops that contain kernels — left out)."""
    path = sorted(trace_dir.rglob("*.trace.json.gz"))[-1]
    spent, calls = collections.Counter(), collections.Counter()
    for e in json.load(gzip.open(path))["traceEvents"]:
        name = e.get("name", "")
        if e.get("ph") != "X" or name.startswith(("$", "ThunkExecutor", "while", "conditional", "end:")):
            continue
        spent[name] += e.get("dur", 0)
        calls[name] += 1
    return spent, calls


def profile(args, sc, base, points) -> int:
    (_, scenario, cfg), = variants("profile", sc, base)
    params, keys = engine.chunk_inputs(points, args.runs, 0, 0, args.runs, args.runs)
    program = jax.jit(lambda pp, kk: engine.simulate(scenario, cfg, pp, kk)).lower(params, keys).compile()
    jax.block_until_ready(program(params, keys))
    with tempfile.TemporaryDirectory() as tmp:
        with jax.profiler.trace(tmp, create_perfetto_trace=True):
            jax.block_until_ready(program(params, keys))
        spent, calls = kernel_times(Path(tmp))
    kinds, kind_calls = collections.Counter(), collections.Counter()
    for name, us in spent.items():
        kind = re.sub(r"\.\d+$", "", name)
        kinds[kind] += us
        kind_calls[kind] += calls[name]
    print(f"{args.runs} runs x {cfg.n_steps} steps, one call: kernels {sum(spent.values()) / 1e3:.1f} ms in all")
    for kind, us in kinds.most_common(args.top):
        print(f"{us / 1e3:10.2f} ms {kind_calls[kind]:8d} calls  {kind}")
    if args.match:
        hlo = program.as_text()
        for name, us in spent.most_common():
            if args.match in name:
                m = re.search(r"%" + re.escape(name) + r" = (\S+) .*?op_name=\"([^\"]*)\"", hlo)
                where = f"{m.group(1)} {m.group(2)[-100:]}" if m else ""
                print(f"{us / 1e3:10.2f} ms {calls[name]:8d} calls  {name}  {where}")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="what", required=True)
    for what, runs, text in (("due", 400, "planning every step vs only when due"),
                             ("options", 100, "older fusion emitters, float32 planner"),
                             ("dispatch", 400, "per chunk size on the CPU devices"),
                             ("profile", 100, "XLA's kernels of one batch call, summed by kind"),
                             ("faults", 300, "the fault model off, on with rates 0, on with faults drawn"),
                             ("bound", 300, "the posterior Cramér–Rao bound off and on")):
        p = sub.add_parser(what, help=text)
        p.add_argument("--runs", type=int, default=runs)
        p.add_argument("--steps", type=int, default=200)
    sub.choices["options"].add_argument("--rounds", type=int, default=2)
    sub.choices["dispatch"].add_argument("--warmup", type=int, default=200)
    sub.choices["dispatch"].add_argument("--chunks", type=int, nargs="+", default=[200, 400])
    for what in ("faults", "bound"):
        sub.choices[what].add_argument("--repeats", type=int, default=3)
    sub.choices["profile"].add_argument("--top", type=int, default=25, help="kinds of kernel to print")
    sub.choices["profile"].add_argument("--match", default=None,
                                        help="also print every kernel whose name contains this text")
    sub.choices["profile"].add_argument("--agents", type=int, default=None,
                                        help="UAVs in the team (default: the config's five)")
    sub.choices["profile"].add_argument("--filters", nargs="+", default=["icf", "modified_icf", "cif"],
                                        choices=["cif", "icf", "modified_icf", "kcf", "local"])
    args = ap.parse_args(argv)
    if min(args.runs, args.steps, getattr(args, "rounds", 1), getattr(args, "top", 1)) < 1:
        ap.error("--runs, --steps, --rounds and --top must be >= 1")
    if args.what == "options":  # before JAX starts
        os.environ.setdefault("MCJAX_CPU_DEVICES", "1")
    elif args.what == "profile":
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --xla_cpu_enable_xprof_traceme=true".strip()
        os.environ["MCJAX_CPU_DEVICES"] = "1"
    configure()  # JAX's 64-bit mode and CPU devices, as the CLI sets them
    sc, base, values = load_config_file(ROOT / "configs" / "sun2011.toml")
    team = {}
    if getattr(args, "agents", None) is not None:  # a larger team takes the scenario's default layout
        if args.agents < 2:
            ap.error("--agents must be >= 2")
        team = dict(n_agents=args.agents)
        values = {k: v for k, v in values.items() if k not in ("initial_positions", "alive")}
    base = dataclasses.replace(base, filters=tuple(getattr(args, "filters", ("icf", "modified_icf", "cif"))),
                               n_steps=args.steps, warmup_steps=min(base.warmup_steps, args.steps - 1), **team)
    points = engine.stack_points([sc.default_params(base, **values)])
    print(f"Sun et al. 2011 closed loop, {base.n_agents} UAVs, {args.runs} runs x {args.steps} steps, "
          f"{runtime.settings()['cpu_devices']} "
          f"CPU device(s), load average {os.getloadavg()[0]:.2f}, {time.strftime('%Y-%m-%d %H:%M')}")
    return {"due": due, "options": options, "dispatch": dispatch, "profile": profile,
            "faults": timed, "bound": timed}[args.what](args, sc, base, points)


if __name__ == "__main__":
    sys.exit(main())
