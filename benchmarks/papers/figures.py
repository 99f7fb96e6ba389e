"""The papers' figures that need every step of every run (each paper's claims are checked by
``mcjax check benchmarks/claims/NAME.toml``; Lou et al. 2013 and Chen & Hao 2022 draw theirs with
their diagnostics, ``lou2013_figures.py`` and ``chen2022_diagnostics.py``):

* ``sun2011`` — Sun et al. 2011 Figs. 4–11 for one seed of each case of Table 1 (case 1: α_I = 0;
  case 2: the config's α_I): ``case1_paths.png``, ``case1_connectivity.png`` (λ2 and degrees),
  ``case1_errors.png``, and the same for case 2;
* ``ren2017`` — Ren & Lv 2017 Figs. 2–5 over N runs: ``errors_over_time.png``,
  ``mode_probability.png``, ``geometry.png`` (``--schedule markov``: modes from the Markov chain);
* ``chen2013`` — Chen & Lu 2013 Figs. 4–6 over N runs: ``paths.png``, ``distances.png``,
  ``wind_error.png``.

    python benchmarks/papers/figures.py sun2011                  # seed 0 -> results/figures_sun2011/
    python benchmarks/papers/figures.py ren2017 --runs 1000
    python benchmarks/papers/figures.py chen2013 --out /tmp/figs

Every paper's runs are set up one way, :func:`run_records`: the config file with overrides, its
runs' per-step records kept (``engine.run_chunks(records=True)``).
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import matplotlib
import numpy as np

from mcjax import configure, engine
from mcjax.scenarios import chen2013 as S
from mcjax.study import load_config_file

configure()  # JAX's 64-bit mode and CPU devices, as the CLI sets them
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after the non-interactive backend)

ROOT = Path(__file__).resolve().parents[2]
SUN_FILTERS = ("icf", "modified_icf", "cif")
SUN_LABELS = {"icf": "ICF [4]-[5]", "modified_icf": "modified ICF", "cif": "CIF"}
CASES = {"case1": 0.0, "case2": None}   # alpha_I: 0, and the config's
REN_FILTERS = ("imm", "cv", "ct")
REN_LABELS = {"imm": "consensus IMM-UKF", "cv": "CV only", "ct": "CT only"}


class Runs(NamedTuple):
    """The scenario, Config and Params of the point, every run's records (numpy, run axis first)
    and the wall time including compilation."""

    scenario: Any
    config: Any
    params: Any
    records: Any
    seconds: float


def run_records(config: str | Path, runs: int, *, config_over: dict | None = None, params_over: dict | None = None,
                base_seed: int = 0, first: int = 0, series: bool = False) -> Runs:
    """``runs`` seeds of the config file's point — seed indices ``first``, ``first + 1``, … of
    ``base_seed``, the runs a sweep of that base seed draws — with ``config_over`` / ``params_over``
    over its values, keeping every step's records (``series``: the per-run outputs and the
    scenario's per-step series instead, as ``(outputs, series)``), with a progress bar."""
    from tqdm import tqdm

    scenario, cfg, values = load_config_file(config)
    cfg = dataclasses.replace(cfg, **(config_over or {}))
    p = scenario.default_params(cfg, **{**values, **(params_over or {})})
    # the batch-aligned chunks that hold seeds first … first + runs − 1 (the runs before them in a chunk are cut)
    plan = engine.chunk_plan(first + runs, engine.BATCH_SIZE)
    chunks = [i for i, (a, b) in enumerate(plan) if b > first]
    t0, parts = time.perf_counter(), []
    with tqdm(total=runs, unit="run", disable=None) as bar:
        for _, start, stop, out in engine.run_chunks(
                scenario, cfg, engine.stack_points([p]), first + runs, base_seed=base_seed,
                chunk_size=engine.BATCH_SIZE, chunks=chunks, **({"timeseries": True} if series else {"records": True})):
            parts.append(out)
            bar.update(stop - max(start, first))
    records = jax.tree.map(lambda *xs: np.concatenate([np.asarray(x) for x in xs])[first - plan[chunks[0]][0]:],
                           *parts)
    return Runs(scenario, cfg, p, records, time.perf_counter() - t0)


def sun2011(config: Path, runs: int, seed: int, out_dir: Path) -> list[Path]:
    """Sun et al. 2011 Figs. 4–11 for one seed (``seed``; ``runs`` unused) of each case of Table 1: the
    UAVs' paths (markers every 40 s), λ2 and each UAV's degree, each UAV's error for the three filters."""
    paths = []
    for case, alpha in CASES.items():
        r = run_records(config, 1, config_over={"filters": SUN_FILTERS}, first=seed,
                           params_over={} if alpha is None else {"alpha_I": alpha})
        cfg, p = r.config, r.params
        rec = jax.tree.map(lambda a: a[0], r.records)
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

        fig, axes = plt.subplots(len(SUN_FILTERS), 1, figsize=(7, 8), sharex=True)
        for ax, name in zip(axes, SUN_FILTERS):
            f = cfg.filters.index(name)
            for i in range(rec.error.shape[2]):
                ax.semilogy(t, np.maximum(rec.error[:, f, i], 1e-1), label="leader" if i == 0 else f"UAV{i}")
            ax.set(ylabel="error, m", title=SUN_LABELS[name])
        axes[0].legend(fontsize=8, ncol=5)
        axes[-1].set(xlabel="t, s")
        fig.suptitle(f"Position error of each UAV's estimate — {title}")
        paths.append(out_dir / f"{case}_errors.png")
        fig.savefig(paths[-1], dpi=110, bbox_inches="tight")
        plt.close(fig)
    return paths


def ren2017(config: Path, runs: int, seed: int, out_dir: Path, schedule: str | None = None) -> list[Path]:
    """Ren & Lv 2017 Figs. 2–5 over ``runs`` runs: each UUV's error over time (mean over runs) for the
    consensus IMM-UKF and the CV-only and CT-only consensus UKFs, the IMM's CT probability against
    the true mode, and one run's geometry (the UUVs, their comm links, the target's path)."""
    r = run_records(config, runs, config_over={"filters": REN_FILTERS, **({"schedule": schedule} if schedule else {})})
    cfg, p, records = r.config, r.params, r.records

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
        for f, name in enumerate(REN_FILTERS):
            ax.plot(t, mean_err[:, f, i], label=REN_LABELS[name])
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


def chen2013(config: Path, runs: int, seed: int, out_dir: Path) -> list[Path]:
    """Chen & Lu 2013 Figs. 4–6 over ``runs`` runs: seed 0's paths along the reference path with the
    formation's centroid, the pairwise distances over time (seed 0, and the 5–95 % band over the
    runs, against the formation's), and UAV2's wind error along x and y for each filter beside the
    unfiltered measurement."""
    r = run_records(config, runs)
    cfg, p, rec = r.config, r.params, r.records
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


PAPERS = {"sun2011": (sun2011, "sun2011.toml", 1), "ren2017": (ren2017, "ren2017.toml", 1000),
          "chen2013": (chen2013, "chen2013.toml", 1000)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("paper", choices=list(PAPERS))
    ap.add_argument("--runs", type=int, default=None, help="runs drawn (default: 1 for sun2011, else 1,000)")
    ap.add_argument("--seed", type=int, default=0, help="sun2011: the run drawn (its seed index, base seed 0)")
    ap.add_argument("--schedule", choices=["fixed", "markov"], default=None, help="ren2017: the target's modes")
    ap.add_argument("--config", type=Path, default=None, help="default: the paper's config in configs/")
    ap.add_argument("--out", type=Path, default=None, help="default: results/figures_PAPER/")
    args = ap.parse_args(argv)
    draw, config, runs = PAPERS[args.paper]
    runs = runs if args.runs is None else args.runs
    if runs < (2 if args.paper == "chen2013" else 1):
        ap.error(f"--runs must be at least {2 if args.paper == 'chen2013' else 1}; got {runs}")
    out = args.out or ROOT / "results" / f"figures_{args.paper}"
    out.mkdir(parents=True, exist_ok=True)
    extra = {"schedule": args.schedule} if args.paper == "ren2017" else {}
    t0 = time.perf_counter()
    for path in draw(args.config or ROOT / "configs" / config, runs, args.seed, out, **extra):
        print(f"figure: {path}")
    print(f"{time.perf_counter() - t0:.1f} s including compilation")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
