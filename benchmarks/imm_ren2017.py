"""Ren & Lv 2017 Table 1 and Figs. 2–5: consensus IMM-UKF vs single-model CV / CT.

Runs N seeds (default 1,000; the paper ran 50) of ``configs/ren2017.toml``: six UUVs, a target
that flies CV, turns (CT) over ``[ct_start, ct_stop)``, then flies CV again (``--schedule
markov`` draws the modes from the Markov chain instead). Prints the paper's Table 1 — for each
UUV, the max / min / mean over time of its position error, averaged over the runs, for the
consensus IMM-UKF and the CV-only and CT-only consensus UKFs — then the mean error of each
filter while the target flies straight and while it turns, and checks the paper's qualitative
claims. Writes every run's summary to ``OUT/runs/`` (one Parquet part) and PNG figures: each UUV's error
over time (mean over runs), the IMM's CT probability over time, and one run's geometry.

    python benchmarks/imm_ren2017.py                  # 1,000 runs
    python benchmarks/imm_ren2017.py --runs 50        # the paper's count

The paper's Table 1 numbers are not legible in the source text, so only its qualitative
claims are checked: the IMM has the lowest mean error for every UUV, and the single model
that mismatches the current manoeuvre has the larger error during it.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import jax
import numpy as np
import pandas as pd

from mcjax import engine
from mcjax.results import environment_metadata, write_part
from mcjax.study import load_config_file, run_rows
from mcjax import configure

configure()  # JAX's 64-bit mode and CPU devices, as the CLI sets them

ROOT = Path(__file__).resolve().parent.parent
FILTERS = ("imm", "cv", "ct")
LABELS = {"imm": "consensus IMM-UKF", "cv": "CV only", "ct": "CT only"}


def run(config: Path, runs: int, schedule: str | None, base_seed: int):
    """All runs' records (numpy, run axis first), summaries, and the wall time incl. compilation."""
    scenario, cfg, params = load_config_file(config)
    cfg = dataclasses.replace(cfg, filters=FILTERS, **({"schedule": schedule} if schedule else {}))
    p = scenario.default_params(cfg, **params)
    t0 = time.perf_counter()
    chunks = [o for _, _, _, o in engine.run_chunks(scenario, cfg, engine.stack_points([p]), runs,
                                                    base_seed=base_seed, chunk_size=runs, records=True)]
    records = jax.tree.map(lambda *xs: np.concatenate(xs), *chunks)
    summaries = jax.jit(jax.vmap(lambda r: scenario.reduce(cfg, r, p)))(records)
    summaries = {k: np.asarray(v) for k, v in summaries.items()}
    return scenario, cfg, p, records, summaries, time.perf_counter() - t0


def table1(out: dict, n_agents: int) -> pd.DataFrame:
    """Per UUV and filter: max / min / mean over time of the position error, mean over runs."""
    data = {}
    for i in range(1, n_agents + 1):
        row = {}
        for f, name in enumerate(FILTERS):
            for stat in ("max", "min", "mean"):
                row[(name, stat)] = float(np.mean(out[f"uuv{i}_{stat}_error"][:, f]))
        data[f"UUV{i}"] = row
    df = pd.DataFrame(data).T
    df.columns = pd.MultiIndex.from_tuples(df.columns)
    return df


def markdown(t1: pd.DataFrame) -> str:
    head = "| UUV | " + " | ".join(f"{LABELS[f]} {s}" for f in FILTERS for s in ("max", "min", "mean")) + " |"
    lines = [head, "|" + "---|" * (1 + 3 * len(FILTERS))]
    for uuv, r in t1.iterrows():
        lines.append(f"| {uuv} | " + " | ".join(f"{r[(f, s)]:.2f}" for f in FILTERS for s in ("max", "min", "mean"))
                     + " |")
    return "\n".join(lines)


def segments(out: dict) -> str:
    lines = ["| filter | mean error, m | while CV, m | while CT, m | ANEES (4 dof) | divergent runs |", "|---|---|---|---|---|---|"]
    for f, name in enumerate(FILTERS):
        lines.append(f"| {LABELS[name]} | {np.mean(out['mean_error'][:, f]):.2f} | {np.nanmean(out['error_cv'][:, f]):.2f} | "
                     f"{np.nanmean(out['error_ct'][:, f]):.2f} | {np.mean(out['anees'][:, f]):.2f} | "
                     f"{int(out['diverged'][:, f].sum())} |")
    return "\n".join(lines)


def checks(t1: pd.DataFrame, out: dict) -> list[tuple[str, bool]]:
    """The qualitative claims of Ren & Lv 2017 §4 (Table 1, Figs. 2–5)."""
    mean = {f: t1[(f, "mean")] for f in FILTERS}
    during_ct = {f: np.nanmean(out["error_ct"][:, k]) for k, f in enumerate(FILTERS)}
    during_cv = {f: np.nanmean(out["error_cv"][:, k]) for k, f in enumerate(FILTERS)}
    return [
        ("consensus IMM-UKF has a lower mean error than CV-only for every UUV", bool((mean["imm"] < mean["cv"]).all())),
        ("consensus IMM-UKF has a lower mean error than CT-only for every UUV", bool((mean["imm"] < mean["ct"]).all())),
        (f"while the target turns, the mismatched CV-only model has the larger error "
         f"({during_ct['cv']:.2f} m > CT-only {during_ct['ct']:.2f} m)", during_ct["cv"] > during_ct["ct"]),
        (f"while the target flies straight, the mismatched CT-only model has the larger error "
         f"({during_cv['ct']:.2f} m > CV-only {during_cv['cv']:.2f} m)", during_cv["ct"] > during_cv["cv"]),
    ]


def figures(cfg, p, records, out_dir: Path) -> list[Path]:
    """Figs. 2–5 of the paper (each UUV's error over time, mean over runs), the IMM's mode
    probability over time, and the geometry of run 0."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    err = records.error                      # (runs, T, F, n)
    T = err.shape[1]
    t = np.arange(T) * float(p.dt)
    mode = records.mode                      # (runs, T)
    fixed = cfg.schedule == "fixed"

    def shade(ax):
        if fixed:
            ax.axvspan(float(p.ct_start) * float(p.dt), float(p.ct_stop) * float(p.dt), color="0.9", zorder=0,
                       label="target turns (CT)")

    n = err.shape[-1]
    cols = 3 if n >= 3 else n
    fig, axes = plt.subplots(-(-n // cols), cols, figsize=(4.2 * cols, 3.0 * -(-n // cols)), sharex=True,
                             sharey=True, squeeze=False)
    mean_err = np.nanmean(err, axis=0)       # (T, F, n)
    for i, ax in enumerate(axes.ravel()):
        if i >= n:
            ax.set_visible(False)
            continue
        shade(ax)
        for f, name in enumerate(FILTERS):
            ax.plot(t, mean_err[:, f, i], label=LABELS[name])
        ax.set(title=f"UUV{i + 1}", ylabel="position error, m" if i % cols == 0 else None,
               xlabel="t, s" if i >= n - cols else None)
    axes.ravel()[0].legend(fontsize=8)
    fig.suptitle(f"Position error over time, mean over {err.shape[0]} runs ({cfg.schedule} schedule)")
    paths.append(out_dir / "errors_over_time.png")
    fig.savefig(paths[-1], dpi=110, bbox_inches="tight")
    plt.close(fig)

    mu = np.nanmean(records.mu_ct, axis=-1)  # (runs, T), mean over UUVs
    fig, ax = plt.subplots(figsize=(7, 3.5))
    shade(ax)
    ax.fill_between(t, np.percentile(mu, 5, axis=0), np.percentile(mu, 95, axis=0), alpha=0.3,
                    label="5–95 % over runs")
    ax.plot(t, mu.mean(axis=0), label="IMM P(CT), mean over runs and UUVs")
    ax.plot(t, mode.mean(axis=0), "k--", lw=1, label="true mode (fraction of runs in CT)")
    ax.set(xlabel="t, s", ylabel="probability", ylim=(-0.02, 1.02), title="Mode probability of the consensus IMM-UKF")
    ax.legend(fontsize=8, loc="center right")
    paths.append(out_dir / "mode_probability.png")
    fig.savefig(paths[-1], dpi=110, bbox_inches="tight")
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 6))
    pos = np.asarray(p.uuv_positions)
    radius = np.broadcast_to(np.asarray(p.comm_radius), (n,))
    for a in range(n):
        for b in range(a + 1, n):
            if np.hypot(*(pos[a] - pos[b])) <= min(radius[a], radius[b]):
                ax.plot(pos[[a, b], 0], pos[[a, b], 1], color="0.7", lw=1, zorder=0)
    ax.plot(pos[:, 0], pos[:, 1], "bs", label="UUVs (comm links grey)")
    for i in range(n):
        ax.annotate(f"UUV{i + 1}", pos[i], textcoords="offset points", xytext=(5, 5), fontsize=8)
    tgt = records.target[0]
    ct = mode[0] == 1
    ax.plot(tgt[:, 0], tgt[:, 2], "k-", lw=1, label="target (run 0)")
    ax.plot(tgt[ct, 0], tgt[ct, 2], "r.", ms=3, label="turning (CT)")
    ax.set(xlabel="x, m", ylabel="y, m", title=f"Geometry (comm radius {float(np.max(radius)):.0f} m)")
    ax.set_aspect("equal", "datalim")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    paths.append(out_dir / "geometry.png")
    fig.savefig(paths[-1], dpi=110, bbox_inches="tight")
    plt.close(fig)
    return paths


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=1000, help="Monte-Carlo runs (paper: 50)")
    ap.add_argument("--schedule", choices=["fixed", "markov"], default=None,
                    help="target mode schedule (default: the config's, 'fixed')")
    ap.add_argument("--config", type=Path, default=ROOT / "configs" / "ren2017.toml")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "imm_ren2017")
    ap.add_argument("--base-seed", type=int, default=0)
    ap.add_argument("--no-figures", action="store_true")
    args = ap.parse_args(argv)
    if args.runs < 1:
        ap.error(f"--runs must be >= 1; got {args.runs}")
    args.out.mkdir(parents=True, exist_ok=True)

    scenario, cfg, p, records, out, wall = run(args.config, args.runs, args.schedule, args.base_seed)
    print(f"{args.runs} runs x {cfg.n_steps} steps ({cfg.schedule} schedule, {cfg.n_agents} UUVs, "
          f"L = {cfg.consensus_steps}, {cfg.consensus_weights} weights) in {wall:.1f} s including compilation "
          f"({wall / args.runs * 1e3:.1f} ms/run)", flush=True)
    df = run_rows(scenario, cfg, out, {"seed_index": np.arange(args.runs)})
    meta = {**scenario.metadata(cfg), "benchmark": "imm_ren2017", "config": dataclasses.asdict(cfg),
            "config_file": str(args.config), "runs": args.runs, "wall_s": wall, **environment_metadata()}
    path = write_part(args.out, "runs", df, "part-000000", meta)
    print(f"runs: {path} ({len(df)} rows; read back with pandas.read_parquet(\"{args.out / 'runs'}\"))")
    if not args.no_figures:
        for path in figures(cfg, p, records, args.out):
            print(f"figure: {path}")
    t1 = table1(out, cfg.n_agents)
    print(f"\nTable 1 — position error of each UUV's estimate, m: max / min / mean over t >= "
          f"{cfg.warmup_steps} s, averaged over {args.runs} runs\n")
    print(markdown(t1))
    print("\nBy manoeuvre (mean over UUVs, steps and runs)\n")
    print(segments(out))
    print()
    failed = 0
    for text, ok in checks(t1, out):
        print(("holds   " if ok else "FAILS   ") + text)
        failed += not ok
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
