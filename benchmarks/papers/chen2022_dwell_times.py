"""Chen & Hao 2022: the IMM's mode chain from dwell times along flown paths (issue 32, item 3).

The paper defers its IMM's transition matrix to its ref. [25]. A Markov chain that stays in mode
i with probability p_ii per step stays there 1/(1 − p_ii) steps on average, so a chain that
matches the mean time τ_i the UAV spends in each condition has

    p_ii = 1 − Δt / τ_i .

What is run. The scenario with ``configs/chen2022.toml`` (or ``--config``) at the FIM-only
weight vector (c1, c2, c3) = (0.2, 0, 0) — the one whose path the planner's NLOS and shadow
terms do not shape — for ``--runs`` seeds (default 200; seeds 0 … runs − 1 of base seed 1000,
not the Table 1 seeds) and the config's 250 steps. Each step is classed by where the UAV is
after it: shadow (no line of sight, no measurement), reflected (line of sight and a reflection
arrives: the measurement is biased), LOS (otherwise). Reflected steps are split by the sign of
their true bias (measured noise-free bearing minus the true azimuth).

Estimates. For each class i: n_i = steps in i that have a next step, n_ii = those followed by
i; the mean stretch length in steps is n_i / (n_i − n_ii) (the maximum-likelihood estimate of
a geometric stretch, counting stretches cut by the run's end), τ_i = Δt · n_i / (n_i − n_ii),
p_ii = n_ii / n_i = 1 − Δt / τ_i. Also printed: the mean length of the stretches that ended
before the run did, and the direct steps from one reflection sign to the other.

The chain over the IMM's modes (LOS, NLOS+, NLOS−):

    LOS row:    p_LL = 1 − Δt/τ_LOS, the rest split evenly between NLOS+ and NLOS−;
    NLOS± rows: p_±± = 1 − Δt/τ_reflected, the rest to LOS, NLOS+ ↔ NLOS− = 0
                (a wall's bias sign does not flip without leaving it).

The shadow has no IMM mode (the filters only predict there); its dwell time is printed for the
shadow's hold (``max_hold_steps``). No error or estimate is read: this is geometry along paths.

How to run::

    python benchmarks/papers/chen2022_dwell_times.py [--runs 200] [--config configs/chen2022.toml]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from mcjax.scenarios import chen2022 as ub
from mcjax.scenarios.chen2022 import environment as env
from mcjax.tracking.models.sensors import azimuth
from figures import run_records  # the one run set-up of this folder's scripts


ROOT = Path(__file__).resolve().parents[2]
LOS, REFL, SHADOW = 0, 1, 2
NAMES = ("LOS", "reflected", "shadow")


def classes(records, params) -> tuple[np.ndarray, np.ndarray]:
    """Per run and step: the class (LOS / reflected / shadow) and the sign of the true bias on
    reflected steps (+1 / −1, 0 elsewhere)."""
    shadow = np.asarray(records.shadow, bool)
    refl = np.asarray(records.nlos, bool)
    cls = np.where(shadow, SHADOW, np.where(refl, REFL, LOS))
    b = ub.buildings_of(params)
    pos = jnp.asarray(records.uav[..., :3])
    clean = env.measured_bearing(b, params.emitter, pos, params.R2, params.power, params.directivity)
    true = azimuth(params.emitter[:2], pos)
    bias = np.asarray(jnp.angle(jnp.exp(1j * (clean - true))))
    sign = np.where(refl, np.sign(bias), 0).astype(int)
    return cls, sign


def dwell(cls: np.ndarray, state: int, dt: float) -> dict:
    """The estimates of the module docstring for one class (runs x steps array of classes)."""
    here, nxt = cls[:, :-1] == state, cls[:, 1:]
    n_i = int(here.sum())
    n_ii = int((here & (nxt == state)).sum())
    exits = n_i - n_ii
    complete = []
    for row in cls:
        run = 0
        for c in row:
            if c == state:
                run += 1
            elif run:
                complete.append(run)
                run = 0
    mean_steps = n_i / exits if exits else float("inf")
    return dict(steps=int((cls == state).sum()), n_i=n_i, n_ii=n_ii, exits=exits, mean_steps=mean_steps,
                tau=dt * mean_steps, p=n_ii / n_i if n_i else float("nan"),
                complete=float(np.mean(complete)) if complete else float("nan"), n_complete=len(complete))


def chain(p_los: float, p_refl: float) -> np.ndarray:
    """The IMM's transition matrix over (LOS, NLOS+, NLOS−) of the module docstring."""
    a = (1.0 - p_los) / 2.0
    return np.array([[p_los, a, a], [1.0 - p_refl, p_refl, 0.0], [1.0 - p_refl, 0.0, p_refl]])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--config", type=Path, default=ROOT / "configs" / "chen2022.toml")
    ap.add_argument("--base-seed", type=int, default=1000)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    runs = run_records(args.config, args.runs, params_over={"c1": 0.2, "c2": 0.0, "c3": 0.0}, base_seed=args.base_seed)
    cfg, records = runs.config, runs.records
    cls, sign = classes(records, runs.params)
    print(f"FIM-only weight vector (0.2, 0, 0), {args.config.name}: {args.runs} runs x {cfg.n_steps} steps "
          f"(base seed {args.base_seed}), dt = {cfg.dt:g} s; {time.perf_counter() - t0:.1f} s\n")
    print("| class | steps (% of all) | mean stretch, steps (MLE, censored) | tau, s | p_ii = 1 - dt/tau | "
          "complete stretches | their mean, steps |")
    print("|---|---|---|---|---|---|---|")
    est = {}
    for state, name in enumerate(NAMES):
        d = dwell(cls, state, cfg.dt)
        est[state] = d
        print(f"| {name} | {d['steps']} ({100 * d['steps'] / cls.size:.1f} %) | {d['mean_steps']:.2f} | "
              f"{d['tau']:.1f} | {d['p']:.4f} | {d['n_complete']} | {d['complete']:.2f} |")
    refl_next = (cls[:, :-1] == REFL) & (cls[:, 1:] == REFL)
    flips = int(np.sum(refl_next & (sign[:, :-1] * sign[:, 1:] < 0)))
    plus, minus = int(np.sum(sign > 0)), int(np.sum(sign < 0))
    print(f"\nReflected steps by the sign of the true bias: + {plus}, - {minus}; steps from one sign straight to "
          f"the other: {flips} of {int(refl_next.sum())} reflected-to-reflected steps.")
    runs_with = {name: int(np.sum(np.any(cls == s, axis=1))) for s, name in enumerate(NAMES)}
    print(f"Runs with at least one step of each class: {runs_with}")
    m = chain(est[LOS]["p"], est[REFL]["p"])
    print("\nIMM transition matrix P(j | l), rows from LOS, NLOS+, NLOS- (p_ii to 4 decimals in the config):")
    print("imm_transition = [" + ", ".join("[" + ", ".join(f"{v:.5g}" for v in row) + "]" for row in m) + "]")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
