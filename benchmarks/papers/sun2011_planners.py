"""Gradient vs sampled planners on the same receding-horizon problems (Sun et al. 2011, eq. 16).

Builds B planning problems of the Sun et al. 2011 team (the paper's UAV layout jittered by up to
±30 km, random headings, the target near its initial state, a leader posterior with
position std 20–300 m and velocity std 5–50 m/s), for case 1 (α_I = 0) and case 2 (α_I
from configs/sun2011.toml), all other weights from the config. Every planner solves the
same B problems from the same warm start (hold the headings) in one compiled, vmapped
call; the wall time is the second call's (compilation excluded, printed apart).

Printed per planner and budget: the mean *exact* cost reached, the mean gap to the best
cost any planner found on each problem (in % of the warm start's cost above that best),
how often it is within 0.1 % of the best, and the wall time per plan.

    python benchmarks/papers/sun2011_planners.py
    python benchmarks/papers/sun2011_planners.py --problems 500 --horizon 8
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mcjax import configure
from mcjax.scenarios.sun2011.horizon import Dynamics, Problem, horizon_cost, horizon_plan_cost
from mcjax.scenarios.sun2011.objectives import CostParams
from mcjax.study import load_config_file
from mcjax.tracking.planning import PlannerOptions, solve

configure()  # JAX's 64-bit mode and CPU devices, as the CLI sets them

ROOT = Path(__file__).resolve().parents[2]
BUDGETS = [("gradient", dict(iterations=k, learning_rate=r)) for k, r in ((5, .3), (10, .3), (20, .3), (40, .3),
                                                                         (3, 1.), (5, 1.))] + \
          [("random", dict(samples=s)) for s in (64, 256, 1024)] + \
          [("cem", dict(iterations=4, samples=s)) for s in (64, 256, 1024)]


def problems(n_problems: int, n_agents: int, seed: int = 0) -> Problem:
    rng = np.random.default_rng(seed)
    layout = np.array([[20, 150], [80, 150], [130, 200], [130, 100], [180, 150]])[:n_agents] * 1e3
    xy = layout + rng.uniform(-30e3, 30e3, (n_problems, n_agents, 2))
    uavs = np.concatenate([xy, np.full((n_problems, n_agents, 1), 800.0),
                           rng.uniform(-np.pi, np.pi, (n_problems, n_agents, 1))], -1)
    target = np.array([200e3, 200.0, 180e3, -1000.0]) + rng.normal(0, 1, (n_problems, 4)) * [20e3, 50, 20e3, 50]
    pos_sd = rng.uniform(20, 300, (n_problems, 2))
    vel_sd = rng.uniform(5, 50, (n_problems, 2))
    var = np.stack([pos_sd[:, 0], vel_sd[:, 0], pos_sd[:, 1], vel_sd[:, 1]], -1) ** 2
    Y = np.einsum("bi,ij->bij", 1.0 / var, np.eye(4))
    return Problem(jnp.asarray(uavs), jnp.asarray(target), jnp.asarray(Y))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--problems", type=int, default=200, help="planning problems per case")
    ap.add_argument("--horizon", type=int, default=5, help="t_r (paper: 5)")
    ap.add_argument("--config", type=Path, default=ROOT / "configs" / "sun2011.toml")
    args = ap.parse_args(argv)
    jax.config.update("jax_enable_x64", True)

    _, cfg, p = load_config_file(args.config)
    n, H = cfg.n_agents, max(cfg.max_horizon, args.horizon)
    probs = problems(args.problems, n)
    dyn = Dynamics(1.0, p.get("alpha_phi", 1.0), p.get("turn_rate_max", np.deg2rad(10.0)), args.horizon,
                   p.get("sigma_accel", 50.0))
    warm = jnp.zeros((args.problems, H, n))
    keys = jax.random.split(jax.random.PRNGKey(1), args.problems)
    print(f"{args.problems} problems per case, {n} UAVs, t_r = {args.horizon}, float64, "
          f"{jax.device_count()} CPU device(s)\n")
    for case, alpha_I in (("case 1 (α_I = 0)", 0.0), ("case 2", p["alpha_I"])):
        cost = CostParams(alpha_I, p["alpha_C"], p["alpha_L"], p["alpha_S"], p["d_safe"], p["d_lt"],
                          p["robustness_scale"], p["plan_temperature"], jnp.full(n, p.get("sensing_radius", 120e3)),
                          jnp.full(n, p.get("comm_radius", 100e3)), p.get("sigma_range", 10.0),
                          p.get("sigma_bearing", 0.017), jnp.ones(n))
        warm_cost = jax.jit(jax.vmap(lambda q, u: horizon_cost(q, u, dyn, cost, penalty=cfg.robustness_penalty)))(
            probs, warm)
        results = []
        for kind, budget in BUDGETS:
            opts = PlannerOptions(kind=kind, **{"learning_rate": cfg.plan_learning_rate, **budget})
            fn = jax.jit(jax.vmap(lambda q, w, k: solve(
                horizon_plan_cost(q, dyn, cost, penalty=cfg.robustness_penalty), w, k, opts)))
            t0 = time.perf_counter()
            jax.block_until_ready(fn(probs, warm, keys))
            first = time.perf_counter() - t0
            t0 = time.perf_counter()
            plan = jax.block_until_ready(fn(probs, warm, keys))
            wall = time.perf_counter() - t0
            label = f"{kind} " + ", ".join(f"{k}={v}" for k, v in budget.items())
            results.append((label, np.asarray(plan.cost), wall, first - wall))
        best = np.min(np.stack([c for _, c, _, _ in results]), 0)
        span = np.maximum(np.asarray(warm_cost) - best, 1e-12)
        print(f"## {case}: warm-start (hold heading) mean cost {float(np.mean(warm_cost)):.1f}\n")
        print("| planner, budget | mean exact cost | mean gap to best, % of (warm − best) | within 0.1 % of best | "
              "ms / plan | compile s |")
        print("|---|---|---|---|---|---|")
        for label, c, wall, comp in results:
            gap = 100 * np.mean((c - best) / span)
            near = 100 * np.mean(c - best <= 1e-3 * np.abs(best))
            print(f"| {label} | {np.mean(c):.2f} | {gap:.1f} | {near:.0f} % | "
                  f"{wall / args.problems * 1e3:.2f} | {comp:.1f} |")
        print()


if __name__ == "__main__":
    main()
