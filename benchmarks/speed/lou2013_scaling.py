"""Flocking (Lou, Cui & Li 2013's scenario) from 20 to 100 nodes: what a run costs as the flock
grows, from a lattice start.

What is run. The scenario ``flocking`` with ``configs/lou2013.toml``, for N = 20, 50, 100 nodes
(``--sizes``; ``n_sensing = N // 2``), every run starting from ``start_layout = "lattice"``
(ours, not the paper's: the nodes on a square lattice of 1.75 m, about the paper's density,
each moved by U[−0.1, 0.1]² m; one draw per run, ``start_attempts = 1``). A uniform draw of 50
or more nodes at the paper's density almost never avoids a pair just below R, so it is
rejected; the lattice never is (``flocking.check_params``), and the in-program start test
still flags any draw that breaks the rule (``start_failed``, checked to be 0). Per N: one
compiled batch of ``--runs`` (20) runs × ``--steps`` (30) steps — the first seconds, where the
flock contracts — and one of ``--full-runs`` (20, 20, 4) runs × ``--full-steps`` (300) steps,
the paper's 30 s; each with the compilation timed apart (ahead-of-time ``lower().compile()``)
and excluded. The paper's own set-up (20 nodes, its figures) is
``benchmarks/papers/lou2013_figures.py``.

How to run::

    python benchmarks/speed/lou2013_scaling.py              # ~13 min on 2 shared cores
    python benchmarks/speed/lou2013_scaling.py --runs 4 --full-steps 0   # the short batches alone
    python benchmarks/speed/lou2013_scaling.py [--runs 20] [--steps 30] [--full-steps 300]
                                                [--full-runs 20 20 4] [--sizes 20 50 100]
                                                [--out DIR] [--no-figures]

What it prints. Per N and batch: compilation and run time, runs/s, the cost per run-step and per
run-substep (the run time over runs × the sub-steps the batch executed: per step, those of its
slowest run), the sub-steps per step, the start failures, broken links, links that reached R,
runs ever disconnected, blow-ups and steps at the sub-step cap; the cost of one RK4 sub-step
alone (``flocking.rk4_step`` vmapped over the batch); and the exponents of log-log fits of every
cost vs N. Exit status 1 if a run started from a failed lattice draw.

Figure (``--out``, default ``results/lou2013_scaling/``; ``--no-figures``): the cost vs N,
log-log with the fits (``scaling.png``).
"""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path

import jax
import numpy as np

from mcjax import configure
from mcjax import engine
from mcjax.scenarios.lou2013 import Params as FlockingParams
from mcjax.study import build_spec

configure()  # JAX's 64-bit mode and CPU devices, as the CLI sets them

ROOT = Path(__file__).resolve().parents[2]
#: λ2 at or below this counts as disconnected (mcjax.tracking.metrics.graph_summary's rule).
DISCONNECTED = 1e-9


#: The scaling runs' start: ``start_layout = "lattice"`` with the scenario's default spacing and
#: jitter (valid for any N, checked by ``flocking.check_params``); one draw per run
#: (``start_attempts = 1``: the lattice needs no redraws; the in-program test still flags it).
SCALING_CONFIG = {"start_layout": "lattice", "start_attempts": 1}
LATTICE_NOTE = (f"{FlockingParams.TABLE['lattice_spacing'].default} m spacing (about the paper's density), each node "
                f"moved by U[−j, j]² m, j = {FlockingParams.TABLE['lattice_jitter'].default}")
COST_LABELS = {"ms_per_run_step": "ms per run-step", "us_per_run_substep": "µs per run-substep",
               "us_per_substep": "µs per run and RK4 sub-step (rk4_step alone)"}


def _scaling_setup(config: Path, n: int, steps: int):
    """``(scenario, Config, Params, "columns x rows")`` of ``n`` nodes on the lattice, validated like a
    sweep spec."""
    from mcjax.scenarios.lou2013 import lattice_sites

    spec = build_spec({"base": str(config.resolve()), "params": {"n_sensing": n // 2},
                       "config": {"n_agents": n, "n_steps": steps, **SCALING_CONFIG}}, config.parent, seeds=1)
    sc, cfg, p = spec.scenario, spec.config, spec.base_params
    sites = lattice_sites(n)
    return sc, cfg, p, f"{int(sites[:, 0].max() + 0.5)} x {int(sites[:, 1].max() + 0.5)}"


def batch_cost(config: Path, n: int, runs: int, steps: int, base_seed: int) -> dict:
    """One compiled batch of ``runs`` runs × ``steps`` steps of ``n`` nodes: compilation (ahead
    of time, ``lower().compile()``) and run timed apart, with what the runs did."""
    scenario, cfg, p, lattice = _scaling_setup(config, n, steps)
    fn = engine.compiled(scenario, cfg, records=True)
    params, keys = engine.chunk_inputs(engine.stack_points([p]), runs, base_seed, 0, runs, runs)
    t0 = time.perf_counter()
    exe = fn.lower(params, keys).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    rec = jax.block_until_ready(exe(params, keys))
    run_s = time.perf_counter() - t0
    out = jax.jit(jax.vmap(lambda r: scenario.reduce(cfg, r, p)))(rec)
    out = {k: np.asarray(v) for k, v in out.items()}
    sub = np.asarray(rec.substeps)                      # (runs, T)
    executed = float(np.sum(sub.max(axis=0)))           # the batch's sub-steps: its slowest run's, per step
    print(f"  N = {n}: compile {compile_s:.1f} s, {runs} runs x {steps} steps in {run_s:.2f} s", flush=True)
    return dict(n=n, lattice=lattice, runs=runs, steps=steps, compile_s=compile_s, run_s=run_s,
                runs_per_s=runs / run_s, ms_per_run_step=run_s / (runs * steps) * 1e3,
                us_per_run_substep=run_s / (runs * executed) * 1e6, substeps_mean=float(sub.mean()),
                substeps_batch=executed / steps, start_failed=int(out["start_failed"].sum()),
                removed=int(np.sum(out["edges_removed"] > 0)), reached=int(out["link_reached_R"].sum()),
                disconnected=int(np.sum(out["lambda2_min"] <= DISCONNECTED)),
                capped=int(out["substeps_capped"].sum()),
                blown=int(np.sum(~np.all(np.isfinite(np.asarray(rec.energy)), axis=1))))


def substep_cost(config: Path, n: int, runs: int, base_seed: int, substeps: int = 10, repeats: int = 3) -> float:
    """Seconds per run and RK4 sub-step of ``mcjax.scenarios.lou2013.dynamics.rk4_step`` alone, vmapped over
    ``runs`` initial states of ``n`` nodes (``flocking.init``) with a fixed ``substeps`` count
    (the best of ``repeats`` calls after compiling): the integrator's cost per unit of work,
    free of how stiff the flock is."""
    from mcjax.scenarios.lou2013 import dynamics as fl
    from mcjax.scenarios.lou2013 import sensing_mask

    scenario, cfg, p, _ = _scaling_setup(config, n, 30)
    keys = jax.vmap(lambda s: engine.init_key(engine.run_key(base_seed, s)))(
        np.arange(runs, dtype=np.uint32))
    states = jax.jit(jax.vmap(lambda k: scenario.init(cfg, p, k)))(keys)
    h = sensing_mask(cfg, p, np.float64)
    g = fl.Gains(float(p.c1), float(p.c2), float(p.k), float(p.R))
    zero = np.zeros((n, 2))
    f = jax.jit(jax.vmap(lambda s, a: fl.rk4_step(s, a, h, lambda tau: (zero, zero), g, float(p.dt), substeps)))
    jax.block_until_ready(f(states.flock, states.adj))
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(f(states.flock, states.adj))
        best = min(best, time.perf_counter() - t0)
    return best / (runs * substeps)


def scaling(config: Path, sizes: list[int], runs: int, steps: int, full_steps: int, full_runs: list[int],
            base_seed: int):
    """Per N: a batch of ``runs`` × ``steps`` with the RK4 sub-step alone, and a batch of
    ``full_runs[i]`` × ``full_steps`` (the paper's 300 steps; skipped if 0 or equal to ``steps``)."""
    rows = [dict(batch_cost(config, n, runs, steps, base_seed), us_per_substep=substep_cost(config, n, runs, base_seed)
                 * 1e6) for n in sizes]
    full = ([batch_cost(config, n, r, full_steps, base_seed) for n, r in zip(sizes, full_runs)]
            if full_steps and full_steps != steps else [])
    return rows, full


def _fit(rows: list[dict], key: str) -> float:
    """Least-squares slope of log(cost) vs log(N)."""
    if len(rows) < 2:
        return math.nan
    return float(np.polyfit(np.log([r["n"] for r in rows]), np.log([r[key] for r in rows]), 1)[0])


def scaling_table(rows: list[dict], full: list[dict]) -> tuple[str, dict]:
    fits = {}
    for label, group in ((f"{rows[0]['steps']} steps", rows), (f"{full[0]['steps']} steps" if full else "", full)):
        for key in ("ms_per_run_step", "us_per_run_substep", "us_per_substep"):
            if group and key in group[0]:
                fits[(label, key)] = _fit(group, key)
    lines = ["| N | lattice (columns x rows) | runs x steps | compile, s | run, s | runs/s | ms per run-step | "
             "µs per run-substep | sub-steps per step (mean over runs / slowest run) | µs per run and RK4 sub-step "
             "(rk4_step alone) | start failed | runs that broke a link | link reached R | runs ever disconnected | "
             "flock went non-finite | steps at the sub-step cap |",
             "|" + "---|" * 16]
    for r in rows + full:
        sub_cost = f"{r['us_per_substep']:.1f}" if "us_per_substep" in r else "–"
        lines.append(f"| {r['n']} | {r['lattice']} | {r['runs']} x {r['steps']} | {r['compile_s']:.1f} | "
                     f"{r['run_s']:.2f} | {r['runs_per_s']:.3g} | {r['ms_per_run_step']:.3g} | "
                     f"{r['us_per_run_substep']:.3g} | {r['substeps_mean']:.1f} / {r['substeps_batch']:.1f} | "
                     f"{sub_cost} | {r['start_failed']}/{r['runs']} | {r['removed']}/{r['runs']} | "
                     f"{r['reached']}/{r['runs']} | {r['disconnected']}/{r['runs']} | {r['blown']}/{r['runs']} | "
                     f"{r['capped']} |")
    return "\n".join(lines), fits



def scaling_figure(rows: list[dict], full: list[dict], fits: dict, out_dir: Path) -> Path:
    """Log-log cost vs N with the fitted exponents: per run-step and per run-substep for each
    batch length, and the RK4 sub-step alone."""
    import matplotlib
    import matplotlib.ticker
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.2, 4.8))
    curves = [(rows, "ms_per_run_step", "tab:blue", "-"), (rows, "us_per_run_substep", "tab:green", "-"),
              (rows, "us_per_substep", "tab:orange", "-")]
    if full:
        curves[2:2] = [(full, "ms_per_run_step", "tab:blue", "--"), (full, "us_per_run_substep", "tab:green", "--")]
    for group, key, color, ls in curves:
        label = f"{group[0]['steps']} steps"
        n = np.array([r["n"] for r in group], float)
        y = np.array([r[key] for r in group]) * (1.0 if key.startswith("ms") else 1e-3)
        what = COST_LABELS[key].replace("µs", "ms")
        extra = "" if key == "us_per_substep" else f", {label}"
        ax.loglog(n, y, ls, marker="o", color=color,
                  label=f"{what}{extra} (runs: {'/'.join(str(r['runs']) for r in group)}): "
                        f"N^{fits[(label, key)]:.2f}")
    n = np.array([r["n"] for r in rows], float)
    ax.set(xlabel="nodes N", ylabel="wall time, ms",
           title="Flocking cost vs N (lattice start; compilation excluded)")
    ax.set_xticks(n, [str(int(v)) for v in n])
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.legend(fontsize=7)
    path = out_dir / "scaling.png"
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=20, help="runs per N of the short batch")
    ap.add_argument("--steps", type=int, default=30,
                    help="steps per run at every N (the first seconds, where the flock contracts)")
    ap.add_argument("--full-steps", type=int, default=300,
                    help="steps of one more batch at every N, as in the paper's runs (0: skip)")
    ap.add_argument("--full-runs", type=int, nargs="+", default=[20, 20, 4],
                    help="runs of the --full-steps batch per N (one value: every N)")
    ap.add_argument("--sizes", type=int, nargs="+", default=[20, 50, 100], help="numbers of nodes N")
    ap.add_argument("--config", type=Path, default=ROOT / "configs" / "lou2013.toml")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "lou2013_scaling")
    ap.add_argument("--base-seed", type=int, default=0)
    ap.add_argument("--no-figures", action="store_true")
    args = ap.parse_args(argv)
    if args.full_steps and len(args.full_runs) not in (1, len(args.sizes)):
        ap.error(f"--full-runs takes one value or one per --sizes; got {args.full_runs}")
    wall0 = time.perf_counter()
    full_runs = args.full_runs * (len(args.sizes) if len(args.full_runs) == 1 else 1)
    print(f"\n### Speed and scaling (start_layout = lattice: the nodes on a jittered square lattice of "
          f"{LATTICE_NOTE}; n_sensing = N // 2; {args.runs} runs x {args.steps} steps per N in one compiled batch"
          + (f", and {args.full_steps} steps with "
             f"{', '.join(f'{r} runs at N = {n}' for n, r in zip(args.sizes, full_runs))}" if args.full_steps else "")
          + ")\n")
    rows, full = scaling(args.config, args.sizes, args.runs, args.steps, args.full_steps, full_runs, args.base_seed)
    table, fits = scaling_table(rows, full)
    print()
    print(table)
    print("\nfitted exponent of the cost vs N (log-log, least squares over the sizes):")
    for (label, key), value in fits.items():
        print(f"  {label}, {COST_LABELS[key]}: {value:.2f}")
    print(f"\nA batch executes, per step, the sub-steps of its slowest run (the sub-step column's second "
          f"figure); µs per run-substep divides the run time by runs x those sub-steps (the filters, the graph and "
          f"λ2 included). The RK4 sub-step alone is flocking.rk4_step vmapped over {args.runs} initial "
          f"states, 10 sub-steps, best of 3. Compilation is timed apart and not in any cost. Load average now "
          f"{', '.join(f'{x:.1f}' for x in os.getloadavg())} on {os.cpu_count()} CPUs.")
    starts = sum(r["start_failed"] for r in rows + full)
    ok = starts == 0
    print(("holds   " if ok else "FAILS   ") + f"every scaling run started from a valid lattice draw "
          f"(start_failed: {starts})")
    if not args.no_figures:
        args.out.mkdir(parents=True, exist_ok=True)
        print(f"\nfigure: {scaling_figure(rows, full, fits, args.out)}")
    print(f"\ntotal wall time {time.perf_counter() - wall0:.0f} s")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
