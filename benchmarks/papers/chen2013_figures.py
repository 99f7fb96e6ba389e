"""The figures of Chen & Lu 2013 (Figs. 4–6) over N runs: seed 0's paths along the reference path with
the formation's centroid, the pairwise distances over time (seed 0, and the 5–95 % band over the runs,
against the formation's), and UAV2's wind error along x and y for each filter beside the unfiltered
measurement. Table 1 and the paper's claims are checked by `mcjax check benchmarks/claims/chen2013.toml`.

    python benchmarks/papers/chen2013_figures.py             # 1,000 runs -> results/chen2013_figures/

Writes paths.png, distances.png and wind_error.png.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from mcjax.scenarios import wind_formation as S
from records import run_records

ROOT = Path(__file__).resolve().parents[2]


def figures(cfg, p, rec, out_dir: Path) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    pos = np.concatenate([np.broadcast_to(np.asarray(p.start), (rec.positions.shape[0], 1) + p.start.shape),
                          rec.positions], axis=1)                     # (runs, T + 1, n, 2)
    paths = []
    fig, ax = plt.subplots(figsize=(11, 4.2))
    xs = np.linspace(pos[0, :, :, 0].min() - 1000, pos[0, :, :, 0].max() + 1000, 2000)
    ax.plot(xs / 1e3, float(p.path_amplitude) * np.sin(xs / float(p.path_scale)) / 1e3, "k-", lw=0.8,
            label="reference path")
    for i in range(cfg.n_agents):
        ax.plot(pos[0, :, i, 0] / 1e3, pos[0, :, i, 1] / 1e3, "-", lw=1, label=f"UAV{i + 1}")
    c = pos[0].mean(axis=1)
    ax.plot(c[:, 0] / 1e3, c[:, 1] / 1e3, "--", color="gray", lw=1, label="centroid")
    ax.set_xlabel("x (km)")
    ax.set_ylabel("y (km)")
    ax.set_aspect("equal")
    ax.legend(fontsize=8, ncol=5, loc="upper right")
    ax.set_title("Seed 0: the formation joins the path and follows it (Chen & Lu 2013 Fig. 4)")
    fig.tight_layout()
    paths.append(out_dir / "paths.png")
    fig.savefig(paths[-1], dpi=120)
    plt.close(fig)

    dt = float(p.dt)
    T = rec.distances.shape[1]
    t = dt * np.arange(1, T + 1)
    ref = np.asarray(S.reference_distances(cfg, jnp.asarray(p.offsets)))
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for k, (i, j) in enumerate(S.pairs(cfg.n_agents)):
        d = rec.distances[:, :, k]
        line, = ax.plot(t, d[0], lw=1.2, label=f"UAV{i + 1}-UAV{j + 1} (seed 0)")
        ax.fill_between(t, np.percentile(d, 5, 0), np.percentile(d, 95, 0), color=line.get_color(), alpha=0.25)
        ax.axhline(ref[k], color=line.get_color(), ls=":", lw=0.8)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("distance (m)")
    ax.set_title(f"Pairwise distances; band: 5-95 % over {rec.distances.shape[0]} runs; dotted: the formation")
    ax.legend(fontsize=8)
    fig.tight_layout()
    paths.append(out_dir / "distances.png")
    fig.savefig(paths[-1], dpi=120)
    plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for k, axn in enumerate("xy"):
        ax = axes[k]
        ax.plot(t, rec.raw_error[0, :, k], color="0.6", lw=0.8, label="measured (unfiltered)")
        for f, name in enumerate(cfg.filters):
            ax.plot(t, rec.axis_error[0, :, f, k], lw=1.2, label=name)
        ax.set_xlabel("time (s)")
        ax.set_title(f"UAV{cfg.report_agent}, |wind error| along {axn}, seed 0")
    axes[0].set_ylabel("m/s")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    paths.append(out_dir / "wind_error.png")
    fig.savefig(paths[-1], dpi=120)
    plt.close(fig)
    return paths


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--config", type=Path, default=ROOT / "configs" / "chen2013.toml")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "chen2013_figures")
    args = ap.parse_args(argv)
    if args.runs < 2:
        ap.error(f"--runs must be >= 2; got {args.runs}")
    runs = run_records(args.config, args.runs)
    print(f"{args.runs} runs in {runs.seconds:.1f} s including compilation")
    for path in figures(runs.config, runs.params, runs.records, args.out):
        print(f"figure: {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
