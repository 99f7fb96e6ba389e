"""The leader's planning cost — Sun et al. 2011, eqs. 16–19, docs/equations.md §6.1.

For one predicted horizon step (UAV poses ``uavs`` (n, 4) = [x, y, v, φ], the commanded
headings, the predicted target position) the cost is

    tr((Y_h + Σ_i g_i I_i)⁻¹)                    A-optimality (eq. 16, term 1; I_i of eq. 10)
    + α_I Σ_i pen(R_I(i))                        connectivity robustness (eqs. 14–16)
    + α_C Σ_i |ψᶜ_i − ψ_i|                       control effort (eq. 17)
    + α_L Σ_i r_Ti                               distance to the target (eq. 16, term 4)
    + α_S [Σ_{i<j} h(1 − l_ij/D_safe)² + h(1 − r_LT/D_LT)²]   eqs. 18–19 as penalties

with ``Y_h`` the leader's information predicted to step h (its current Y at h = 0, then
the posterior of step h − 1 predicted through the CV model — the paper's ``Y_{1,k}`` carried
along the horizon, so that geometry over the whole horizon counts; our reading),
``g_i`` the sensing-range gate, ``h`` the hinge ``max(0, ·)`` and ``pen`` either the
paper's ``1/|R|`` or (default) the barrier ``softplus(−R/s)``: the paper's ``1/|R|``
*rewards* a badly broken graph (large negative R), the barrier grows monotonically as R
falls toward and below 0 (docs/equations.md §6.1).

Every non-smooth piece has a smooth form at the temperature ``T`` (metres): the gate
becomes ``sigmoid((R_s − r)/T)``, the max/min of R_I become soft max/min
(:func:`mcjax.tracking.connectivity.smooth_connectivity_robustness`), the hinges become ``T·softplus(·/T)``
and ``1/|R|`` becomes ``1/√(R² + T²)``. ``smooth=False`` gives the exact cost, which is
what the planners report and what the sampled planners minimise
(:func:`mcjax.scenarios.sun2011.horizon.horizon_plan_cost` packs both for
:func:`mcjax.tracking.planning.solvers.solve`).

Distances inside the cost are ``√(|Δ|² + ε²)`` with ε = 1 m, so gradients stay finite for
coincident UAVs and for a UAV on top of the target.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcjax.tracking import connectivity
from mcjax.tracking.numerics import matmul, spd_inverse, wrap_angle

#: ε of the regularised distance √(|Δ|² + ε²), m.
DISTANCE_EPS = 1.0
ROBUSTNESS_PENALTIES = ("barrier", "inverse")
#: How R_I is computed (Config.robustness_paths): "all_pairs" = the widest path of every pair
#: (Floyd–Warshall, O(n³); smooth: :func:`mcjax.tracking.connectivity.smooth_connectivity_robustness`),
#: "spanning_tree" = the same exact numbers from a maximum spanning tree in O(n²), smooth: a softmin
#: over the tree's links (:func:`mcjax.tracking.connectivity.smooth_tree_connectivity_robustness`, a different
#: surrogate), "auto" = all pairs up to :data:`TREE_ABOVE` agents, the tree above.
ROBUSTNESS_PATHS = ("auto", "all_pairs", "spanning_tree")
#: "auto" takes the spanning tree above this many agents (ours, chosen before measuring: every
#: built-in config, the paper's 5 UAVs, stays on all pairs; issue "Scale": swarms of 50–100).
TREE_ABOVE = 10


def resolve_paths(paths: str, n: int) -> str:
    """``"all_pairs"`` or ``"spanning_tree"``: ``Config.robustness_paths`` for a team of ``n``."""
    if paths not in ROBUSTNESS_PATHS:
        raise ValueError(f"robustness_paths must be one of {', '.join(ROBUSTNESS_PATHS)}; got {paths!r}")
    if paths == "auto":
        return "spanning_tree" if n > TREE_ABOVE else "all_pairs"
    return paths


class CostParams(NamedTuple):
    """The numbers of the planning cost (one set per run; all may vary inside a batch)."""

    alpha_I: jax.Array           # weight of the connectivity-robustness penalty (case 1: 0)
    alpha_C: jax.Array           # 1/rad, weight of the control effort
    alpha_L: jax.Array           # 1/m, weight of the distance to the target
    alpha_S: jax.Array           # weight of the D_safe / D_LT penalties
    d_safe: jax.Array            # m, eq. 18
    d_lt: jax.Array              # m, eq. 19 (leader–target)
    robustness_scale: jax.Array  # m, s of the barrier softplus(−R/s)
    temperature: jax.Array       # m, temperature of the smooth forms
    sensing_radius: jax.Array    # (n,) m
    comm_radius: jax.Array       # (n,) m
    sigma_range: jax.Array       # m
    sigma_bearing: jax.Array     # rad
    alive: jax.Array             # (n,) 0/1


def _dist(d: jax.Array) -> jax.Array:
    return jnp.sqrt(jnp.sum(d * d, axis=-1) + DISTANCE_EPS**2)


def position_information(sensors: jax.Array, target_xy: jax.Array, sigma_range, sigma_bearing):
    """Position block of the range–bearing information ``I_i = H_iᵀ R⁻¹ H_i`` (Sun et al. 2011, eq. 10).

    With ``u`` the unit line of sight and ``w`` its normal, ``H`` (position columns) has rows
    ``uᵀ`` (range) and ``wᵀ/r`` (bearing), so ``I = u uᵀ/σ_r² + w wᵀ/(σ_θ² r²)``.
    ``sensors`` (n, 2), ``target_xy`` (2,) -> (n, 2, 2). r is regularised by ε = 1 m.
    """
    d = target_xy - sensors
    r = _dist(d)
    u = d / r[:, None]
    w = jnp.stack([-u[:, 1], u[:, 0]], axis=-1)
    return (u[:, :, None] * u[:, None, :] / sigma_range**2
            + w[:, :, None] * w[:, None, :] / (sigma_bearing**2 * r**2)[:, None, None])


def a_optimality(Y: jax.Array, info_xy: jax.Array, gates: jax.Array):
    """``tr((Y + Σ_i g_i I_i)⁻¹)`` — Sun et al. 2011, eq. 16, first term (A-optimality criterion).

    ``Y`` (4, 4) the leader's (predicted) information matrix on ``[x, ẋ, y, ẏ]``;
    ``info_xy`` (n, 2, 2) position blocks of eq. 10; ``gates`` (n,) in [0, 1].
    Returns ``(trace, P)`` with ``P = (Y + Σ g I)⁻¹`` the predicted posterior covariance."""
    s = jnp.sum(gates[:, None, None] * info_xy, axis=0)
    # s into the position rows and columns (0, 2) of the 4×4: a Kronecker product is a
    # broadcast multiply, no scatter (scatters are slow under vmap on the CPU)
    total = Y + jnp.kron(s, jnp.array([[1.0, 0.0], [0.0, 0.0]], Y.dtype))
    P = spd_inverse(total)
    return jnp.trace(P), P


def information_after_prediction(P, F, Q):
    """``(F P Fᵀ + Q)⁻¹``: the information after one prediction through the CV model
    (Sun et al. 2011, eq. 1) of the covariance ``P``.

    (Not :func:`mcjax.tracking.filters.gaussian.predict_information`, which predicts a filter state.)"""
    return spd_inverse(matmul(matmul(F, P), F.T) + Q)


def robustness_penalty(R: jax.Array, kind: str, scale, temperature, smooth: bool) -> jax.Array:
    """``pen(R_I)`` of Sun et al. 2011, eq. 16 (second term; R_I of eqs. 14–15), per agent.

    ``"inverse"``: the paper's ``1/|R|`` (smooth: ``1/√(R² + T²)``). ``"barrier"`` (default,
    docs/equations.md §6.1): ``softplus(−R/s)`` — about ``−R/s`` for a broken graph, ``s log 2``-ish
    at R = 0, vanishing once R ≫ s. An agent without information neighbours (R = +inf)
    costs 0 either way."""
    finite = jnp.isfinite(R)
    R = jnp.where(finite, R, 0.0)
    if kind == "inverse":
        a = jnp.sqrt(R * R + temperature**2) if smooth else jnp.abs(R)
        pen = 1.0 / a
    elif kind == "barrier":
        pen = jax.nn.softplus(-R / scale)
    else:
        raise ValueError(f"robustness_penalty must be one of {', '.join(ROBUSTNESS_PENALTIES)}; got {kind!r}")
    return jnp.where(finite, pen, 0.0)


def _hinge(x, temperature, smooth: bool):
    """``max(0, x)``; smooth: ``T·softplus(x/T)`` (x dimensionless, T relative)."""
    if smooth:
        return temperature * jax.nn.softplus(x / temperature)
    return jnp.maximum(x, 0.0)


def safety_penalty(positions, leader_target_range, p: CostParams, smooth: bool) -> jax.Array:
    """Sun et al. 2011, eqs. 18–19 as penalties: ``Σ_{i<j} h(1 − l_ij/D_safe)² + h(1 − r_LT/D_LT)²``
    over alive UAVs.

    The smooth hinge's temperature is ``T/D`` (the metre temperature made relative)."""
    n = positions.shape[0]
    l = _dist(positions[:, None, :] - positions[None, :, :])
    pair = jnp.triu(jnp.ones((n, n), bool), 1) & (p.alive[:, None] > 0.5) & (p.alive[None, :] > 0.5)
    coll = _hinge(1.0 - l / p.d_safe, p.temperature / p.d_safe, smooth) ** 2
    lt = _hinge(1.0 - leader_target_range / p.d_lt, p.temperature / p.d_lt, smooth) ** 2
    return jnp.sum(jnp.where(pair, coll, 0.0)) + jnp.where(p.alive[0] > 0.5, lt, 0.0)


class CostTerms(NamedTuple):
    information: jax.Array
    robustness: jax.Array
    control: jax.Array
    distance: jax.Array
    safety: jax.Array


def step_terms(Y, uavs, prev_headings, commands, target_xy, p: CostParams, *,
               penalty: str = "barrier", smooth: bool, paths: str = "all_pairs"):
    """The unweighted terms of Sun et al. 2011, eqs. 16–19 of one predicted step (see the
    module docstring).

    ``Y`` the leader's predicted information at this step, ``uavs`` (n, 4) predicted poses
    after the step, ``prev_headings`` (n,) headings before it (ψ_i(k) of eq. 17),
    ``commands`` (n,) the commanded headings ψᶜ_i(k+1). Returns ``(CostTerms, P)`` with P
    the predicted posterior covariance of the step. ``paths``: how R_I is computed
    (:data:`ROBUSTNESS_PATHS`, ``"auto"`` resolved by the team's size)."""
    alive = p.alive > 0.5
    xy = uavs[:, :2]
    r_t = _dist(target_xy - xy)
    if smooth:
        gates = jax.nn.sigmoid((p.sensing_radius - r_t) / p.temperature)
    else:
        gates = (r_t <= p.sensing_radius).astype(xy.dtype)
    gates = jnp.where(alive, gates, 0.0)
    info, P = a_optimality(Y, position_information(xy, target_xy, p.sigma_range, p.sigma_bearing), gates)

    neighbours = alive[:, None] & alive[None, :]
    if resolve_paths(paths, xy.shape[0]) == "spanning_tree":
        if smooth:
            R = connectivity.smooth_tree_connectivity_robustness(xy, p.comm_radius, p.temperature, alive)
        else:
            R = connectivity.tree_connectivity_robustness(xy, p.comm_radius, alive)
    elif smooth:
        R = connectivity.smooth_connectivity_robustness(xy, p.comm_radius, p.temperature, neighbours)
    else:
        R = connectivity.connectivity_robustness(xy, p.comm_radius, neighbours)
    pen = robustness_penalty(R, penalty, p.robustness_scale, p.temperature, smooth)
    control = jnp.abs(wrap_angle(commands - prev_headings))
    return CostTerms(
        information=info,
        robustness=jnp.sum(jnp.where(alive, pen, 0.0)),
        control=jnp.sum(jnp.where(alive, control, 0.0)),
        distance=jnp.sum(jnp.where(alive, r_t, 0.0)),
        safety=safety_penalty(xy, r_t[0], p, smooth),
    ), P


def weighted(terms: CostTerms, p: CostParams) -> jax.Array:
    """Sun et al. 2011, eq. 16 with eqs. 18–19 as penalties: the weighted sum of :class:`CostTerms`."""
    return (terms.information + p.alpha_I * terms.robustness + p.alpha_C * terms.control
            + p.alpha_L * terms.distance + p.alpha_S * terms.safety)
