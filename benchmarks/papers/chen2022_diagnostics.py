"""Chen & Hao 2022: what a claims file cannot say — the figures (Figs. 4–5), the flight, the locks and the
holds, and the planners compared on the same states. Table 1 and the paper's orderings are checked by
`mcjax check benchmarks/claims/chen2022.toml`.

What is run. The scenario ``urban_bearing`` at the three weight vectors of a Table 1 sweep spec (its
[zip] axis: full score (0.2, 0.5, -0.3), without the NLOS term (0.2, 0.5, 0), FIM only (0.2, 0, 0)),
N seeds each (default 1,000), the same seed indices at every weight vector, keeping every step's
records, for the default set-up (``sweeps/chen2022_table1.toml``) and the first one
(``sweeps/chen2022_wide_prior_table1.toml``; ``--sweep-old ''`` skips it); ``--max-hold N`` adds the
default set-up with ``params.max_hold_steps = N``.

    python benchmarks/papers/chen2022_diagnostics.py                 # 1,000 runs per weight vector
    python benchmarks/papers/chen2022_diagnostics.py --runs 100 --sweep-old ''


Printed per set-up: the flight table — mean steps in the shadow, with a reflected (NLOS)
measurement and holding the previous command; the locked runs (Wilson interval: a run is locked
when, for at least 20 steps in a row, the measurement was a clean line-of-sight bearing while the
IMM's NLOS probability exceeded 0.5) with the mean final error of locked and other runs; the longest
hold and the runs the paper's hold traps (>= 60 held steps in a row); the seeds locked under every
weight vector.

Figures (``--out``, default ``results/chen2022_diagnostics/<set-up>/``): ``paths.png`` — seed 0's path
per weight vector over the buildings, with the true shadow and reflection regions at 200 m;
``error_over_time.png`` — the mean error per step (eq. 23) per weight vector with its 95 % band and
the median, log scale.

The planners on the same states: ``benchmarks/papers/chen2022_planners.py``; in closed loop:
``mcjax check benchmarks/claims/chen2022_planners.toml``.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mcjax import configure
from mcjax import engine
from mcjax.analysis.statistics import t_critical, wilson_interval
from mcjax.scenarios import chen2022 as ub
from mcjax.scenarios.chen2022 import environment as env
from mcjax.study import load_spec

configure()  # JAX's 64-bit mode and CPU devices, as the CLI sets them

ROOT = Path(__file__).resolve().parents[2]
#: Chen & Hao 2022 Table 1: final error (m), mean over 50 runs of eq. 23 at the last step.
PAPER = {
    (0.2, 0.5, -0.3): ("track 1", "full score", 1.2),
    (0.2, 0.5, 0.0): ("track 2", "without the NLOS term", 98.4),
    (0.2, 0.0, 0.0): ("track 3", "FIM only", 6.5),
}
ALTITUDE = 200.0      # m: altitude of the drawn shadow / reflection regions (the start altitude)
ZOOM = 800.0          # m: half-width of the zoomed panel of paths.png
COLORS = ("tab:blue", "tab:red", "tab:green")


def fmt_wilson(k: int, n: int) -> str:
    lo, hi = wilson_interval(k, n)
    return f"{k} ({100 * k / n:.1f} % [{100 * lo:.1f}, {100 * hi:.1f}])"


# --------------------------------------------------------------------------- the Table 1 sweep


def tracks(spec) -> list[dict]:
    """One entry per sweep point: its weights, the paper's name and number (if any)."""
    out = []
    for _, row in spec.points.iterrows():
        w = (float(row["c1"]), float(row["c2"]), float(row["c3"]))
        key = next((k for k in PAPER if np.allclose(k, w)), None)
        name, what, paper = PAPER[key] if key else (f"point {int(row['point_id'])}", "", float("nan"))
        out.append(dict(point=int(row["point_id"]), weights=w, key=key, name=name, what=what, paper=paper))
    return out


def run_sweep(spec, runs: int, base_seed: int):
    """Records (run axis first, point-major: run = point * runs + seed) of every point and
    seed, the per-run summaries (``reduce``) and the wall time including compilation."""
    sc, cfg = spec.scenario, spec.config
    pp = spec.params
    n = spec.n_points * runs
    t0 = time.perf_counter()
    chunks = [o for *_, o in engine.run_chunks(sc, cfg, pp, runs, base_seed=base_seed, chunk_size=n, records=True)]
    records = jax.tree.map(lambda *xs: np.concatenate(xs), *chunks)
    per_run = jax.tree.map(lambda a: np.asarray(a)[np.arange(n) // runs], pp)
    summaries = jax.jit(jax.vmap(lambda r, p: sc.reduce(cfg, r, p)))(records, per_run)
    summaries = {k: np.asarray(v) for k, v in summaries.items()}
    return records, summaries, time.perf_counter() - t0


# --------------------------------------------------------------------------- figures


def regions(b: env.Buildings, emitter, xs, ys, z: float):
    """True shadow and reflection (NLOS, the paper's region: ``check_legs=False``) masks on
    the grid ``xs`` x ``ys`` at altitude ``z``: (len(ys), len(xs)) each."""
    X, Y = np.meshgrid(xs, ys)
    pts = jnp.asarray(np.stack([X, Y, np.full_like(X, z)], -1))
    e = jnp.asarray(emitter)
    shadow = np.asarray(env.in_shadow(b, e, pts))
    nlos = np.asarray(jnp.any(env.reflections(b, e, pts, check_legs=False).valid, axis=(-2, -1)))
    return shadow, nlos


def figures(spec, trk, records, runs: int, imm: int, ekf: int | None, out_dir: Path) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch, Rectangle

    p = spec.base_params
    boxes = np.asarray(p.buildings)
    b = ub.buildings_of(p)
    emitter = np.asarray(p.emitter)
    start = np.asarray(p.uav0)
    paths = []

    # (a) paths over the buildings and the true shadow / reflection regions at ALTITUDE
    tracks_xy = [np.asarray(records.uav[k * runs])[:, :2] for k in range(len(trk))]   # seed 0 of each point
    allxy = np.concatenate([*tracks_xy, start[None, :2], emitter[None, :2]])
    lo = np.minimum(allxy.min(0), emitter[:2] - 2000.0) - 300.0
    hi = np.maximum(allxy.max(0), emitter[:2] + 2000.0) + 300.0
    windows = [(lo, hi, "whole flight (and at least 4 km x 4 km around the emitter)"),
               (emitter[:2] - ZOOM, emitter[:2] + ZOOM, f"zoom: {2 * ZOOM / 1e3:g} km x {2 * ZOOM / 1e3:g} km around "
                                                         "the emitter")]
    fig, axes = plt.subplots(1, 2, figsize=(15, 7.2), gridspec_kw=dict(width_ratios=[1.15, 1]))
    for ax, (wlo, whi, title) in zip(axes, windows):
        n = 700
        xs, ys = np.linspace(wlo[0], whi[0], n), np.linspace(wlo[1], whi[1], n)
        shadow, nlos = regions(b, emitter, xs, ys, ALTITUDE)
        ext = [xs[0] / 1e3, xs[-1] / 1e3, ys[0] / 1e3, ys[-1] / 1e3]
        ax.contourf(xs / 1e3, ys / 1e3, shadow.astype(float), levels=[0.5, 1.5], colors=["0.35"], alpha=0.35)
        ax.contourf(xs / 1e3, ys / 1e3, nlos.astype(float), levels=[0.5, 1.5], colors=["orange"], alpha=0.35)
        for j, (x0, y0, x1, y1, h) in enumerate(boxes):
            ax.add_patch(Rectangle((x0 / 1e3, y0 / 1e3), (x1 - x0) / 1e3, (y1 - y0) / 1e3, facecolor="k",
                                   edgecolor="k", zorder=4))
            if title.startswith("zoom"):
                centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
                away = (centre - emitter[:2]) / max(np.hypot(*(centre - emitter[:2])), 1e-9)
                ax.annotate(f"building {j + 1}: {h:.0f} m tall", centre / 1e3, xytext=tuple(away * [70, 45]),
                            textcoords="offset points", ha="center", va="center", fontsize=9, zorder=8,
                            arrowprops=dict(arrowstyle="-", lw=0.8),
                            bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="0.5", alpha=0.9))
        for k, (t, xy) in enumerate(zip(trk, tracks_xy)):
            ax.plot(xy[:, 0] / 1e3, xy[:, 1] / 1e3, color=COLORS[k % len(COLORS)], lw=1.3, zorder=5,
                    label=f"{t['name']}: {t['what']} (c1, c2, c3) = {t['weights']}")
            ax.plot(xy[-1, 0] / 1e3, xy[-1, 1] / 1e3, "o", color=COLORS[k % len(COLORS)], ms=5, zorder=6)
        ax.plot(emitter[0] / 1e3, emitter[1] / 1e3, "r*", ms=14 if title.startswith("zoom") else 16, mec="k",
                zorder=7, label="emitter")
        ax.plot(start[0] / 1e3, start[1] / 1e3, "k^", ms=9, zorder=7, label="UAV start")
        ax.set(xlim=ext[:2], ylim=ext[2:], xlabel="x (east), km", ylabel="y (north), km", title=title)
        ax.set_aspect("equal")
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    handles += [Patch(facecolor="0.35", alpha=0.35), Patch(facecolor="orange", alpha=0.35),
                Patch(facecolor="k")]
    labels += [f"shadow at {ALTITUDE:.0f} m altitude (no line of sight)",
               f"reflection (NLOS) region at {ALTITUDE:.0f} m (eqs. 9–10)", "buildings"]
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=9, frameon=False)
    fig.suptitle("UAV paths, seed 0 of each weight vector (dot = position at the last step); regions drawn "
                 f"for the true emitter at {ALTITUDE:.0f} m altitude (the UAV flies 100–400 m)")
    fig.tight_layout(rect=(0, 0.09, 1, 0.97))
    paths.append(out_dir / "paths.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    # (b) mean error over time with its 95 % t band (log y)
    err = np.asarray(records.error)[..., 0]            # (runs_total, T, F)
    T = err.shape[1]
    steps = np.arange(1, T + 1)
    filt = [(imm, "IMM-EKF (the paper's filter; the planner uses it)")]
    if ekf is not None:
        filt.append((ekf, "LOS-only EKF (ours: assumes line of sight)"))
    # the axis starts below every mean and median curve; a band reaching <= 0 (heavy tails, few runs) is cut there
    curves = [f(err[k * runs:(k + 1) * runs, :, i], 0) for k in range(len(trk)) for i, _ in filt
              for f in (np.mean, np.median)]
    floor = 0.3 * min(float(np.min(c[c > 0])) for c in curves if np.any(c > 0))
    fig, axes = plt.subplots(1, len(filt), figsize=(7 * len(filt), 5.2), sharey=True, squeeze=False)
    for ax, (f, title) in zip(axes[0], filt):
        for k, t in enumerate(trk):
            e = err[k * runs:(k + 1) * runs, :, f]
            m = e.mean(0)
            half = t_critical(runs - 1) * e.std(0, ddof=1) / np.sqrt(runs) if runs > 1 else np.zeros(T)
            c = COLORS[k % len(COLORS)]
            ax.fill_between(steps, np.maximum(m - half, floor), m + half, color=c, alpha=0.2, lw=0)
            ax.plot(steps, m, color=c, lw=1.5, label=f"{t['name']} ({t['what']}): mean, 95 % band")
            ax.plot(steps, np.median(e, 0), color=c, lw=1, ls="--", label=f"{t['name']}: median")
            if f == imm and np.isfinite(t["paper"]):
                ax.plot(T, t["paper"], marker="D", color=c, mec="k", ms=7, ls="none", clip_on=False,
                        label=f"{t['name']}: paper's Table 1 ({t['paper']:g} m)")
        ax.set_yscale("log")
        ax.set(xlabel="step (Δt = 2 s)", title=title, xlim=(0, T + 3), ylim=(floor, None))
        ax.grid(alpha=0.3, which="both")
    axes[0, 0].set_ylabel("distance of the estimate from the emitter, m (eq. 23)")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(trk), fontsize=8.5, frameon=False)
    fig.suptitle(f"Localisation error over time, mean over {runs} runs per weight vector (same seeds); "
                 "band: 95 % t interval of the mean (cut at the axis where it reaches 0)")
    fig.tight_layout(rect=(0, 0.13, 1, 0.95))
    paths.append(out_dir / "error_over_time.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths




# --------------------------------------------------------------------------- locks and holds

LOCK_STEPS = 20    # steps: a lock = this many steps in a row of clean LOS bearings the IMM calls NLOS
TRAP_STEPS = 60    # steps: a run "trapped" by the paper's hold = this many held steps in a row


def longest_true(flags: np.ndarray) -> np.ndarray:
    """Longest stretch of True per row of a (runs, steps) boolean array."""
    best = np.zeros(flags.shape[0], int)
    cur = np.zeros(flags.shape[0], int)
    for t in range(flags.shape[1]):
        cur = np.where(flags[:, t], cur + 1, 0)
        best = np.maximum(best, cur)
    return best


def locks(records) -> np.ndarray:
    """Per run: locked onto an NLOS mode = at least LOCK_STEPS steps in a row whose measurement was a
    clean line-of-sight bearing (no shadow, no reflection) while the IMM's NLOS+ + NLOS− probability
    exceeded 0.5 (the filter explained 40 s of unbiased bearings as biased ones)."""
    mu = np.asarray(records.mu)
    clean = ~np.asarray(records.shadow, bool) & ~np.asarray(records.nlos, bool)
    return longest_true(clean & (mu[..., 1] + mu[..., 2] > 0.5)) >= LOCK_STEPS


def setup_tables(label, trk, summ, records, runs: int, imm: int) -> str:
    """The flight table (with locks and holds) of one set-up."""
    fe = summ["final_error"][:, imm].reshape(len(trk), runs)
    lock = locks(records).reshape(len(trk), runs)
    hold = longest_true(np.asarray(records.held, bool)).reshape(len(trk), runs)
    lines = [f"\nFlight, locks and holds, {label} (means over runs; counts over the {runs} runs of each weight "
             "vector):\n",
             "| weight vector | shadow steps, mean | NLOS (reflected) steps, mean | held steps, mean | locked runs "
             f"(>= {LOCK_STEPS} clean LOS steps in a row called NLOS; % [95 % Wilson]) | IMM final error of locked / "
             f"other runs, mean, m | longest hold, mean steps | runs holding >= {TRAP_STEPS} steps in a row (% [95 % "
             "Wilson]) |", "|---|---|---|---|---|---|---|---|"]
    for k, t in enumerate(trk):
        sl = slice(k * runs, (k + 1) * runs)
        lk, e = lock[k], fe[k]
        el = f"{e[lk].mean():.1f}" if lk.any() else "–"
        lines.append(f"| {t['name']} | {summ['shadow_steps'][sl].mean():.1f} | {summ['nlos_steps'][sl].mean():.1f} | "
                     f"{summ['held_steps'][sl].mean():.1f} | {fmt_wilson(int(lk.sum()), runs)} | {el} / "
                     f"{e[~lk].mean():.1f} | {hold[k].mean():.1f} | "
                     f"{fmt_wilson(int(np.sum(hold[k] >= TRAP_STEPS)), runs)} |")
    lines.append(f"\nSeeds locked under every weight vector: {int(np.all(lock, axis=0).sum())} (of "
                 f"{int(np.any(lock, 0).sum())} seeds locked under any).")
    return "\n".join(lines)


# --------------------------------------------------------------------------- main


def main(argv=None) -> int:
    t_script = time.perf_counter()
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=1000, help="runs per weight vector (paper: 50)")
    ap.add_argument("--sweep", type=Path, default=ROOT / "sweeps" / "chen2022_table1.toml",
                    help="sweep spec of the default set-up (config and weight vectors)")
    ap.add_argument("--sweep-old", default=str(ROOT / "sweeps" / "chen2022_wide_prior_table1.toml"),
                    help="sweep spec of the first set-up (wide prior); '' to skip it")
    ap.add_argument("--max-hold", type=int, default=0,
                    help="also run the default set-up with params.max_hold_steps = N (ours; 0: not run)")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "chen2022_diagnostics")
    ap.add_argument("--base-seed", type=int, default=None, help="default: the sweep spec's")
    ap.add_argument("--no-figures", action="store_true")
    args = ap.parse_args(argv)
    if args.runs < 2:
        ap.error(f"--runs must be >= 2; got {args.runs}")
    runs = args.runs
    setups = [("default set-up", "default", args.sweep, {})]
    if args.max_hold > 0:
        setups.append((f"default set-up, max_hold_steps = {args.max_hold}", f"max_hold_{args.max_hold}", args.sweep,
                       {"params.max_hold_steps": args.max_hold}))
    if args.sweep_old:
        setups.append(("first set-up (wide prior)", "wide_prior", Path(args.sweep_old), {}))

    for label, tag, sweep, overrides in setups:
        spec = load_spec(sweep, seeds=runs, overrides=overrides)
        base_seed = spec.base_seed if args.base_seed is None else args.base_seed
        trk = tracks(spec)
        cfg = spec.config
        imm = cfg.filters.index("imm")
        ekf = cfg.filters.index("ekf") if "ekf" in cfg.filters else None
        records, summ, wall = run_sweep(spec, runs, base_seed)
        print(f"{label}: {spec.n_points} weight vectors x {runs} runs in {wall:.1f} s wall, compilation included; "
              f"load average {os.getloadavg()[0]:.2f}", flush=True)
        if not args.no_figures:
            (args.out / tag).mkdir(parents=True, exist_ok=True)
            for path in figures(spec, trk, records, runs, imm, ekf, args.out / tag):
                print(f"  figure: {path}")
        print(setup_tables(label, trk, summ, records, runs, imm))
        del records

    print(f"\nwhole script {time.perf_counter() - t_script:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
