"""Divergence statistics of Sun et al. 2011 Table 1, closed loop, over N runs.

Case 1 ignores the connectivity robustness (α_I = 0); case 2 weights it (α_I from
``configs/sun2011.toml``). Each case runs N seeds (default 1,000; the paper ran 20) with
each planner (gradient = optax Adam on the smoothed cost, cem = sampled search). Prints,
beside the paper's numbers: divergence count, mean position error of ICF / modified ICF /
CIF over all runs and over non-divergent runs, min λ2, disconnected steps and wall time
(per run, and for the whole N-run batch including compilation). Writes every run to
``OUT/runs/`` (one Parquet part) and, for seed 0 of each case, PNG figures like the paper's Fig. 4–11
(paths, λ2 and degrees over time, error curves of the three filters).

    python benchmarks/divergence_sun2011.py                       # 1,000 runs, both planners
    python benchmarks/divergence_sun2011.py --runs 20 --planners gradient
    python benchmarks/divergence_sun2011.py --runs 10000 --planners gradient --cases case2 \
        --icf-variants priors --no-figures       # the 10,000-run speed target

Both readings of the ICF run side by side (the config's, "priors" — the ICF as the paper ran
it —, then "contributions"). The leader plans from the modified ICF, so the closed loop does not
depend on the reading; the two compiled programs round differently in the last bits, which the
closed loop amplifies in single runs, so what is checked is that the modified ICF's divergence
count and mean error agree; the table's modified-ICF and CIF columns are the first reading's.

A run *diverges* (our rule; the paper gives none) when the filter's position error of some
UAV exceeds ``divergence_threshold`` (1 km) after the 10-step warm-up. The headline count is
the modified ICF's (the paper's filter); the other filters' counts are printed too.
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
FILTERS = ("icf", "modified_icf", "cif")
LABELS = {"icf": "ICF [4]-[5]", "modified_icf": "modified ICF", "cif": "CIF"}
#: Sun et al. 2011 Table 1 (20 MATLAB runs per case).
PAPER = {
    "case1": dict(run_time=20.8, divergences=16, icf=82.8, modified_icf=34.5, cif=11.1),
    "case2": dict(run_time=22.6, divergences=0, icf=39.7, modified_icf=9.8, cif=8.5),
}


def setup(config: Path, planner: str, icf_variant: str | None = None, filters=FILTERS):
    scenario, cfg, params = load_config_file(config)
    cfg = dataclasses.replace(cfg, filters=filters, planner=planner, icf_variant=icf_variant or cfg.icf_variant)
    return scenario, cfg, params


def case_params(scenario, cfg, params: dict, case: str):
    values = dict(params)
    if case == "case1":
        values["alpha_I"] = 0.0
    return scenario.default_params(cfg, **values)


def run_case(scenario, cfg, p, runs: int, base_seed: int):
    """All runs of one case; returns (summary dict of arrays, wall seconds incl. compile)."""
    point = engine.stack_points([p])
    t0 = time.perf_counter()
    outs = [o for _, _, _, o in engine.run_chunks(scenario, cfg, point, runs, base_seed=base_seed,
                                                  chunk_size=max(runs, 1))]
    wall = time.perf_counter() - t0
    out = {k: np.concatenate([o[k] for o in outs]) for k in outs[0]}
    return out, wall


def rows(scenario, cfg, out: dict, case: str, planner: str) -> pd.DataFrame:
    n = len(out["lambda2_min"])
    return run_rows(scenario, cfg, out, {"case": case, "planner": planner, "icf_variant": cfg.icf_variant,
                                         "seed_index": np.arange(n)})


def table(df: pd.DataFrame, walls: dict, variants: list[str]) -> str:
    """Table 1 beside the paper's, one line per case, planner and reading of the ICF. The
    closed loop does not depend on the ICF's reading, so the modified ICF and CIF columns of
    every reading come from the first one's runs (their equality is checked in main)."""
    head = ("| case | planner | ICF reading | runs | divergences (mod. ICF) | div. ICF / CIF | mean error ICF / "
            "mod. ICF / CIF, m (all runs) | same, non-divergent runs | min λ2 (mean over runs) | disconnected steps | "
            "wall s/run | wall N runs incl. compile, s |")
    lines = [head, "|" + "---|" * 12]
    for (case, planner), g in df.groupby(["case", "planner"], sort=True):
        base = g[g["icf_variant"] == variants[0]]
        by = {f: base[base["filter"] == f].sort_values("seed_index") for f in FILTERS}
        div = by["modified_icf"]["diverged"].to_numpy().astype(bool)
        ok = ~div
        lam = by["cif"]
        for v in variants:
            icf = g[(g["icf_variant"] == v) & (g["filter"] == "icf")].sort_values("seed_index")
            cols = {**by, "icf": icf}
            err_all = " / ".join(f"{cols[f]['mean_error'].mean():.1f}" for f in FILTERS)
            err_ok = " / ".join(f"{cols[f]['mean_error'].to_numpy()[ok].mean():.1f}" if ok.any() else "–"
                                for f in FILTERS)
            wall = walls[(case, planner, v)]
            lines.append(f"| {case} | {planner} | {v} | {len(div)} | {div.sum()} | {int(icf['diverged'].sum())} / "
                         f"{int(by['cif']['diverged'].sum())} | {err_all} | {err_ok} | "
                         f"{lam['lambda2_min'].mean():.3f} | {lam['disconnected_steps'].mean():.1f} | "
                         f"{wall / len(div):.3f} | {wall:.0f} |")
    for case, p in PAPER.items():
        lines.append(f"| {case} | paper (MATLAB) | – | 20 | {p['divergences']} | – | {p['icf']} / "
                     f"{p['modified_icf']} / {p['cif']} | – | – | – | {p['run_time']} | – |")
    return "\n".join(lines)


def checks(df: pd.DataFrame, variant: str) -> list[tuple[str, bool]]:
    """The qualitative claims of Sun et al. 2011 Table 1, per planner, with the ICF read as
    ``variant`` (the config's), plus the paper's ICF result in case 2: no divergence."""
    res = []
    df = df[df["icf_variant"] == variant]
    for planner, g in df.groupby("planner"):
        m = g.groupby(["case", "filter"])
        div = m["diverged"].sum().unstack()["modified_icf"]
        err = m["mean_error"].mean().unstack()
        lam = g[g["filter"] == "cif"].groupby("case")["lambda2_min"].mean()
        both = {"case1", "case2"} <= set(div.index)
        if both:  # the comparisons of the two cases
            res += [
                (f"{planner}: case 2 diverges less often than case 1 ({div['case2']} < {div['case1']})",
                 div["case2"] < div["case1"]),
                (f"{planner}: case 2 keeps min λ2 higher ({lam['case2']:.3f} > {lam['case1']:.3f})",
                 lam["case2"] > lam["case1"]),
            ]
        res += [
            (f"{planner}: modified ICF more accurate than ICF in {'both cases' if both else 'the case run'}",
             bool((err["modified_icf"] < err["icf"]).all())),
            (f"{planner}: CIF the most accurate in {'both cases' if both else 'the case run'}",
             bool(((err["cif"] < err["icf"]) & (err["cif"] < err["modified_icf"])).all())),
        ]
        if "case2" in div.index:
            icf_div = m["diverged"].sum()[("case2", "icf")]
            res.append((f"{planner}: the ICF ({variant}) diverges in no case-2 run ({icf_div})", icf_div == 0))
    return res


def figures(scenario, cfg, p_by_case: dict, out_dir: Path) -> list[Path]:
    """Fig. 4–11 of the paper for seed 0 of each case: paths, λ2 & degrees, filter errors."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    fn = engine.compiled(scenario, cfg, records=True)
    for case, p in p_by_case.items():
        params, keys = engine.chunk_inputs(engine.stack_points([p]), 1, 0, 0, 1, 1)
        rec = jax.tree.map(lambda a: np.asarray(a)[0], fn(params, keys))
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
    ap.add_argument("--runs", type=int, default=1000, help="runs per case and planner (paper: 20)")
    ap.add_argument("--planners", nargs="+", default=["gradient", "cem"], choices=["gradient", "cem", "random"])
    ap.add_argument("--config", type=Path, default=ROOT / "configs" / "sun2011.toml")
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "divergence_sun2011")
    ap.add_argument("--base-seed", type=int, default=0)
    ap.add_argument("--no-figures", action="store_true")
    ap.add_argument("--cases", nargs="+", default=["case1", "case2"], choices=["case1", "case2"],
                    help="Table 1 cases to run (case 1: alpha_I = 0; case 2: the config's alpha_I)")
    ap.add_argument("--icf-variants", nargs="+", default=None, choices=["priors", "contributions"],
                    help="readings of the ICF to run side by side (default: the config's, then the other); the "
                         "first one's runs give the modified ICF / CIF columns and the checks")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    variants = args.icf_variants or [load_config_file(args.config)[1].icf_variant]
    if args.icf_variants is None:
        variants += [v for v in ("priors", "contributions") if v not in variants]

    frames, walls = [], {}
    for planner in args.planners:
        for v in variants:
            scenario, cfg, params = setup(args.config, planner, v)
            first_cfg = cfg if v == variants[0] else first_cfg
            p_by_case = {c: case_params(scenario, cfg, params, c) for c in args.cases}
            for case, p in p_by_case.items():
                out, wall = run_case(scenario, cfg, p, args.runs, args.base_seed)
                walls[(case, planner, v)] = wall
                print(f"{case} / {planner} / ICF {v}: {args.runs} runs x {cfg.n_steps} steps in {wall:.1f} s "
                      f"including compilation ({wall / args.runs * 1e3:.0f} ms/run)", flush=True)
                frames.append(rows(scenario, cfg, out, case, planner))
            if planner == args.planners[0] and v == variants[0] and not args.no_figures:
                for path in figures(scenario, cfg, p_by_case, args.out):
                    print(f"figure: {path}")
    df = pd.concat(frames, ignore_index=True)
    mod = df[df["filter"] == "modified_icf"].set_index(["case", "planner", "seed_index", "icf_variant"])["rmse"]
    # The readings compile to different programs, which round differently in the last bits, and
    # the closed loop amplifies that: single runs drift apart (up to 5.5 % in RMSE over 1,000
    # runs, measured 2026-12-01), while the statistics agree: same divergence count, mean error
    # within 0.1 %.
    base = df[(df["filter"] == "modified_icf") & (df["icf_variant"] == variants[0])]
    stats0 = base.groupby(["case", "planner"]).agg(div=("diverged", "sum"), err=("mean_error", "mean"))
    gap, same = 0.0, True
    for v in variants[1:]:
        other = df[(df["filter"] == "modified_icf") & (df["icf_variant"] == v)]
        stats = other.groupby(["case", "planner"]).agg(div=("diverged", "sum"), err=("mean_error", "mean"))
        same &= bool((stats["div"] == stats0["div"]).all() and np.allclose(stats["err"], stats0["err"], rtol=1e-3))
        gap = max(gap, float(np.nanmax(np.abs(mod.xs(v, level="icf_variant").to_numpy()
                                              / mod.xs(variants[0], level="icf_variant").to_numpy() - 1.0))))
    print(f"modified ICF under every ICF reading: same divergence counts and mean errors within 0.1 %: {same}; "
          f"largest per-run relative RMSE difference {gap:.1e}")
    meta = {**scenario.metadata(first_cfg), "benchmark": "divergence_sun2011", "config": str(args.config), "runs": args.runs,
            "walls_s": {"/".join(k): w for k, w in walls.items()}, **environment_metadata()}
    path = write_part(args.out, "runs", df, "part-000000", meta)
    print(f"runs: {path} ({len(df)} rows; read back with pandas.read_parquet(\"{args.out / 'runs'}\"))\n")
    print(table(df, walls, variants))
    print()
    failed = 0
    for text, ok in [*checks(df, variants[0]), ("the closed loop's statistics do not depend on the ICF's reading", same)]:
        print(("holds   " if ok else "FAILS   ") + text)
        failed += not ok
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
