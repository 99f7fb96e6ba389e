"""Does tuning the planner's weights by gradient beat a grid search of the same compute?

Sun et al. 2011 closed loop at a 70 km comm radius (``sweeps/tune_sun2011.toml``): tune
(α_I, α_L, α_C) from the config's values (1000, 1e-4, 1) with ``mcjax tune``'s machinery on
``--train-seeds`` training seeds, then compare on ``--heldout-seeds`` held-out seeds (exact
simulation, modified ICF): the initial weights, the tuned weights, and the best point of a
log-spaced grid over the same bounds that was given the same compute.

Compute accounting, in simulated runs: an exact run of the closed loop costs 1; a gradient
pass over N runs costs N × (wall time of the pass / wall time of N exact runs), both measured
in this process on the same machine (compilation excluded). The grid gets as many points ×
training seeds as the tune used (rounded down to a full grid), runs on the same training
seeds, and its best point is the one with the fewest divergences (then the lowest mean RMSE).

Figures in OUT: ``trace.png`` (the tune's loss and weights per step) and
``path_heatmap.png`` (the tune's path through (α_I, α_L) over the grid's divergence rate on
the training seeds, at the grid's α_C nearest the tuned one). ``summary.md`` holds the table.

    python benchmarks/papers/tune_sun2011.py                                   # 128 training, 1,000 held-out seeds
    python benchmarks/papers/tune_sun2011.py --train-seeds 32 --heldout-seeds 200 --steps 4   # a quick look
    python benchmarks/papers/tune_sun2011.py --train-seeds 64 --n-steps 100 --steps 10 --heldout-seeds 500 \
        --gradient-window 10 --out results/tune_sun2011_w10          # the run in docs/tune.md
"""

from __future__ import annotations

import argparse
import json
import math
import time
from datetime import date
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[2]


def _stats(df: pd.DataFrame) -> dict:
    from mcjax.analysis.statistics import mean_ci, wilson_interval

    n = len(df)
    k = int(df["diverged"].astype(bool).sum())
    w = wilson_interval(k, n)
    m = mean_ci(df["rmse"].to_numpy())
    ok = df[~df["diverged"].astype(bool)]
    m_ok = mean_ci(ok["rmse"].to_numpy()) if len(ok) > 1 else None
    out = {"runs": n, "divergences": k, "rate": k / n, "rate_lo": w.low, "rate_hi": w.high,
           "rmse": m.mean, "rmse_lo": m.low, "rmse_hi": m.high}
    if m_ok is not None:
        out.update(rmse_ok=m_ok.mean, rmse_ok_lo=m_ok.low, rmse_ok_hi=m_ok.high)
    return out


def path_heatmap(g: pd.DataFrame, trace: pd.DataFrame, best, final, n_seeds: int, path: Path) -> Path:
    """The tune's path through (α_I, α_L) over two heat maps of the grid (training seeds, exact
    simulation) at the grid's α_C nearest the tuned one: divergence rate and mean RMSE."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cs = sorted(g["alpha_C"].unique())
    c_near = min(cs, key=lambda c: abs(math.log(c) - math.log(final[2])))

    def edges(v):
        lv = np.log10(v)
        d = np.diff(lv).mean() if len(lv) > 1 else 1.0
        return 10 ** np.concatenate([lv - d / 2, [lv[-1] + d / 2]])

    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    for ax, col, label, cmap in [(axes[0], "div", "divergence rate", "viridis_r"),
                                 (axes[1], "rmse", "mean RMSE, m", "viridis")]:
        sl = g[g["alpha_C"] == c_near].pivot(index="alpha_L", columns="alpha_I", values=col)
        I, L = np.array(sl.columns), np.array(sl.index)
        mesh = ax.pcolormesh(edges(I), edges(L), sl.to_numpy(), cmap=cmap, shading="flat")
        fig.colorbar(mesh, ax=ax, label=f"grid {label} ({n_seeds} training seeds, exact)")
        ax.plot(trace["alpha_I"], trace["alpha_L"], "w.-", lw=1.5, label="tune path")
        ax.plot(trace["alpha_I"].iloc[0], trace["alpha_L"].iloc[0], "ws", label="initial")
        ax.plot(trace["alpha_I"].iloc[-1], trace["alpha_L"].iloc[-1], "r*", ms=12, label="tuned")
        ax.plot(best["alpha_I"], best["alpha_L"], "o", mfc="none", mec="orange", ms=12, label="grid best")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("alpha_I")
        ax.set_ylabel("alpha_L [1/m]")
        ax.set_title(f"comm radius 70 km; grid slice alpha_C = {c_near:.3g} (tuned {final[2]:.3g})", fontsize=9)
        ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _cached_sweep(spec, path: Path):
    """The sweep's rows, read from ``path`` if an earlier (killed) run of this benchmark wrote
    them, else run and written there; and the wall seconds it took."""
    from mcjax.study import run_sweep

    t0 = time.perf_counter()
    if path.is_file():
        return pd.read_parquet(path), time.perf_counter() - t0
    df = run_sweep(spec)
    df.to_parquet(path)
    return df, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spec", default=str(ROOT / "sweeps" / "tune_sun2011.toml"))
    ap.add_argument("--train-seeds", type=int, default=128)
    ap.add_argument("--heldout-seeds", type=int, default=1000)
    ap.add_argument("--steps", type=int, default=None, help="optimisation steps (default: the spec's)")
    ap.add_argument("--n-steps", type=int, default=None, help="simulation steps per run (default: the config's)")
    ap.add_argument("--gradient-window", type=int, default=None,
                    help="truncate the gradient to windows of this many steps (default: the spec's)")
    ap.add_argument("--out", default="results/tune_sun2011_benchmark")
    args = ap.parse_args()

    import jax

    from mcjax import engine, tune
    from mcjax.base.validation import read_toml
    from mcjax.study import build_spec

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    raw = read_toml(Path(args.spec), "tune spec")
    raw["tune"]["train_seeds"] = args.train_seeds
    raw["tune"]["heldout_seeds"] = args.heldout_seeds
    if args.steps is not None:
        raw["tune"]["steps"] = args.steps
    if args.n_steps is not None:
        raw.setdefault("config", {})["n_steps"] = args.n_steps
        raw["tune"]["checkpoint_every"] = min(raw["tune"].get("checkpoint_every", 10), args.n_steps)
    if args.gradient_window is not None:
        raw["tune"]["gradient_window"] = args.gradient_window
    spec = tune.build_tune_spec(raw, Path(args.spec).parent)
    import os

    log = {"date": str(date.today()), "load_average_start": list(os.getloadavg()),
           "command": "python benchmarks/papers/tune_sun2011.py " + " ".join(
        f"--{k.replace('_', '-')} {v}" for k, v in vars(args).items() if v is not None and k != "spec")}

    # ---- tune (resumes from OUT/tune when it was interrupted)
    tdir = out / "tune"
    resume = (tdir / tune.IDENTITY_FILE).is_file()
    tune.prepare_tune_output(spec, tdir, resume=resume, force=False, spec_file=args.spec)
    t0 = time.perf_counter()
    evaluator = tune.Evaluator(spec)

    def show(row):
        print(f"step {int(row['step']):3d}  loss {row['loss']:.5f}  " + "  ".join(
            f"{n} {row[n]:.4g}" for n in spec.names) + f"  |g| {row['grad_norm']:.3g}  {row['wall_s']:.1f} s",
              flush=True)

    trace = tune.optimise(spec, tdir, evaluator=evaluator, progress=show)
    tune_wall = time.perf_counter() - t0
    tune.plot_trace(spec, trace, out / "trace.png")
    final = tune.final_values(spec, trace)

    # ---- cost of one exact run vs one gradient pass (compilation excluded)
    s = spec.study
    keys = tune.train_keys(spec)
    params = jax.tree.map(lambda a: np.broadcast_to(np.asarray(a), (spec.train_seeds,) + np.shape(a)),
                          s.base_params)
    fn = engine.compiled(s.scenario, s.config)
    jax.block_until_ready(fn(params, keys))
    t1 = time.perf_counter()
    jax.block_until_ready(fn(params, keys))
    exact_wall = time.perf_counter() - t1  # one device; the gradient passes use every device
    n_dev = len(evaluator.devs)
    walls = trace["wall_s"].to_numpy()[1:] if len(trace) > 2 else trace["wall_s"].to_numpy()
    grad_wall = float(np.median(walls))
    # runs per gradient pass, counted as exact runs of the same wall time on the same devices
    pass_cost = spec.train_seeds * grad_wall * n_dev / exact_wall
    n_passes = len(trace)
    tune_cost = n_passes * pass_cost
    print(f"exact batch of {spec.train_seeds} runs: {exact_wall:.1f} s on 1 device; gradient pass: "
          f"{grad_wall:.1f} s on {n_dev} device(s) = {pass_cost:.0f} runs; tune: {n_passes} passes = "
          f"{tune_cost:.0f} runs", flush=True)

    # ---- grid of the same compute on the training seeds
    points = max(1, int(tune_cost // spec.train_seeds))
    k_c = 3 if points >= 12 else 1
    k = max(2, int(math.floor(math.sqrt(points / k_c))))
    bnd = {b.name: b for b in spec.bounds}

    def axis(name, m):
        b = bnd[name]
        inner = np.geomspace(b.low, b.high, m + 2)[1:-1]  # strictly inside the bounds
        return [float(v) for v in inner]

    grid = {"alpha_I": axis("alpha_I", k), "alpha_L": axis("alpha_L", k),
            "alpha_C": axis("alpha_C", k_c) if k_c > 1 else [bnd["alpha_C"].initial]}
    shared = {kk: v for kk, v in raw.items() if kk != "tune"}
    gspec = build_spec({**shared, "params": {kk: v for kk, v in shared.get("params", {}).items() if kk not in grid},
                        "grid": grid, "seeds": spec.train_seeds, "base_seed": spec.train_base_seed},
                       Path(args.spec).parent)
    gdf, grid_wall = _cached_sweep(gspec, out / "grid_runs.parquet")
    g = gdf.groupby(["alpha_I", "alpha_L", "alpha_C"]).agg(div=("diverged", "mean"), rmse=("rmse", "mean")).reset_index()
    best = g.sort_values(["div", "rmse"]).iloc[0]
    print(f"grid: {len(g)} points x {spec.train_seeds} seeds = {len(g) * spec.train_seeds} runs in {grid_wall:.0f} s; "
          f"best {best.to_dict()}", flush=True)

    # ---- held-out: initial, tuned, grid best (exact simulation, same seeds)
    cand = {"initial": spec.initial(), "tuned": final,
            "grid best": np.array([best["alpha_I"], best["alpha_L"], best["alpha_C"]])}
    zipped = {n: [float(c[i]) for c in cand.values()] for i, n in enumerate(spec.names)}
    hspec = build_spec({**shared, "params": {kk: v for kk, v in shared.get("params", {}).items() if kk not in zipped},
                        "zip": zipped, "seeds": spec.heldout_seeds, "base_seed": spec.heldout_base_seed},
                       Path(args.spec).parent)
    hdf, held_wall = _cached_sweep(hspec, out / "heldout_runs.parquet")
    rows = []
    for pid, name in enumerate(cand):
        st = _stats(hdf[hdf["point_id"] == pid])
        rows.append({"weights": name, **{n: float(cand[name][i]) for i, n in enumerate(spec.names)}, **st})

    # ---- figure: the path over the grid's heat maps (divergence rate, mean RMSE)
    path_heatmap(g, trace, best, final, spec.train_seeds, out / "path_heatmap.png")

    budget = {"exact_runs_per_grad_pass": pass_cost, "grad_passes": n_passes, "tune_cost_runs": tune_cost,
              "grid_points": len(g), "grid_runs": len(g) * spec.train_seeds, "tune_wall_s": tune_wall,
              "grid_wall_s": grid_wall, "heldout_wall_s": held_wall, "exact_batch_wall_s": exact_wall,
              "grad_pass_wall_s": grad_wall, "devices": n_dev}
    log["load_average_end"] = list(os.getloadavg())
    summary = {**log, "budget": budget, "results": rows}
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=float))
    lines = [f"# tune_sun2011 ({log['date']})", "", f"`{log['command']}`", "",
             f"Load average (1, 5, 15 min) at start {log['load_average_start']}, at end {log['load_average_end']}", "",
             "| weights | alpha_I | alpha_L | alpha_C | held-out runs | divergence rate [95 % Wilson] | "
             "mean RMSE, m [95 % t] | mean RMSE of non-divergent runs, m |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ok = f"{r.get('rmse_ok', float('nan')):.2f} [{r.get('rmse_ok_lo', float('nan')):.2f}, " \
             f"{r.get('rmse_ok_hi', float('nan')):.2f}]"
        lines.append(f"| {r['weights']} | {r['alpha_I']:.4g} | {r['alpha_L']:.4g} | {r['alpha_C']:.4g} | {r['runs']} | "
                     f"{r['rate']:.3f} [{r['rate_lo']:.3f}, {r['rate_hi']:.3f}] | {r['rmse']:.1f} "
                     f"[{r['rmse_lo']:.1f}, {r['rmse_hi']:.1f}] | {ok} |")
    lines += ["", "Compute (in exact closed-loop runs): " + ", ".join(f"{k} = {v:.4g}" if isinstance(v, float)
                                                                     else f"{k} = {v}" for k, v in budget.items())]
    (out / "summary.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
