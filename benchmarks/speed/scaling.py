"""How the cost of a run scales: with the number of runs, agents, the planning horizon and the
consensus steps — Sun et al. 2011's leader–follower scenario (``configs/sun2011.toml``).

Four curves, each a list of Configs/Params run through the engine as a sweep would
(:func:`mcjax.engine.run_chunks`, 100-run batches), timed after a first call that compiles:

* **runs** — open loop, 5 UAVs: wall time per run for 1, 10, 100, 1,000, 10,000 (and with
  ``--max-runs 100000``, 100,000) runs: it should be flat from one batch (100 runs) up;
* **agents** — 5, 10, 20, 50, 100 UAVs, open loop and closed loop (gradient planner; above 10 UAVs
  the planner's connectivity robustness runs on a maximum spanning tree, ``Config.robustness_paths``
  = "auto"; ``--robustness-paths all_pairs`` measures the O(n³) all-pairs form instead);
* **horizon** — the planner's horizon t_r = 1, 2, 5, 10, 20 (closed loop, τ_r = min(3, t_r),
  ``max_horizon = t_r``: one program per t_r);
* **consensus steps** — L = 1, 2, 5, 10 consensus iterations per step (open loop);

and the peak memory per run of each compiled batch program (XLA's own account of its
arguments, outputs and temporaries, divided by the runs in the batch). Each row also gives the compile time.

How to run (≈ 20–30 min on the 2-core VM at the default sizes)::

    python benchmarks/speed/scaling.py                       # all four curves, PNG + markdown table
    python benchmarks/speed/scaling.py --curves runs agents --steps 50
    python benchmarks/speed/scaling.py --curves agents --steps 50 --filters modified_icf   # the swarm curve, one filter
    MCJAX_CPU_DEVICES=1 python benchmarks/speed/scaling.py   # one core

Writes ``--out`` (default ``results/scaling``): ``scaling.csv``, ``scaling.png`` and the
markdown table it prints.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import resource
import sys
import time
import tomllib
from pathlib import Path

import pandas as pd

from mcjax import configure
from mcjax import engine, runtime
from mcjax.study import load_config_file

configure()  # JAX's 64-bit mode and CPU devices, as the CLI sets them

ROOT = Path(__file__).resolve().parents[2]
CURVES = ("runs", "agents", "horizon", "consensus")


def _memory_per_run(sc, cfg, runs: int) -> float:
    """XLA's account of the compiled batch program's arguments + outputs + temporaries, per
    run (bytes): read from the program the engine compiled (no second compilation)."""
    fn = engine.compiled(sc, cfg)
    progs = engine.cached_programs(fn)
    m = progs[-1][0].result().memory_analysis() if progs else None  # a program future
    if m is None:
        return float("nan")
    return (m.argument_size_in_bytes + m.output_size_in_bytes + m.temp_size_in_bytes) / engine.batch_size_for(runs)


def _time(sc, cfg, values: dict, runs: int) -> dict:
    """Compile (first batch) and run ``runs`` runs of one point; seconds and ms per run."""
    points = engine.stack_points([sc.default_params(cfg, **values)])
    b = engine.batch_size_for(runs)
    t0 = time.perf_counter()
    list(engine.run_chunks(sc, cfg, points, runs, chunk_size=b, chunks=[0]))
    t1 = time.perf_counter()
    for _ in engine.run_chunks(sc, cfg, points, runs, chunk_size=max(b, 1000)):
        pass
    t2 = time.perf_counter()
    return {"compile_s": t1 - t0, "run_s": t2 - t1, "ms_per_run": 1e3 * (t2 - t1) / runs,
            "memory_per_run_kb": _memory_per_run(sc, cfg, runs) / 1e3}


def _rows(curve: str, args, sc, base, values) -> list[dict]:
    warm = min(base.warmup_steps, args.steps // 2)
    open_loop = dataclasses.replace(base, planner="none", n_steps=args.steps, warmup_steps=warm)
    closed = dataclasses.replace(base, n_steps=args.steps, warmup_steps=warm)
    out = []
    if curve == "runs":
        n = 1
        while n <= args.max_runs:
            out.append(("open", n, open_loop, values, n))
            n *= 10
    elif curve == "agents":
        # the config lists the paper's five UAVs; larger teams take the scenario's default
        # layout (the paper's five, the rest on a line behind the leader) and all alive
        values = {k: v for k, v in values.items() if k not in ("initial_positions", "alive")}
        for n in args.agents:
            for loop, cfg in (("open", open_loop), ("closed", closed)):
                if loop == "closed" and n > args.max_closed_agents:
                    continue
                runs = args.closed_runs if loop == "closed" else args.runs  # each exchange side by side
                out += [(loop, n, dataclasses.replace(cfg, n_agents=n, consensus_exchange=e), values, runs)
                        for e in args.exchange]
    elif curve == "horizon":
        for h in args.horizons:
            cfg = dataclasses.replace(closed, max_horizon=h, plan_period=min(3, h))
            out.append(("closed", h, cfg, {**values, "horizon": h, "replan_every": min(3, h)}, args.closed_runs))
    elif curve == "consensus":
        for L in args.consensus:
            out.append(("open", L, dataclasses.replace(open_loop, consensus_steps=L), values, args.runs))
    rows = []
    for loop, x, cfg, vals, runs in out:
        r = {"curve": curve, "loop": loop, "x": x, "runs": runs, **_time(sc, cfg, vals, runs),
             "load": os.getloadavg()[0], "exchange": cfg.consensus_exchange}
        print(f"{curve:10s} {loop:6s} {r['exchange']:6s} x={x:<7d} runs={runs:<7d} compile {r['compile_s']:6.1f} s  "
              f"{r['ms_per_run']:9.3f} ms/run  {r['memory_per_run_kb']:9.1f} kB/run  load {r['load']:.1f}",
              flush=True)
        rows.append(r)
    return rows


def _plot(df: pd.DataFrame, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    labels = {"runs": "runs per sweep", "agents": "UAVs", "horizon": "horizon t_r (steps)",
              "consensus": "consensus steps L"}
    curves = [c for c in CURVES if c in set(df.curve)]
    fig, axes = plt.subplots(1, len(curves), figsize=(4.2 * len(curves), 3.6), squeeze=False)
    for ax, curve in zip(axes[0], curves):
        for (loop, ex), g in df[df.curve == curve].groupby(["loop", "exchange"]):
            ax.plot(g.x, g.ms_per_run, "o-", label=f"{loop} loop" + (f", {ex}" if df.exchange.nunique() > 1 else ""))
        xs = sorted(set(df[df.curve == curve].x))
        if curve in ("runs", "agents"):  # log-log, ticks at the measured points
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xticks(xs, [f"{x:,}" for x in xs])
            ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
        else:  # linear from zero: a flat curve looks flat
            ax.set_xticks(xs)
            ax.set_ylim(0, 1.15 * df[df.curve == curve].ms_per_run.max())
        ax.set_xlabel(labels[curve])
        ax.set_ylabel("ms per run")
        ax.grid(alpha=0.3, which="both")
        ax.legend(loc="upper left" if curve == "horizon" else "best")
    fig.suptitle("Sun et al. 2011 scenario: cost per run (compiled, compile time excluded)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--curves", nargs="+", choices=CURVES, default=list(CURVES))
    ap.add_argument("--steps", type=int, default=100, help="steps per run (paper: 200)")
    ap.add_argument("--runs", type=int, default=500, help="runs per open-loop point")
    ap.add_argument("--closed-runs", type=int, default=100,
                    help="runs per closed-loop point (agents and horizon curves)")
    ap.add_argument("--max-runs", type=int, default=10_000, help="largest run count of the runs curve")
    ap.add_argument("--agents", type=int, nargs="+", default=[5, 10, 20, 50, 100])
    ap.add_argument("--max-closed-agents", type=int, default=100, help="largest team run in closed loop")
    ap.add_argument("--filters", nargs="+", default=["icf", "modified_icf", "cif"],
                    help="filters run (the planner needs modified_icf)")
    ap.add_argument("--robustness-paths", default="auto", choices=["auto", "all_pairs", "spanning_tree"],
                    help="Config.robustness_paths: how the planner computes R_I")
    ap.add_argument("--exchange", nargs="+", default=["auto"], choices=["auto", "dense", "sparse"],
                    help="Config.consensus_exchange of the agents curve (several: each point side by side)")
    ap.add_argument("--set", nargs="*", default=[], metavar="FIELD=VALUE", help="Config fields for every point, "
                    "e.g. plan_iterations=3 plan_learning_rate=1.0 plan_dtype=float32 (a planner budget)")
    ap.add_argument("--horizons", type=int, nargs="+", default=[1, 2, 5, 10, 20])
    ap.add_argument("--consensus", type=int, nargs="+", default=[1, 2, 5, 10])
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "scaling")
    ap.add_argument("--from-csv", type=Path, metavar="CSV",
                    help="measure nothing: redraw the PNG and the table from an earlier run's scaling.csv")
    args = ap.parse_args(argv)
    if args.from_csv is not None:
        _report(pd.read_csv(args.from_csv), args.out)
        return 0
    sc, base, values = load_config_file(ROOT / "configs" / "sun2011.toml")
    changes = dict(a.partition("=")[::2] for a in args.set)
    for key, raw in changes.items():  # TOML values (3, 1.0, true); a bare word is a string (float32)
        if key not in {f.name for f in dataclasses.fields(base)} or not raw:
            ap.error(f"--set {key}={raw}: FIELD=VALUE with FIELD one of the Config's fields")
        try:
            changes[key] = tomllib.loads(f"v = {raw}")["v"]
        except tomllib.TOMLDecodeError:
            pass
    try:
        base = dataclasses.replace(base, filters=tuple(args.filters), robustness_paths=args.robustness_paths, **changes)
    except (TypeError, ValueError) as e:
        ap.error(f"--set: {e}")
    print(f"scaling, {runtime.settings()['cpu_devices']} CPU device(s), {args.steps} steps per run, "
          f"{time.strftime('%Y-%m-%d')}")
    rows = []
    for curve in args.curves:
        rows += _rows(curve, args, sc, base, values)
    _report(pd.DataFrame(rows), args.out)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # kB on Linux
    print(f"peak resident memory of this process: {peak:.2f} GiB")
    return 0


def _report(df: pd.DataFrame, out: Path) -> None:
    """Write ``scaling.csv`` and ``scaling.png`` into ``out`` and print the markdown table."""
    out.mkdir(parents=True, exist_ok=True)
    df = df.assign(exchange=df.get("exchange", "auto"))  # a csv of before the option: auto
    df.to_csv(out / "scaling.csv", index=False)
    _plot(df, out / "scaling.png")
    print("\n| curve | loop | exchange | x | runs | compile s | ms per run | kB per run | load |")
    print("|---|---|---|---:|---:|---:|---:|---:|---:|")
    for r in df.itertuples():
        print(f"| {r.curve} | {r.loop} | {r.exchange} | {r.x} | {r.runs} | {r.compile_s:.1f} | {r.ms_per_run:.3f} | "
              f"{r.memory_per_run_kb:.1f} | {r.load:.1f} |")
    print(f"\nwrote {out / 'scaling.csv'} and {out / 'scaling.png'}")


if __name__ == "__main__":
    sys.exit(main())
