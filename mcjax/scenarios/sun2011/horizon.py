"""Receding-horizon rollout and cost — Sun et al. 2011 §4.2, docs/equations.md §6.2.

A plan is ``u`` (H, n) with entries in [−1, 1], H = ``Config.max_horizon``: at predicted step
h UAV i is commanded the heading ``ψᶜ = ψ_i(h−1) + u·φ̇_max/α_φ`` — offsets up to the one
that saturates the eq. 4 turn-rate limit, so every ``u`` is feasible (the gradient planner
reaches it as ``tanh`` of free parameters). The UAVs move with the platform model the
simulation uses (:func:`mcjax.tracking.models.platforms.unicycle_step`, eqs. 3–4) and the target's
mean with the CV model (eq. 1). Steps ``h ≥ t_r`` are masked out of the cost, so the
horizon ``t_r`` is a per-run number and runs with different horizons share one program.
:func:`horizon_plan_cost` packs the horizon cost (Sun et al. 2011, eq. 16) as the
:class:`~mcjax.tracking.planning.solvers.PlanCost` the generic planners take.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcjax.tracking.models.motion import cv_matrices, cv_process_noise
from mcjax.tracking.models.platforms import UnicycleLimits, unicycle_step
from mcjax.tracking.numerics import matvec, spd_inverse
from mcjax.tracking.planning.solvers import PlanCost
from mcjax.scenarios.sun2011.objectives import (
    ROBUSTNESS_PENALTIES, CostParams, CostTerms, information_after_prediction, step_terms, weighted,
)


class Problem(NamedTuple):
    """What the leader knows when it plans (Sun et al. 2011 §4: its own ICF estimate, the UAV states)."""

    uavs: jax.Array         # (n, 4) [x, y, v, φ] now
    target_mean: jax.Array  # (4,) the leader's estimate [x, ẋ, y, ẏ]
    Y: jax.Array            # (4, 4) the leader's information matrix


class Dynamics(NamedTuple):
    dt: jax.Array
    alpha_phi: jax.Array
    turn_rate_max: jax.Array
    horizon: jax.Array      # t_r, steps (≤ max_horizon)
    sigma_accel: jax.Array  # m/s², the CV process noise the leader's filter assumes


def command_offset_limit(dyn: Dynamics):
    """Largest useful heading-command offset: the one that saturates the turn rate
    (Sun et al. 2011, eq. 4)."""
    return dyn.turn_rate_max / dyn.alpha_phi


def rollout(problem: Problem, u: jax.Array, dyn: Dynamics):
    """Predicted UAV poses (H, n, 4), the headings before each step (H, n), the commands
    (H, n) and the target means (H, 4) of the plan ``u`` (H, n): the UAVs by Sun et al. 2011,
    eqs. 3–4, the target mean by the CV model, Sun et al. 2011, eq. 1."""
    n = problem.uavs.shape[0]
    v = problem.uavs[:, 2]
    zero = jnp.zeros((), u.dtype)
    limits = UnicycleLimits(v, v, zero, zero, jnp.broadcast_to(dyn.turn_rate_max, (n,)))
    F, _ = cv_matrices(dyn.dt, u.dtype)
    offset = command_offset_limit(dyn)

    def body(carry, u_h):
        uavs, x = carry
        cmd = uavs[:, 3] + offset * u_h
        # rematerialised in the backward pass: storing the step's quadrature nodes for it
        # costs more than recomputing them (docs/benchmarks.md, 2026-12-02)
        nxt = jax.checkpoint(unicycle_step)(uavs, cmd, 0.0, dyn.alpha_phi, limits, dyn.dt)
        x = matvec(F, x)
        return (nxt, x), (nxt, uavs[:, 3], cmd, x)

    _, (poses, prev, cmds, targets) = jax.lax.scan(body, (problem.uavs, problem.target_mean), u)
    return poses, prev, cmds, targets


def horizon_terms(problem: Problem, u: jax.Array, dyn: Dynamics, cost: CostParams, *,
                  penalty: str, smooth: bool, paths: str = "all_pairs") -> CostTerms:
    """The terms of Sun et al. 2011, eqs. 16–19 summed over the first ``t_r`` predicted steps
    (later ones masked)."""
    poses, prev, cmds, targets = rollout(problem, u, dyn)
    F, _ = cv_matrices(dyn.dt, u.dtype)
    Q = cv_process_noise(dyn.dt, dyn.sigma_accel, u.dtype)

    def body(P, step):
        pose, h, c, x = step
        terms, P_post = step_terms(information_after_prediction(P, F, Q), pose, h, c, x[::2],
                                   cost, penalty=penalty, smooth=smooth, paths=paths)
        return P_post, terms

    # each step recomputed in the backward pass instead of stacking its intermediates
    _, terms = jax.lax.scan(jax.checkpoint(body), spd_inverse(problem.Y), (poses, prev, cmds, targets))
    mask = (jnp.arange(u.shape[0]) < dyn.horizon).astype(u.dtype)
    return CostTerms(*(jnp.sum(mask * t) for t in terms))


def horizon_cost(problem: Problem, u: jax.Array, dyn: Dynamics, cost: CostParams, *,
                 penalty: str = "barrier", smooth: bool = False, paths: str = "all_pairs") -> jax.Array:
    """Sun et al. 2011, eq. 16 (with eqs. 18–19 as penalties) summed over the horizon t_r."""
    return weighted(horizon_terms(problem, u, dyn, cost, penalty=penalty, smooth=smooth, paths=paths), cost)


def horizon_plan_cost(problem: Problem, dyn: Dynamics, cost: CostParams, *, penalty: str,
                      paths: str = "all_pairs") -> PlanCost:
    """The horizon cost of Sun et al. 2011, eq. 16 (eqs. 18–19 as penalties) as a
    :class:`~mcjax.tracking.planning.solvers.PlanCost` of the plan ``u`` (H, n) in [−1, 1]:
    ``exact`` is :func:`horizon_cost` with ``smooth=False``, ``smooth`` the same with
    ``smooth=True`` (the surrogate of :mod:`~mcjax.scenarios.sun2011.objectives`).

    ``penalty``: the robustness penalty, ``"barrier"`` or ``"inverse"`` (``Config.robustness_penalty``);
    ``paths``: how R_I is computed (``Config.robustness_paths``, :data:`~.objectives.ROBUSTNESS_PATHS`).
    Use: ``solve(horizon_plan_cost(problem, dyn, cost, penalty=...), warm, key, options)``."""
    if penalty not in ROBUSTNESS_PENALTIES:
        raise ValueError(f"robustness_penalty must be one of {', '.join(ROBUSTNESS_PENALTIES)}; "
                         f"got {penalty!r}")
    return PlanCost(
        exact=lambda u: horizon_cost(problem, u, dyn, cost, penalty=penalty, smooth=False, paths=paths),
        smooth=lambda u: horizon_cost(problem, u, dyn, cost, penalty=penalty, smooth=True, paths=paths),
    )


def shift_plan(u: jax.Array, by, horizon) -> jax.Array:
    """The previous plan advanced by ``by`` steps (τ_r), the freed tail (and every step at or
    beyond ``t_r``) set to 0 — hold the heading: the warm start of the next plan."""
    H = u.shape[0]
    idx = jnp.arange(H) + by
    valid = (idx < horizon)[:, None]
    return jnp.where(valid, u[jnp.minimum(idx, H - 1)], 0.0)
