"""Consensus filters against faults of the network: which degrades gracefully, and is bursty
link loss worse than i.i.d. loss at the same mean rate?

Runs the two sweeps ``sweeps/faults_sun2011.toml`` (Sun et al. 2011's closed loop: CIF, ICF,
modified ICF, KCF, local EKF) and ``sweeps/faults_ren2017.toml`` (Ren & Lv 2017: consensus
IMM-UKF, CV and CT consensus UKFs) — i.i.d. link loss 0 … 0.5, bursty loss (Gilbert–Elliott,
mean burst 5 steps) at the same rates, one or two agents lost at random times — and prints, per
point and filter, the divergence rate (Wilson 95 % interval) and the RMSE (mean with a 95 %
interval, and median), then bursty minus i.i.d. per seed (the same targets and measurement
noise: paired). Writes each sweep's dataset (``mcjax report OUT/<name>`` draws its plots) and
``OUT/faults.png``. Then times the closed loop of Sun et al. 2011 with the fault model off and
on, side by side in this process.

    python benchmarks/robustness/faults.py                    # 500 runs per point (~10 min on 2 cores)
    python benchmarks/robustness/faults.py --runs 50 --out /tmp/faults-quick
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

import numpy as np
import pandas as pd

from mcjax import configure
from mcjax.statistics import mean_ci, wilson_interval
from mcjax.study import build_spec, load_spec, prepare_output, run_sweep

configure()  # JAX's 64-bit mode and CPU devices, as the CLI sets them

ROOT = Path(__file__).resolve().parents[2]
SWEEPS = {"sun2011": "faults_sun2011.toml", "ren2017": "faults_ren2017.toml"}
RATES = (0.1, 0.2, 0.3, 0.5)


def point_labels(df: pd.DataFrame, n_agents: int) -> dict[int, str]:
    """A readable name per point: ``iid 0.2``, ``bursty 0.2``, ``1 lost`` …"""
    out = {}
    for pid, row in df.groupby("point_id").first().iterrows():
        if row.agent_loss_rate > 0:
            out[pid] = f"{n_agents - int(row.min_alive)} lost"
        else:
            out[pid] = f"{'bursty' if row.link_burst > 0 else 'iid'} {row.link_loss:g}"
    return out


def run(name: str, runs: int, out: Path) -> tuple[pd.DataFrame, float]:
    study = load_spec(ROOT / "sweeps" / SWEEPS[name], seeds=runs)
    folder = out / name
    shutil.rmtree(folder, ignore_errors=True)
    prepare_output(study, folder, spec_file=ROOT / "sweeps" / SWEEPS[name])
    t0 = time.perf_counter()
    df = run_sweep(study, folder)
    return df, time.perf_counter() - t0


def table(df: pd.DataFrame, labels: dict[int, str]) -> pd.DataFrame:
    rows = []
    for (pid, f), g in df.groupby(["point_id", "filter"], sort=False):
        k, n = int(g.diverged.sum()), len(g)
        div = wilson_interval(k, n)
        rm = mean_ci(g.rmse)
        rows.append(dict(point=labels[pid], filter=f, diverged=k / n, div_low=div.low, div_high=div.high,
                         rmse_mean=rm.mean, rmse_low=rm.low, rmse_high=rm.high, rmse_median=g.rmse.median(),
                         links_lost=g.links_lost.mean(), agents_lost=g.agents_lost.mean()))
    return pd.DataFrame(rows)


def paired(df: pd.DataFrame, labels: dict[int, str]) -> pd.DataFrame:
    """Bursty minus i.i.d. at each rate, per filter, paired by seed: divergence and RMSE."""
    by_label = {v: k for k, v in labels.items()}
    rows = []
    for rate in RATES:
        a, b = by_label.get(f"iid {rate:g}"), by_label.get(f"bursty {rate:g}")
        if a is None or b is None:
            continue
        for f, g in df.groupby("filter", sort=False):
            x = g[g.point_id == a].set_index("seed_index")
            y = g[g.point_id == b].set_index("seed_index").loc[x.index]
            d_div = mean_ci(y.diverged.astype(float) - x.diverged.astype(float))
            d_rmse = mean_ci(np.log(y.rmse) - np.log(x.rmse))
            rows.append(dict(rate=rate, filter=f, d_diverged=d_div.mean, d_div_low=d_div.low, d_div_high=d_div.high,
                             rmse_ratio=np.exp(d_rmse.mean), ratio_low=np.exp(d_rmse.low),
                             ratio_high=np.exp(d_rmse.high)))
    return pd.DataFrame(rows)


def plot(tables: dict[str, pd.DataFrame], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(tables), 2, figsize=(11, 4.2 * len(tables)), squeeze=False)
    for row, (name, t) in zip(axes, tables.items()):
        for i, f in enumerate(t["filter"].unique()):
            colour = f"C{i}"
            for kind, style in (("iid", "-o"), ("bursty", "--s")):
                s = t[(t["filter"] == f) & t.point.str.match(rf"^({kind} |iid 0$)")].copy()
                s["rate"] = s.point.str.split().str[1].astype(float)
                s = s.sort_values("rate")
                lab = f"{f} ({kind})"
                row[0].errorbar(s.rate, s.diverged, yerr=[s.diverged - s.div_low, s.div_high - s.diverged], fmt=style,
                                color=colour, label=lab, capsize=2, ms=4)
                row[1].plot(s.rate, s.rmse_median, style, color=colour, label=lab, ms=4)
        row[0].set(title=f"{name}: runs diverged (95 % Wilson)", xlabel="link loss rate", ylabel="fraction of runs")
        row[1].set(title=f"{name}: median RMSE", xlabel="link loss rate", ylabel="RMSE (m)", yscale="log")
        row[1].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def speed(runs: int, repeats: int = 3) -> dict[str, float]:
    """Seconds per run of Sun et al. 2011's default closed loop: the fault model off (no fault
    draws in the program), on with every rate 0, and on with faults drawn (link loss 0.2 in
    bursts of 5, agent loss 0.002 per UAV and step, sensor dropout 0.05) — each compiled first,
    then timed ``repeats`` times in turn; the best of each."""
    base = {"base": str(ROOT / "configs" / "sun2011.toml")}
    on = {"config": {"faults": "on"}}
    specs = {"off": build_spec(base, ROOT, seeds=runs),
             "on, rates 0": build_spec({**base, **on}, ROOT, seeds=runs),
             "on, faults drawn": build_spec({**base, **on, "params": {
                 "link_loss": 0.2, "link_burst": 5.0, "agent_loss_rate": 0.002, "sensor_dropout": 0.05}},
                 ROOT, seeds=runs)}
    for s in specs.values():
        run_sweep(s)  # compile (and warm up)
    times = {k: [] for k in specs}
    for _ in range(repeats):
        for k, s in specs.items():
            t0 = time.perf_counter()
            run_sweep(s)
            times[k].append((time.perf_counter() - t0) / runs)
    return {k: min(v) for k, v in times.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=500, help="runs per point (default 500)")
    ap.add_argument("--out", type=Path, default=Path("/tmp/mcjax-faults"), help="output folder")
    ap.add_argument("--only", choices=tuple(SWEEPS), help="run one sweep only")
    ap.add_argument("--speed-runs", type=int, default=300, help="runs per timing of the speed check (0: skip)")
    ap.add_argument("--speed-only", action="store_true", help="only the speed check")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    pd.set_option("display.width", 200)
    pd.set_option("display.max_rows", 200)
    tables = {}
    for name in () if args.speed_only else SWEEPS if args.only is None else (args.only,):
        df, wall = run(name, args.runs, args.out)
        n_agents = {"sun2011": 5, "ren2017": 6}[name]
        labels = point_labels(df, n_agents)
        t = table(df, labels)
        tables[name] = t
        print(f"\n== {name}: {df.point_id.nunique()} points x {args.runs} runs in {wall:.0f} s (compile included)")
        print(t.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
        print(f"\n-- {name}: bursty minus i.i.d. at the same rate, paired by seed (95 % intervals)")
        print(paired(df, labels).to_string(index=False, float_format=lambda v: f"{v:.4g}"))
        t.to_csv(args.out / f"{name}_table.csv", index=False)
    if tables:
        plot(tables, args.out / "faults.png")
        print(f"\nplot: {args.out / 'faults.png'}; datasets: {', '.join(str(args.out / n) for n in tables)}")
    if args.speed_runs:
        s = speed(args.speed_runs)
        print(f"\n== speed, Sun et al. 2011 closed loop, {args.speed_runs} runs, best of 3 (ms per run; ratio to off)")
        for k, v in s.items():
            print(f"   {k:18s} {1e3 * v:7.2f}   {v / s['off']:.3f}")


if __name__ == "__main__":
    main()
