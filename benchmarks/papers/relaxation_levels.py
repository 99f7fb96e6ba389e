"""How the smooth system approaches the exact one as its temperatures shrink, in each built-in
scenario (issue 34: "as temperatures shrink (3 levels), the smooth system's summary approaches
the exact one's").

For each paper's config, the same runs (the same keys) are simulated exactly and with the
scenario's relaxation switch at its default temperatures times 1, 0.1 and 0.01. Printed per
scenario and level: the mean of the error output (``rmse`` or the scenario's own) of the exact
and the smooth system and their gap, relative to the exact mean, for every filter; and the
mean over runs of the per-run absolute difference, and the 95 % t-interval of the paired
difference smooth − exact (is a gap of the means resolved by the runs?). The figure (``--figure``) draws the largest
relative gap of the means against the level, one line per scenario.

    python benchmarks/papers/relaxation_levels.py --runs 50 --figure docs/relaxation_levels.png

The temperatures are passed to one compiled program as arrays (one compilation per scenario for
the three levels; the exact program is a second one).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = ("sun2011", "ren2017", "chen2013", "lou2013", "chen2022")
LEVELS = (1.0, 0.1, 0.01)


def measure(name: str, runs: int, steps: int | None) -> list[dict]:
    import jax
    import jax.numpy as jnp

    from mcjax import engine, runtime
    from mcjax.analysis.statistics import mean_ci
    from mcjax.study import load_config_file

    runtime.configure()
    scenario, cfg, params = load_config_file(ROOT / "configs" / f"{name}.toml")
    if steps is not None and steps < cfg.n_steps:
        import dataclasses

        cfg = dataclasses.replace(cfg, n_steps=steps, warmup_steps=min(cfg.warmup_steps, steps // 4))
    base = scenario.default_params(cfg, **params)
    P = jax.tree.map(lambda a: np.repeat(np.asarray(a)[None], runs, 0), base)
    keys = engine.run_keys(0, np.arange(runs))
    error = next(k for k, o in scenario.outputs(cfg).items() if o.role == "error")
    Temperatures = scenario.relaxation.Temperatures
    default = np.asarray(Temperatures(), np.float64)
    t0 = time.perf_counter()
    exact = np.asarray(jax.jit(lambda: engine.simulate(scenario, cfg, P, keys)[error])())
    smooth = jax.jit(lambda s: engine.simulate(scenario, cfg, P, keys, temperatures=s)[error])
    rows = []
    for level in LEVELS:
        s = Temperatures(*(jnp.asarray(v * level) for v in default))
        got = np.asarray(smooth(s))
        for f, filt in enumerate(cfg.filters):
            e, g = exact[:, f], got[:, f]
            ok = np.isfinite(e) & np.isfinite(g)
            d = mean_ci(g[ok] - e[ok])  # paired by run
            rows.append({"scenario": name, "level": level, "filter": filt, "exact_mean": float(e[ok].mean()),
                         "smooth_mean": float(g[ok].mean()), "paired_ci_low": d.low, "paired_ci_high": d.high,
                         "relative_gap": float(abs(g[ok].mean() - e[ok].mean()) / abs(e[ok].mean())),
                         "mean_abs_difference": float(np.abs(g[ok] - e[ok]).mean()), "runs": int(ok.sum())})
    print(f"{name}: {cfg.n_steps} steps x {runs} runs, {time.perf_counter() - t0:.0f} s "
          f"(temperatures: {dict(zip(Temperatures._fields, default))})", flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--steps", type=int, default=None, help="cut every config to this many steps")
    ap.add_argument("--configs", default=",".join(CONFIGS))
    ap.add_argument("--figure", type=Path, default=None)
    a = ap.parse_args()
    import pandas as pd

    rows = []
    for name in a.configs.split(","):
        rows += measure(name, a.runs, a.steps)
    df = pd.DataFrame(rows)
    with pd.option_context("display.width", 200, "display.max_rows", 200):
        print(df.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    if a.figure is not None:
        from matplotlib.figure import Figure

        fig = Figure(figsize=(6.4, 4.2), layout="constrained")
        ax = fig.subplots()
        for name, g in df.groupby("scenario", sort=False):
            worst = g.groupby("level")["relative_gap"].max()
            ax.plot(worst.index, np.maximum(worst.values, 1e-12), marker="o", label=name)
        ax.axhline(1e-12, color="0.5", lw=0.8, ls=":")
        ax.annotate("a gap of 0 (equal to the last bit) is drawn here", (1.0, 1e-12), xytext=(0, 4),
                    textcoords="offset points", fontsize="x-small", color="0.4")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.invert_xaxis()
        ax.set_xlabel("temperatures / the scenario's defaults")
        ax.set_ylabel("|mean error smooth − exact| / exact\n(largest over filters)")
        ax.set_title(f"The smooth system approaches the exact one ({a.runs} runs each, same keys)", fontsize="medium")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize="small")
        fig.savefig(a.figure, dpi=150)
        print(f"figure: {a.figure}")


if __name__ == "__main__":
    main()
