"""The faults study's figure from a check of ``benchmarks/claims/faults.toml``: per filter, the
fraction of runs diverged (95 % Wilson interval) and the median RMSE against the link-loss rate,
i.i.d. (solid) and bursty (dashed, from the no-loss point), for Sun et al. 2011's closed loop and
Ren & Lv 2017's consensus IMM-UKF — one row of two panels per sweep. The points with lost agents
are not drawn (their verdicts are the check's).

The runs are the check's sweep folders ``CHECK/sun2011`` and ``CHECK/ren2017``
(:func:`mcjax.base.parquet.read_table`); run the check first::

    mcjax check benchmarks/claims/faults.toml                        # 500 runs per point (~10 min on 2 cores)
    python benchmarks/stress/faults_figure.py                    # results/check_faults/faults.png
    python benchmarks/stress/faults_figure.py --check /tmp/faults_check --out /tmp/faults.png

The fault model's cost: ``python benchmarks/speed/closed_loop.py faults``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from mcjax.analysis.statistics import wilson_interval
from mcjax.base.parquet import read_metadata, read_table

SWEEPS = ("sun2011", "ren2017")


def curves(rows: pd.DataFrame, filters: list[str]) -> pd.DataFrame:
    """Per filter, kind (``iid``, ``bursty``) and link-loss rate: the fraction of runs diverged with
    its Wilson interval and the median RMSE (the no-loss point starts both kinds' curves)."""
    rows = rows[rows["agent_loss_rate"] == 0]
    out = []
    for (f, rate, burst), g in rows.groupby(["filter", "link_loss", "link_burst"]):
        k, n = int(g["diverged"].sum()), len(g)
        div = wilson_interval(k, n)
        for kind in ("iid", "bursty") if rate == 0 else ("bursty" if burst > 0 else "iid",):
            out.append(dict(filter=f, kind=kind, rate=rate, diverged=k / n, div_low=div.low, div_high=div.high,
                            rmse_median=g["rmse"].median()))
    t = pd.DataFrame(out)
    order = {f: i for i, f in enumerate(filters)}
    return t.sort_values(["filter", "rate"], key=lambda c: c.map(order) if c.name == "filter" else c)


def plot(tables: dict[str, pd.DataFrame], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(tables), 2, figsize=(11, 4.2 * len(tables)), squeeze=False)
    for row, (name, t) in zip(axes, tables.items()):
        for i, f in enumerate(t["filter"].unique()):
            for kind, style in (("iid", "-o"), ("bursty", "--s")):
                s = t[(t["filter"] == f) & (t["kind"] == kind)]
                lab = f"{f} ({kind})"
                row[0].errorbar(s.rate, s.diverged, yerr=[s.diverged - s.div_low, s.div_high - s.diverged], fmt=style,
                                color=f"C{i}", label=lab, capsize=2, ms=4)
                row[1].plot(s.rate, s.rmse_median, style, color=f"C{i}", label=lab, ms=4)
        row[0].set(title=f"{name}: runs diverged (95 % Wilson)", xlabel="link loss rate", ylabel="fraction of runs")
        row[1].set(title=f"{name}: median RMSE", xlabel="link loss rate", ylabel="RMSE (m)", yscale="log")
        row[1].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", type=Path, default=Path("results/check_faults"),
                    help="the check's output folder (default: %(default)s)")
    ap.add_argument("--out", type=Path, help="the figure (default: CHECK/faults.png)")
    args = ap.parse_args()
    missing = [n for n in SWEEPS if not (args.check / n).is_dir()]
    if missing:
        raise SystemExit(f"{args.check}: no sweep folder {', '.join(missing)}; run mcjax check "
                         f"benchmarks/claims/faults.toml --out {args.check} first")
    tables = {n: curves(read_table(args.check / n), read_metadata(args.check / n)["filters"]) for n in SWEEPS}
    out = args.out or args.check / "faults.png"
    plot(tables, out)
    print(f"plot: {out} ({', '.join(f'{n}: {len(t)} curve points' for n, t in tables.items())})")


if __name__ == "__main__":
    main()
