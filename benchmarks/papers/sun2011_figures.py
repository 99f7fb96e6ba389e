"""The figures of Sun et al. 2011 (Figs. 4–11) for one seed of each case of Table 1: the UAVs' paths
(markers every 40 s), the algebraic connectivity λ2 and each UAV's degree over time, and the position
error of each UAV's estimate for the ICF, the modified ICF and the CIF. Case 1 ignores the connectivity
robustness (α_I = 0), case 2 weights it (the config's α_I). Table 1 and the paper's claims are checked by
`mcjax check benchmarks/claims/sun2011.toml`.

    python benchmarks/papers/sun2011_figures.py              # seed 0 -> results/sun2011_figures/
    python benchmarks/papers/sun2011_figures.py --seed 7 --out /tmp/figs

Writes case1_paths.png, case1_connectivity.png, case1_errors.png and the same for case 2.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import numpy as np

from records import run_records

ROOT = Path(__file__).resolve().parents[2]
FILTERS = ("icf", "modified_icf", "cif")
LABELS = {"icf": "ICF [4]-[5]", "modified_icf": "modified ICF", "cif": "CIF"}
CASES = {"case1": 0.0, "case2": None}   # alpha_I: 0, and the config's


def figures(config: Path, seed: int, out_dir: Path) -> list[Path]:
    """Fig. 4–11 of the paper for one seed of each case: paths, λ2 & degrees, filter errors."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    for case, alpha in CASES.items():
        runs = run_records(config, 1, config_over={"filters": FILTERS}, first=seed,
                           params_over={} if alpha is None else {"alpha_I": alpha})
        cfg, p = runs.config, runs.params
        rec = jax.tree.map(lambda a: a[0], runs.records)
        t = np.arange(rec.lambda2.shape[0]) * float(p.dt)
        title = {"case1": "case 1: robustness ignored (α_I = 0)", "case2": "case 2: robustness weighted"}[case]

        fig, ax = plt.subplots(figsize=(6.5, 6))
        for i in range(rec.positions.shape[1]):
            ax.plot(rec.positions[:, i, 0] / 1e3, rec.positions[:, i, 1] / 1e3,
                    label="leader" if i == 0 else f"UAV{i}")
            ax.plot(rec.positions[::40, i, 0] / 1e3, rec.positions[::40, i, 1] / 1e3, "k.", ms=4)
        ax.plot(rec.target[:, 0] / 1e3, rec.target[:, 2] / 1e3, "k--", label="target")
        ax.plot(rec.target[::40, 0] / 1e3, rec.target[::40, 2] / 1e3, "k^", ms=5)
        ax.set(xlabel="x, km", ylabel="y, km", title=f"Paths (markers every 40 s) — {title}")
        ax.set_aspect("equal", "datalim")
        ax.legend(fontsize=8)
        paths.append(out_dir / f"{case}_paths.png")
        fig.savefig(paths[-1], dpi=110, bbox_inches="tight")
        plt.close(fig)

        fig, (a1, a2) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
        a1.plot(t, rec.lambda2)
        a1.set(ylabel="λ2 of the comm Laplacian", title=f"Algebraic connectivity and degrees — {title}")
        for i in range(rec.degrees.shape[1]):
            a2.plot(t, rec.degrees[:, i], label="leader" if i == 0 else f"UAV{i}")
        a2.set(xlabel="t, s", ylabel="degree")
        a2.legend(fontsize=8, ncol=5)
        paths.append(out_dir / f"{case}_connectivity.png")
        fig.savefig(paths[-1], dpi=110, bbox_inches="tight")
        plt.close(fig)

        fig, axes = plt.subplots(len(FILTERS), 1, figsize=(7, 8), sharex=True)
        for ax, name in zip(axes, FILTERS):
            f = cfg.filters.index(name)
            for i in range(rec.error.shape[2]):
                ax.semilogy(t, np.maximum(rec.error[:, f, i], 1e-1), label="leader" if i == 0 else f"UAV{i}")
            ax.set(ylabel="error, m", title=LABELS[name])
        axes[0].legend(fontsize=8, ncol=5)
        axes[-1].set(xlabel="t, s")
        fig.suptitle(f"Position error of each UAV's estimate — {title}")
        paths.append(out_dir / f"{case}_errors.png")
        fig.savefig(paths[-1], dpi=110, bbox_inches="tight")
        plt.close(fig)
    return paths


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", type=Path, default=ROOT / "configs" / "sun2011.toml")
    ap.add_argument("--seed", type=int, default=0, help="the run drawn (its seed index, base seed 0)")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "sun2011_figures")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    for path in figures(args.config, args.seed, args.out):
        print(f"figure: {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
