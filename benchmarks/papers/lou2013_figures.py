"""Lou, Cui & Li 2013 Figs. 3–6 over N runs, and the diagnostics a claims file cannot give. The
paper's claims (KCF beats KF, λ2 > 0, no link breaks, no collision, links stable by 15 s, spacing
6.5 m, energy falls, Theorem 2's ideal case) are ``benchmarks/claims/lou2013.toml``
(``mcjax check benchmarks/claims/lou2013.toml``); the integrators compared:
``benchmarks/papers/lou2013_integrator.py``; the cost from 20 to 100 nodes:
``benchmarks/speed/lou2013_scaling.py``. This script draws and prints, and checks nothing.

What is run: ``configs/lou2013.toml`` as it stands, N seeds (default 1,000) of 300 steps of 0.1 s
through ``mcjax.engine.run_chunks`` (per-run summaries and per-step series from one simulation).

    python benchmarks/papers/lou2013_figures.py               # 1,000 runs (~40 min on 2 loaded shared cores)
    python benchmarks/papers/lou2013_figures.py --runs 20     # a quick look

What it prints: (1) the wall time and the sub-steps per 0.1 s step; (2) the extremes — smallest
distance, smallest link margin R − r, largest rise of Q — and their change when the 10 runs nearest
each are re-run at 100x tighter tolerance; (3) the energy Q = φ of eq. 15 (Fig. 5) over the runs
whose flock stayed finite: the runs whose Q(t) never rises, every rise attributed to a step that
formed a new link (its potential enters Q) or not, and the four terms of Q for seed 0.

Figures (``--out``, default ``results/lou2013_figures/``; ``--no-figures``): errors over time
(``fig3_errors.png``), the flock of seed 0 at t = 0, 15 and 30 s with its links, the target
and its path (``flock_seed0.png``), energy and λ2 over time (``fig5_energy_lambda2.png``),
links over time (``fig4_edges.png``) and minimum distance over time (``fig6_min_distance.png``).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import math
import os
import time
from pathlib import Path

import jax
import numpy as np

from mcjax import engine
from mcjax.analysis.statistics import t_critical, wilson_interval
from mcjax.scenarios.lou2013 import target_state
from figures import run_records  # the one run set-up of the papers' figures (this folder)
from mcjax import configure

configure()  # JAX's 64-bit mode and CPU devices, as the CLI sets them

ROOT = Path(__file__).resolve().parents[2]
LABELS = {"kcf": "KCF (Alg. 1)", "local": "standalone KF"}
#: The paper's Fig. 6 minimum distance (not reachable with its eq. 12; drawn, not targeted).
PAPER_MIN_DISTANCE = 6.5
#: A rise of Q between two steps above this fraction of Q after the first step is a rise.
MONOTONE_RTOL = 1e-9
SNAPSHOTS_S = (0.0, 15.0, 30.0)


# --------------------------------------------------------------------------- runs


# --------------------------------------------------------------------------- one run, step by step


@functools.cache
def _stepper(scenario, cfg):
    """Jitted ``init`` and ``step`` of one Config (params and keys are arguments), made once:
    every seed of (a) then reuses one compilation."""
    return (jax.jit(lambda p, k: scenario.init(cfg, p, k)), jax.jit(lambda p, s, k: scenario.step(cfg, p, s, k)))


def trajectory(scenario, cfg, p, seed_index: int, base_seed: int = 0) -> dict:
    """Run ``seed_index`` step by step in a jitted Python loop with the engine's keys (run key
    ``fold_in(PRNGKey(base_seed), seed)``; init ``engine.init_key(key)``; step t
    ``fold_in(key, t)``, as in ``mcjax.engine``). Returns the positions ``q``, velocities ``v``,
    adaptive gains ``b`` and graphs ``adj`` of the states (T+1, ...; index k = time k·dt) and the
    step records' ``lambda2``, ``edges`` and ``energy`` (T,)."""
    init, step = _stepper(scenario, cfg)
    key = engine.run_key(base_seed, seed_index)
    states, recs = [init(p, engine.init_key(key))], []
    for t in range(cfg.n_steps):
        state, rec = step(p, states[-1], jax.random.fold_in(key, t))
        states.append(state)
        recs.append(rec)
    stack = lambda xs: np.stack([np.asarray(x, float) for x in xs])  # noqa: E731
    return dict(q=stack(s.flock.q for s in states), v=stack(s.flock.p for s in states),
                b=stack(s.flock.b for s in states), adj=stack(s.adj for s in states),
                **{k: stack(getattr(r, k) for r in recs) for k in ("lambda2", "edges", "energy")})


def _distances(q: np.ndarray) -> np.ndarray:
    d = np.sqrt(np.sum((q[:, None, :] - q[None, :, :]) ** 2, -1))
    np.fill_diagonal(d, np.inf)
    return d


def energy_terms(cfg, p, tr: dict, k: int) -> dict:
    """The four terms of Q = φ (Lou et al. 2013 eq. 15, l = c2) for state index ``k`` of a
    :func:`trajectory`, in numpy: the potential of eq. 12 over links, type-I tracking
    ``c1 ‖q_i − q_γ‖²``, kinetic ``‖p_i − p_γ‖²`` and the type-II adaptive gains
    ``(b_ij − l)²/(2k)``, each with the ½ of eq. 15."""
    q, v, b, adj = tr["q"][k], tr["v"][k], tr["b"][k], tr["adj"][k] > 0.5
    n = len(q)
    h = (np.arange(n) < float(p.n_sensing)).astype(float)
    x = np.asarray(target_state(cfg, p, np.float64(k * float(p.dt))))
    R, c1, l, kk = float(p.R), float(p.c1), float(p.c2), float(p.k)
    r = np.where(adj, _distances(q), R / 2)
    psi = np.where(adj, 1.0 / r**2 + r**2 / (R - r), 0.0)
    return dict(potential=0.5 * psi.sum(), tracking=0.5 * np.sum(h * c1 * np.sum((q - x[[0, 2]]) ** 2, -1)),
                kinetic=0.5 * np.sum((v - x[[1, 3]]) ** 2),
                gains=0.5 * np.sum(np.where(adj, (b - l) ** 2, 0.0).sum(1) * (1 - h) / (2 * kk)))


def fmt_frac(k: int, n: int) -> str:
    lo, hi = wilson_interval(k, n)
    return f"{k}/{n} = {k / n:.3f} [{lo:.3f}, {hi:.3f}]"


def blow_ups(series: dict) -> np.ndarray:
    """Runs whose flock state went non-finite (the integration blew up): Q(t) of eq. 15 is finite
    for any finite flock whose links are shorter than R (links at R break first), so a
    non-finite Q marks NaN positions. Returns the mask (runs,)."""
    return ~np.all(np.isfinite(series["energy"]), axis=1)


def energy_rises(series: dict, out: dict) -> dict:
    """Rises of Q(t) between consecutive steps, relative to Q after the first step, and
    whether the step that rose formed a new link (its potential enters Q); over the runs
    whose flock stayed finite."""
    keep = ~blow_ups(series)
    out = {k: np.asarray(v)[keep] for k, v in out.items()}
    e, edges = series["energy"][keep], series["edges"][keep]
    rise = np.diff(e, axis=1)
    rel = rise / np.abs(out["energy_start"])[:, None]
    is_rise = rel > MONOTONE_RTOL
    new_link = np.diff(edges, axis=1) > 0
    at_link, elsewhere = is_rise & new_link, is_rise & ~new_link
    worst = lambda m: float(np.max(np.where(m, rel, 0.0))) if m.any() else 0.0  # noqa: E731
    worst_abs = lambda m: float(np.max(np.where(m, rise, 0.0))) if m.any() else 0.0  # noqa: E731
    return dict(runs=len(e), blown=int(np.sum(~keep)), monotone=int(np.sum(~is_rise.any(1))), rises=int(is_rise.sum()),
                at_link=int(at_link.sum()), elsewhere=int(elsewhere.sum()),
                runs_elsewhere=int(np.sum(elsewhere.any(1))), link_steps=int(new_link.sum()),
                max_rel=worst(is_rise), max_rel_link=worst(at_link), max_rel_elsewhere=worst(elsewhere),
                max_abs=worst_abs(is_rise), max_abs_elsewhere=worst_abs(elsewhere),
                median_rel=float(np.median(np.maximum(out["energy_max_rise"], 0) / np.abs(out["energy_start"]))),
                end_below_start=int(np.sum(out["energy_end"] < out["energy_start"])))


def energy_lines(en: dict, label: str) -> list[str]:
    return [
        f"{label}, the {en['runs']} runs whose flock stayed finite ({en['blown']} blew up: left out): "
        f"Q(t) never rises (every step-to-step rise ≤ {MONOTONE_RTOL:g} × Q after the first step) in "
        f"{fmt_frac(en['monotone'], en['runs'])} of runs; median over runs of the largest relative rise "
        f"{en['median_rel']:.3g}; Q at the end below Q after the first step in "
        f"{fmt_frac(en['end_below_start'], en['runs'])}",
        f"  rises: {en['rises']} steps over all runs, {en['at_link']} at a step that formed a new link "
        f"({en['link_steps']} such steps in all), {en['elsewhere']} at other steps ({en['runs_elsewhere']} runs); "
        f"largest rise {en['max_abs']:.4g} ({en['max_rel']:.3g} of Q), at a new link {en['max_rel_link']:.3g} of Q, "
        f"elsewhere {en['max_abs_elsewhere']:.4g} ({en['max_rel_elsewhere']:.3g} of Q)",
    ]


# --------------------------------------------------------------------------- the integrator's convergence


EXTREMES = (("min_distance", "smallest distance between two nodes, m", np.argmin),
            ("min_link_margin", "smallest link margin R − r, m", np.argmin),
            ("energy_max_rise", "largest rise of Q between two steps", np.argmax))


def convergence(scenario, cfg, p, out: dict, base_seed: int, per_extreme: int = 10, factor: float = 100.0):
    """Each extreme over the runs (smallest distance, smallest link margin, largest energy rise)
    at the config's tolerance and ``factor`` times tighter: the ``per_extreme`` runs nearest
    each extreme are re-run at the tighter tolerance (an extreme moves by far less than the gap
    to the next run, checked), and the largest change of any re-run run's value. Returns
    ``(rows, tight config, runs re-run, their wall time)``."""
    order = {name: (np.argsort(out[name]) if pick is np.argmin else np.argsort(-out[name]))[:per_extreme]
             for name, _, pick in EXTREMES}
    seeds = np.unique(np.concatenate(list(order.values())))
    tight = dataclasses.replace(cfg, tolerance=cfg.tolerance / factor)
    # the chosen seeds alone, in one compiled batch with the engine's keys (run_chunks runs 0 … N−1)
    keys = jax.numpy.asarray(engine.run_keys(base_seed, seeds))
    params = jax.tree.map(lambda x: jax.numpy.broadcast_to(x, (len(seeds),) + np.shape(x)), p)
    t0 = time.perf_counter()
    fine = {k: np.asarray(v) for k, v in engine.compiled(scenario, tight)(params, keys).items()}
    wall = time.perf_counter() - t0
    rows = []
    for name, label, pick in EXTREMES:
        change = np.abs(fine[name] - out[name][seeds])
        i = int(pick(out[name]))
        extreme_fine = fine[name][int(pick(fine[name]))]
        ranked = np.sort(out[name]) if pick is np.argmin else -np.sort(-out[name])
        rows.append(dict(label=label, value=float(out[name][i]), seed=i, tight=float(extreme_fine),
                         change=float(abs(extreme_fine - out[name][i])), max_change=float(change.max()),
                         gap=float(abs(ranked[per_extreme] - out[name][i])) if len(ranked) > per_extreme
                         else math.nan))
    return rows, tight, len(seeds), wall


# --------------------------------------------------------------------------- figures


def _band(ax, t, x, color, label, lo=5, hi=95):
    """Median and lo–hi percentile band over runs (rows)."""
    x = np.asarray(x, float)
    ax.fill_between(t, np.percentile(x, lo, axis=0), np.percentile(x, hi, axis=0), color=color, alpha=0.25,
                    lw=0, label=f"{lo}–{hi} % over runs")
    ax.plot(t, np.median(x, axis=0), color=color, lw=1.6, label=label)


def figures(cfg, p, series: dict, out: dict, traj0: dict, out_dir: Path) -> list[Path]:
    """Figs. 3–6 over the runs and the flock of seed 0 (Figs. 1–2), as PNGs in ``out_dir``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []

    def save(fig, name):
        paths.append(out_dir / name)
        fig.savefig(paths[-1], dpi=120, bbox_inches="tight")
        plt.close(fig)

    dt = float(p.dt)
    runs, T = series["energy"].shape
    blown = blow_ups(series)
    kept = (f"{runs - int(blown.sum())} runs whose flock stayed finite"
            + (f" ({int(blown.sum())} blew up)" if blown.any() else ""))
    t_end = (np.arange(T) + 1) * dt          # the series are at the end of each step
    t_start = np.arange(T) * dt               # the errors are at each step's measurement time

    # (a) Fig. 3: the error of the type-I nodes' estimates over time
    fig, ax = plt.subplots(figsize=(8, 4.2))
    crit = t_critical(runs - 1)
    for f, name in enumerate(cfg.filters):
        e = series["error_mean"][:, :, f]     # (runs, T)
        m = e.mean(0)
        half = crit * e.std(0, ddof=1) / math.sqrt(runs) if runs > 1 else np.zeros_like(m)
        color = {"kcf": "tab:blue", "local": "tab:orange"}.get(name, None)
        ax.fill_between(t_start, np.percentile(e, 5, 0), np.percentile(e, 95, 0), color=color, alpha=0.12, lw=0,
                        label=f"{LABELS.get(name, name)}: 5–95 % of runs")
        ax.fill_between(t_start, m - half, m + half, color=color, alpha=0.45, lw=0)
        ax.plot(t_start, m, color=color, lw=1.5,
                label=f"{LABELS.get(name, name)}: mean over runs (band: 95 % t interval)")
    ax.axvline(cfg.warmup_steps * dt, color="0.5", ls=":", lw=1, label="end of warm-up (RMSE after)")
    ax.set(xlabel="t, s", ylabel="position error of the estimate, m",
           title=f"Fig. 3 — type-I nodes' mean position error, {runs} runs", ylim=(0, None))
    ax.legend(fontsize=8, loc="upper right")
    save(fig, "fig3_errors.png")

    # (b) Figs. 1–2: the flock of seed 0 at t = 0, 15, 30 s
    fig, axes = plt.subplots(1, len(SNAPSHOTS_S), figsize=(5.2 * len(SNAPSHOTS_S), 5.0))
    m_sense = int(round(float(p.n_sensing)))
    xs = np.linspace(-1.0, float(p.target_speed) * T * dt + 5.0, 2000)
    for ax, ts in zip(axes, SNAPSHOTS_S):
        k = min(int(round(ts / dt)), T)
        q, adj = traj0["q"][k], traj0["adj"][k]
        for i, j in zip(*np.nonzero(np.triu(adj > 0.5, 1))):
            ax.plot(q[[i, j], 0], q[[i, j], 1], color="0.75", lw=0.5, zorder=1)
        ax.plot(xs, np.sin(xs), "k--", lw=1, zorder=0, label="target path y = sin x")
        ax.plot(q[m_sense:, 0], q[m_sense:, 1], "o", mfc="white", mec="tab:blue", ms=6, zorder=3,
                label="type II (no sensing)")
        ax.plot(q[:m_sense, 0], q[:m_sense, 1], "o", color="tab:red", ms=6, zorder=3, label="type I (senses, KCF)")
        tg = np.asarray(target_state(cfg, p, np.float64(k * dt)))
        ax.plot(tg[0], tg[2], "*", color="gold", mec="k", ms=16, zorder=4, label="target")
        lo = np.minimum(q.min(0), [tg[0], tg[2]]) - 1.0
        hi = np.maximum(q.max(0), [tg[0], tg[2]]) + 1.0
        c, half = (lo + hi) / 2, max(hi - lo) / 2
        ax.set(xlim=(c[0] - half, c[0] + half), ylim=(c[1] - half, c[1] + half), xlabel="x, m", ylabel="y, m",
               title=f"t = {k * dt:.0f} s: {int(np.sum(adj) // 2)} links")
        ax.set_aspect("equal")
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=9, bbox_to_anchor=(0.5, -0.04))
    fig.suptitle(f"Seed 0: the flock and its hysteresis graph (R = {float(p.R)} m, links grey)")
    save(fig, "flock_seed0.png")

    # (c) Fig. 5: energy Q(t) and λ2(t)
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True)
    _band(a1, t_end, series["energy"][~blown], "tab:purple", "median over runs")
    a1.set_yscale("log")
    a1.set(ylabel="energy Q = φ of eq. 15\n(as in the paper, no single unit)",
           title=f"Fig. 5 — energy Q: the {kept}")
    a2.set_title(f"λ2: all {runs} runs", fontsize=10)
    a1.legend(fontsize=8)
    lam = series["lambda2"]
    _band(a2, t_end, lam, "tab:green", "median over runs")
    a2.plot(t_end, lam.min(0), color="k", lw=1, ls="--", label="min over runs (0: some run broke apart)")
    a2.set(xlabel="t, s", ylabel="λ2 of the graph Laplacian", ylim=(0, cfg.n_agents * 1.05))
    a2.legend(fontsize=8, loc="lower right")
    save(fig, "fig5_energy_lambda2.png")

    # Fig. 4: links over time
    fig, ax = plt.subplots(figsize=(8, 3.6))
    _band(ax, t_end, series["edges"], "tab:brown", "median over runs")
    ax.plot(t_end, series["edges"].min(0), color="k", lw=1, ls="--", label="min over runs (0: some run broke apart)")
    ax.axhline(cfg.n_agents * (cfg.n_agents - 1) / 2, color="0.5", ls=":", lw=1, label="complete graph")
    ax.set(xlabel="t, s", ylabel="links in the hysteresis graph",
           title=f"Fig. 4 — links over time; last change: median {np.median(out['last_change_time']):.1f} s, "
                 f"max {np.max(out['last_change_time']):.1f} s")
    ax.legend(fontsize=8, loc="lower right")
    save(fig, "fig4_edges.png")

    # (d) Fig. 6: the minimum distance over time
    fig, ax = plt.subplots(figsize=(8, 4.2))
    dm = series["min_distance"][~blown]
    _band(ax, t_end, dm, "tab:cyan", "median over runs (smallest pair distance in the step)")
    ax.plot(t_end, dm.min(0), color="k", lw=1, ls="--", label="min over runs")
    ax.axhline(PAPER_MIN_DISTANCE, color="tab:red", ls=":", lw=1.2)
    ax.text(t_end[-1], PAPER_MIN_DISTANCE * 0.85,
            f"paper's Fig. 6: {PAPER_MIN_DISTANCE} m — not reachable with eq. 12 "
            f"(ours settles at {np.median(dm[:, -1]):.2f} m, median)",
            ha="right", va="top", fontsize=8, color="tab:red")
    ax.set_yscale("log")
    ax.set(xlabel="t, s", ylabel="minimum distance between nodes, m",
           title=f"Fig. 6 — minimum inter-node distance, the {kept}", ylim=(0.05, 10))
    ax.legend(fontsize=8, loc="lower right")
    save(fig, "fig6_min_distance.png")
    return paths


# --------------------------------------------------------------------------- main


def print_speed(args, r) -> None:
    """Section 1: wall time and sub-steps of the paper's runs."""
    cfg, p, out = r.config, r.params, r.records[0]
    print(f"\n## Lou, Cui & Li 2013 — {args.runs} runs x {cfg.n_steps} steps of {float(p.dt)} s "
          f"({cfg.n_agents} nodes, M = {int(p.n_sensing)} type I, R = {float(p.R)} m, ε = {float(p.epsilon)} m, "
          f"config {args.config.name}); the claims: mcjax check benchmarks/claims/lou2013.toml\n")
    print(f"wall {r.seconds:.1f} s including compilation; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    print(f"sub-steps ({cfg.integrator}; attempts if adaptive) per 0.1 s step: mean over runs "
          f"{out['substeps_mean'].mean():.2f} (run means: min {out['substeps_mean'].min():.2f}, max "
          f"{out['substeps_mean'].max():.2f}); steps at the cap of {cfg.max_substeps}: "
          f"{int(out['substeps_capped'].sum())} (in {int(np.sum(out['substeps_capped'] > 0))} runs)")


def print_extremes(args, r) -> None:
    """Section 2: the extremes at 100x tighter tolerance."""
    conv, tight, n_conv, wall_conv = convergence(r.scenario, r.config, r.params, r.records[0], args.base_seed)
    print(f"\n### The integrator: {r.config.integrator}, tolerance {r.config.tolerance:g} (m, m/s) — extremes and their "
          f"convergence\n")
    print(f"the {n_conv} runs nearest the three extremes re-run at {tight.tolerance:g} (100x tighter) in "
          f"{wall_conv:.1f} s incl. compilation\n")
    print("| extreme over the runs | value | seed | at 100x tighter | change | largest change of a re-run run | "
          "gap to the 11th run |\n|---|---|---|---|---|---|---|")
    for row in conv:
        print(f"| {row['label']} | {row['value']:.6g} | {row['seed']} | {row['tight']:.6g} | {row['change']:.1e} | "
              f"{row['max_change']:.1e} | {row['gap']:.1e} |")


def print_energy(args, r, traj0: dict) -> None:
    """Section 3: the rises of Q and its terms for seed 0 (Theorem 2's ideal case, where Q never rises,
    is a claim of benchmarks/claims/lou2013.toml)."""
    cfg, p, out = r.config, r.params, r.records[0]
    blown = blow_ups(r.records[1])
    print("\n### Energy Q(t) = φ of eq. 15 (Fig. 5)\n")
    print("\n".join(energy_lines(energy_rises(r.records[1], out), f"paper's set-up ({args.runs} runs)")))
    print(f"  Q after the first step: median {np.median(out['energy_start'][~blown]):.4g}; at the end: median "
          f"{np.median(out['energy_end'][~blown]):.4g}")
    rows = []
    for k in (1, 20, cfg.n_steps):
        terms = energy_terms(cfg, p, traj0, k)
        rows.append(f"| {k * float(p.dt):.1f} | {traj0['energy'][k - 1]:.1f} | {sum(terms.values()):.1f} | "
                    + " | ".join(f"{v:.1f}" for v in terms.values()) + " |")
    print("\n  the terms of Q for seed 0 (numpy, from the step-by-step run's state; the record's Q beside "
          "their sum):\n")
    print("| t, s | Q (record) | sum of terms | potential ψ (eq. 12) | tracking c1‖q − q_γ‖² (type I) | kinetic "
          "‖p − p_γ‖² | adaptive gains (b − l)²/(2k) (type II) |\n|---|---|---|---|---|---|---|")
    print("\n".join(rows))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=1000, help="Monte-Carlo runs of the paper's set-up")
    ap.add_argument("--config", type=Path, default=ROOT / "configs" / "lou2013.toml")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "lou2013_figures")
    ap.add_argument("--base-seed", type=int, default=0)
    ap.add_argument("--no-figures", action="store_true")
    args = ap.parse_args(argv)
    if args.runs < 1:
        ap.error(f"--runs must be >= 1; got {args.runs}")
    wall0 = time.perf_counter()
    paper = run_records(args.config, args.runs, base_seed=args.base_seed, series=True)
    print_speed(args, paper)
    print_extremes(args, paper)
    traj0 = trajectory(paper.scenario, paper.config, paper.params, 0, args.base_seed)  # the terms of Q, the seed-0 figure
    print_energy(args, paper, traj0)
    if not args.no_figures:
        args.out.mkdir(parents=True, exist_ok=True)
        print()
        for path in figures(paper.config, paper.params, paper.records[1], paper.records[0], traj0, args.out):
            print(f"figure: {path}")
    print(f"\ntotal wall time {time.perf_counter() - wall0:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
