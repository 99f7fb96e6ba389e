"""The figures of Ren & Lv 2017 (Figs. 2–5) over N runs: each UUV's position error over time (mean over
runs) for the consensus IMM-UKF and the CV-only and CT-only consensus UKFs, the IMM's CT probability
against the true mode, and one run's geometry (the UUVs, their comm links and the target's path). The
paper's claims (Table 1, the mismatched model's larger error) are checked by
`mcjax check benchmarks/claims/ren2017.toml`.

    python benchmarks/papers/ren2017_figures.py                     # 1,000 runs -> results/ren2017_figures/
    python benchmarks/papers/ren2017_figures.py --schedule markov   # modes drawn from the Markov chain

Writes errors_over_time.png, mode_probability.png and geometry.png.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from records import run_records

ROOT = Path(__file__).resolve().parents[2]
FILTERS = ("imm", "cv", "ct")
LABELS = {"imm": "consensus IMM-UKF", "cv": "CV only", "ct": "CT only"}


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
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "ren2017_figures")
    args = ap.parse_args(argv)
    if args.runs < 1:
        ap.error(f"--runs must be >= 1; got {args.runs}")
    args.out.mkdir(parents=True, exist_ok=True)
    runs = run_records(args.config, args.runs,
                       config_over={"filters": FILTERS, **({"schedule": args.schedule} if args.schedule else {})})
    print(f"{args.runs} runs in {runs.seconds:.1f} s including compilation")
    for path in figures(runs.config, runs.params, runs.records, args.out):
        print(f"figure: {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
