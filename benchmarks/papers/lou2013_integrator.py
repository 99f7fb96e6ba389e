"""The flock's integrator (Lou, Cui & Li 2013, issue 37): accuracy of one 0.1 s step against a
DOP853 reference, and cost per run, for the RK4 sub-steps used before, the hand-written
Dormand–Prince 5(4) pair of ``mcjax.scenarios.lou2013.dynamics.dopri5_adaptive`` and diffrax's
``Dopri5`` with its PID step-size controller, each at the config's tolerance and 100× tighter.

What is run.

1. States. ``--runs`` (10) runs of ``configs/lou2013.toml`` (its integrator: the hand-written
   pair at its tolerance), 300 steps each, through the scenario's ``init`` and ``step`` (the
   engine's keys). From each run: steps 0–19 (the transient: the flock contracts, pairs close at
   ~10 m/s) and 30 steps evenly spaced over 20–299 (steady flight): 500 states by default. For a
   state k the step's inputs are the flock at k, the graph at k and the type-I nodes' reference
   (their KCF estimate after step k's update, extrapolated at constant velocity, as the step
   does); re-integrating with the config's integrator gives the flock at k + 1 again (checked).
2. Reference. scipy's ``solve_ivp(method="DOP853", rtol=1e-11, atol=1e-12)`` of the same
   right-hand side (eqs. 1, 11, 13: ``dynamics.derivative``) over the 0.1 s step from each
   state.
3. Accuracy. Each integrator over the same step from every state (vmapped over the states):
   the largest error in position (m), velocity (m/s) and gain b_ij (1/s) over all states,
   transient and steady apart, and the sub-steps (attempts) per step.
4. Cost per run. ``--cost-runs`` (100) runs × 300 steps of the whole scenario (filters, graph,
   energy) per integrator: one program each (``jit(vmap(scan(step)))``, compiled ahead of
   time and excluded), timed on one call. diffrax is put in the scenario's place of the
   hand-written pair for its own program. Every lane of a ``vmap``-ped while loop runs to the
   slowest lane: the cost is that of the batch's slowest run per step.

How to run (one CPU device: flocking programs on two devices deadlock)::

    MCJAX_CPU_DEVICES=1 python benchmarks/papers/lou2013_integrator.py [--runs 10] [--cost-runs 100]

diffrax (not a dependency of mcjax; its rows are left out when it is not installed) has no closing-speed cap on the sub-step and takes the link margin and the
smallest distance at the sub-step ends (no Hermite interpolant); it is here for the comparison
only.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import time
from dataclasses import replace
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from scipy.integrate import solve_ivp

from mcjax import configure, engine
from mcjax.scenarios.lou2013 import dynamics as dyn
from mcjax.scenarios.lou2013 import scenario as sc
from mcjax.study import load_config_file

configure()  # JAX's 64-bit mode and CPU devices, as the CLI sets them
ROOT = Path(__file__).resolve().parents[2]

CONFIG = ROOT / "configs" / "lou2013.toml"
TRANSIENT = 20


def diffrax_adaptive(state, adj, sensing, reference, g, dt, max_substeps, tolerance, moving=None, barrier=None):
    """diffrax's Dopri5 with its PID controller (integral only, as the hand-written pair: safety
    0.9, factors in [0.2, 5]) at ``atol = tolerance / 10`` (the hand-written pair's
    :data:`~mcjax.scenarios.lou2013.dynamics.SUBSTEP_SHARE`), ``rtol = 0``, max norm; the same signature
    and returns as :func:`mcjax.scenarios.lou2013.dynamics.dopri5_adaptive`."""
    import diffrax
    import optimistix as optx

    def f(t, y, args):
        rq, rp = reference(t)
        return dyn.derivative(y, adj, sensing, rq, rp, g, moving, barrier)

    eye = jnp.eye(state.q.shape[0], dtype=bool)
    linked = (adj > 0.5) & ~eye

    def extremes(t, y, args):
        _, r, _ = dyn._pair_vectors(y.q)
        return (jnp.min(jnp.where(linked, g.R - r, jnp.inf)), jnp.min(jnp.where(eye, jnp.inf, r)))

    ctrl = diffrax.PIDController(rtol=0.0, atol=dyn.SUBSTEP_SHARE * tolerance, norm=optx.max_norm, factormin=0.2, factormax=5.0)
    dtype = state.q.dtype
    sol = diffrax.diffeqsolve(diffrax.ODETerm(f), diffrax.Dopri5(), jnp.asarray(0.0, dtype), dt,
                              dyn.stable_step(state, adj, sensing, g), state, stepsize_controller=ctrl,
                              saveat=diffrax.SaveAt(subs=[diffrax.SubSaveAt(t1=True),
                                                          diffrax.SubSaveAt(steps=True, fn=extremes)]),
                              max_steps=max_substeps, throw=False)
    end, (margins, dists) = sol.ys[0], sol.ys[1]
    end = jax.tree.map(lambda x: x[0], end)
    k = sol.stats["num_steps"]
    done = sol.result == diffrax.RESULTS.successful
    margin = jnp.minimum(jnp.min(jnp.where(jnp.isfinite(margins), margins, jnp.inf)), jnp.inf)
    dmin = jnp.min(jnp.where(jnp.isfinite(dists), dists, jnp.inf))
    fine = jnp.all(jnp.isfinite(end.q)) & done
    return end, jnp.where(fine, margin, jnp.nan), jnp.where(fine, dmin, jnp.nan), k, ~done


# --------------------------------------------------------------------------- states


def collect(cfg, p, runs: int, base_seed: int = 0):
    """Every state of ``runs`` runs (stacked: run, time): flock, graph, the KCF's estimates."""
    keys = jnp.asarray(engine.run_keys(base_seed, np.arange(runs)))

    def one(key):
        s0 = sc.init(cfg, p, engine.init_key(key))

        def body(s, t):
            s1, _ = sc.step(cfg, p, s, jax.random.fold_in(key, t))
            return s1, (s1.flock, s1.adj, s1.filters[cfg.filters.index("kcf")].x)

        _, (flock, adj, est) = jax.lax.scan(body, s0, jnp.arange(cfg.n_steps))
        first = lambda a, b: jnp.concatenate([a[None], b])  # noqa: E731
        return jax.tree.map(first, s0.flock, flock), first(s0.adj, adj), est

    return jax.jit(jax.vmap(one))(keys)


def samples(flock, adj, est, n_steps: int, steady: int = 30):
    """Steps 0–19 and ``steady`` evenly spaced over 20–(n_steps − 1) of every run: the inputs of
    each step k (the flock and the graph at k, the KCF estimate after step k's update), the
    flock at k + 1, and whether k is in the transient."""
    idx = np.r_[np.arange(TRANSIENT), np.linspace(TRANSIENT, n_steps - 1, steady).round().astype(int)]
    runs = flock.q.shape[0]
    rr, kk = np.repeat(np.arange(runs), len(idx)), np.tile(idx, runs)
    take = lambda a, off=0: jnp.asarray(np.asarray(a)[rr, kk + off])  # noqa: E731
    return (jax.tree.map(take, flock), take(adj), take(est), jax.tree.map(lambda a: take(a, 1), flock),
            kk < TRANSIENT)


def integrate(cfg, p, fn, start, adj, est, tolerance, max_substeps):
    """``fn`` (one of the integrators) over one step from every sample, vmapped and jitted."""
    pp = p
    h = sc.sensing_mask(cfg, pp, jnp.float64)
    g = dyn.Gains(pp.c1, pp.c2, pp.k, pp.R)

    def one(s, a, x):
        rq0, rp0 = x[:, jnp.array([0, 2])], x[:, jnp.array([1, 3])]
        return fn(s, a, h, lambda tau: (rq0 + tau * rp0, rp0), g, pp.dt, max_substeps, tolerance)

    f = jax.jit(jax.vmap(one)).lower(start, adj, est).compile()
    t0 = time.perf_counter()
    out = jax.block_until_ready(f(start, adj, est))
    return out, time.perf_counter() - t0


def reference(cfg, p, start, adj, est):
    """DOP853 (rtol 1e-11, atol 1e-12) over one step from every sample; (q, p, b) arrays."""
    h = sc.sensing_mask(cfg, p, jnp.float64)
    g = dyn.Gains(p.c1, p.c2, p.k, p.R)
    n = start.q.shape[1]

    @jax.jit
    def rhs(t, y, a, x):
        s = dyn.FlockState(y[:2 * n].reshape(n, 2), y[2 * n:4 * n].reshape(n, 2), y[4 * n:].reshape(n, n))
        rq0, rp0 = x[:, jnp.array([0, 2])], x[:, jnp.array([1, 3])]
        d = dyn.derivative(s, a, h, rq0 + t * rp0, rp0, g)
        return jnp.concatenate([d.q.ravel(), d.p.ravel(), d.b.ravel()])

    out, nfev = [], []
    for i in range(start.q.shape[0]):
        a, x = adj[i], est[i]
        y0 = np.concatenate([np.asarray(start.q[i]).ravel(), np.asarray(start.p[i]).ravel(), np.asarray(start.b[i]).ravel()])
        sol = solve_ivp(lambda t, y: np.asarray(rhs(t, y, a, x)), (0.0, float(p.dt)), y0, method="DOP853",
                        rtol=1e-11, atol=1e-12)
        out.append(sol.y[:, -1])
        nfev.append(sol.nfev)
    y = np.stack(out)
    return y[:, :2 * n].reshape(-1, n, 2), y[:, 2 * n:4 * n].reshape(-1, n, 2), y[:, 4 * n:].reshape(-1, n, n), nfev


# --------------------------------------------------------------------------- cost per run


def run_cost(cfg, p, runs: int, base_seed: int = 0, swap=None):
    """Seconds per run of ``runs`` runs × ``cfg.n_steps`` steps of the whole scenario, one
    program (compiled ahead of time, excluded), and the runs' extremes. ``swap``: an
    integrator put in the hand-written pair's place while the program is traced."""
    keys = jnp.asarray(engine.run_keys(base_seed, np.arange(runs)))

    def one(key):
        s0 = sc.init(cfg, p, engine.init_key(key))

        def body(s, t):
            s1, rec = sc.step(cfg, p, s, jax.random.fold_in(key, t))
            return s1, (rec.min_distance, rec.min_link_margin, rec.energy, rec.substeps, rec.capped)

        _, recs = jax.lax.scan(body, s0, jnp.arange(cfg.n_steps))
        return recs

    saved = dyn.dopri5_adaptive
    if swap is not None:
        dyn.dopri5_adaptive = swap
    try:
        t0 = time.perf_counter()
        f = jax.jit(jax.vmap(one), compiler_options=engine.compiler_options(sc.SCENARIO)).lower(keys).compile()
        compile_s = time.perf_counter() - t0
    finally:
        dyn.dopri5_adaptive = saved
    t0 = time.perf_counter()
    dmin, margin, energy, sub, capped = (np.asarray(x) for x in jax.block_until_ready(f(keys)))
    wall = time.perf_counter() - t0
    rise = np.maximum(np.max(energy[:, 1:] - energy[:, :-1], axis=1), 0.0)
    return dict(s_per_run=wall / runs, compile_s=compile_s, substeps=float(sub.mean()),
                slowest=float(sub.max(0).mean()), capped=int(capped.sum()), min_distance=dmin.min(1),
                min_margin=margin.min(1), max_rise=rise)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=10, help="runs whose states are sampled (50 states each)")
    ap.add_argument("--cost-runs", type=int, default=100, help="runs of the cost comparison (0: skip)")
    ap.add_argument("--max-substeps", type=int, default=4000, help="cap of the accuracy comparison's integrators")
    args = ap.parse_args(argv)
    os.environ.setdefault("MCJAX_CPU_DEVICES", "1")
    scenario, cfg, values = load_config_file(CONFIG)
    p = scenario.default_params(cfg, **values)
    p = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), p)
    tol = cfg.tolerance
    print(f"load: {subprocess.run(['uptime'], capture_output=True, text=True).stdout.strip()}")
    print(f"config: {CONFIG.name}, integrator {cfg.integrator}, tolerance {tol:g} (m, m/s), "
          f"max_substeps {cfg.max_substeps}")

    t0 = time.perf_counter()
    flock, adj, est = collect(cfg, p, args.runs)
    start, a, x, end, transient = samples(flock, adj, est, cfg.n_steps)
    print(f"states: {start.q.shape[0]} ({int(transient.sum())} transient, steps 0-{TRANSIENT - 1}; "
          f"{int((~transient).sum())} steady) from {args.runs} runs, {time.perf_counter() - t0:.1f} s")

    (again, *_), _ = integrate(cfg, p, dyn.dopri5_adaptive, start, a, x, tol, cfg.max_substeps)
    same = max(float(jnp.max(jnp.abs(u - v))) for u, v in zip(jax.tree.leaves(again), jax.tree.leaves(end)))
    print(f"check: re-integrating each sampled step reproduces the run's next state to {same:.1e}")

    t0 = time.perf_counter()
    rq, rp, rb, nfev = reference(cfg, p, start, a, x)
    print(f"reference: DOP853 rtol 1e-11 atol 1e-12, {np.mean(nfev):.0f} evaluations per step (mean), "
          f"{time.perf_counter() - t0:.0f} s")

    def rk4(s, adj_, h, ref, g, dt, m, _tol):
        return dyn.rk4_adaptive(s, adj_, h, ref, g, dt, min(m, cfg.max_substeps), float(p.substep_safety))

    import importlib.util
    has_diffrax = importlib.util.find_spec("diffrax") is not None  # not a dependency of mcjax
    if not has_diffrax:
        print("diffrax is not installed: its rows are left out (pip install diffrax)")
    cases = [("RK4 sub-steps (before)", rk4, tol), ("dopri5, hand-written", dyn.dopri5_adaptive, tol),
             ("dopri5, hand-written, 100x tighter", dyn.dopri5_adaptive, tol / 100)]
    if has_diffrax:
        cases += [("diffrax Dopri5", diffrax_adaptive, tol), ("diffrax Dopri5, 100x tighter", diffrax_adaptive, tol / 100)]
    print(f"\n| integrator | tolerance | largest error, position (m): transient / steady | velocity (m/s) | "
          f"gain b (1/s) | sub-steps per step (mean / max) | capped | time for the {start.q.shape[0]} steps (vmapped) |")
    print("|---|---|---|---|---|---|---|---|")
    for label, fn, t in cases:
        (s, _, _, k, capped), wall = integrate(cfg, p, fn, start, a, x, t, args.max_substeps)
        eq = np.max(np.abs(np.asarray(s.q) - rq), axis=(1, 2))
        ep = np.max(np.abs(np.asarray(s.p) - rp), axis=(1, 2))
        eb = np.max(np.abs(np.asarray(s.b) - rb), axis=(1, 2))
        tr = np.asarray(transient)
        print(f"| {label} | {t:g} | {eq[tr].max():.2e} / {eq[~tr].max():.2e} | {ep[tr].max():.2e} / "
              f"{ep[~tr].max():.2e} | {eb.max():.2e} | {np.mean(k):.1f} / {np.max(k)} | {int(np.sum(capped))} | "
              f"{wall:.2f} s |")

    if args.cost_runs:
        print(f"\ncost per run: {args.cost_runs} runs x {cfg.n_steps} steps of the whole scenario, one program "
              f"each (compilation excluded); load before: "
              f"{subprocess.run(['uptime'], capture_output=True, text=True).stdout.strip()}")
        print("| integrator | s per run | sub-steps per step (mean / slowest run's) | capped steps | compile (s) |")
        print("|---|---|---|---|---|")
        rows = [("RK4 sub-steps (before)", replace(cfg, integrator="rk4", max_substeps=200), None),
                ("dopri5, hand-written", cfg, None),
                ("diffrax Dopri5", replace(cfg, max_substeps=cfg.max_substeps + 1), diffrax_adaptive)][:3 if has_diffrax else 2]
        for label, c, swap in rows:
            r = run_cost(c, p, args.cost_runs, swap=swap)
            print(f"| {label} | {r['s_per_run']:.3f} | {r['substeps']:.1f} / {r['slowest']:.1f} | {r['capped']} | "
                  f"{r['compile_s']:.0f} |")
        print(f"load after: {subprocess.run(['uptime'], capture_output=True, text=True).stdout.strip()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
