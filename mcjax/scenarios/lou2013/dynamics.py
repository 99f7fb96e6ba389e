"""The flock's integration over a sampling step — Lou, Cui & Li 2013's flock (:mod:`.model`).

The paper leaves the integration open (ours): :func:`dopri5_adaptive` integrates a sampling
step by the Dormand–Prince 5(4) pair with step-size control on an absolute tolerance (m, m/s),
its sub-steps also capped by the pairs' closing speeds so no link event is stepped over;
:func:`rk4_adaptive` is the RK4 sub-stepping sized for stability used before. The model's
names (eqs. 1, 10–16: the potential, the controllers, the energy) are read here too.

Everything is pure and vmappable; positions are (N, 2), the adjacency (N, N) 0/1.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mcjax.scenarios.lou2013.model import (  # the model, also read from here by its callers
    FlockState, Gains, controls, derivative, energy, faded_potential, faded_potential_slope, pair_vectors, potential,
    potential_curvature, potential_forces, potential_slope,
)

_pair_vectors = pair_vectors  # the name benchmarks/papers/lou2013_integrator.py reads


def _rk4_substep(f, s: FlockState, tau, h) -> FlockState:
    """One classical RK4 step of size ``h`` from time ``tau`` of ``ds/dt = f(s, tau)``."""
    def add(a, da, c):
        return jax.tree.map(lambda x, y: x + c * y, a, da)

    k1 = f(s, tau)
    k2 = f(add(s, k1, h / 2), tau + h / 2)
    k3 = f(add(s, k2, h / 2), tau + h / 2)
    k4 = f(add(s, k3, h), tau + h)
    return jax.tree.map(lambda a, b1, b2, b3, b4: a + h / 6 * (b1 + 2 * b2 + 2 * b3 + b4), s, k1, k2, k3, k4)


def _track_margins(s: FlockState, adj, R, margin, dmin, moving=None):
    """Running minima of ``R − r_ij`` over links and of the pairwise distance (between nodes
    ``moving`` (N,) bool, if given)."""
    _, r, eye = pair_vectors(s.q)
    linked = (adj > 0.5) & ~eye
    apart = eye if moving is None else eye | ~(moving[:, None] & moving[None, :])
    return (jnp.minimum(margin, jnp.min(jnp.where(linked, R - r, jnp.inf))),
            jnp.minimum(dmin, jnp.min(jnp.where(apart, jnp.inf, r))))


def _stability_bounds(state: FlockState, adj, sensing, g: Gains):
    """``(κ, γ, r, linked)``: the Gershgorin bound κ on the potential's Hessian per node
    (``Σ_j |ψ″| + |ψ′|/r`` over links), the damping γ = max(c2, max Σ_j b_ij on type-II
    rows), the pair distances and the link mask."""
    _, r, eye = pair_vectors(state.q)
    linked = (adj > 0.5) & ~eye
    rl = jnp.where(linked, r, g.R / 2)
    per_pair = jnp.where(linked, potential_curvature(rl, g.R) + jnp.abs(potential_slope(rl, g.R)) / rl, 0.0)
    kappa = jnp.max(jnp.sum(per_pair, axis=1))
    gamma = jnp.maximum(g.c2, jnp.max(jnp.sum(jnp.where(linked, jnp.abs(state.b), 0.0), 1) * (1.0 - sensing)))
    return kappa, gamma, rl, linked


def stable_substeps(state: FlockState, adj, sensing, g: Gains, dt, max_substeps: int, safety=1.0):
    """Number of RK4 sub-steps for the step ``dt`` (ours): ``ceil(dt / h)`` with
    ``h = safety · min(1/√κ, 1/γ)``, where κ bounds the stiffness of the potential per node
    (Gershgorin row sum of its Hessian block, ``Σ_j |ψ″(r_ij)| + |ψ′(r_ij)|/r_ij`` over
    links) and γ its damping (``c2`` and ``Σ_j b_ij``); RK4 is stable for h·√κ < 2.8 and
    h·γ < 2.7. Clipped to [1, max_substeps]."""
    kappa, gamma, _, _ = _stability_bounds(state, adj, sensing, g)
    h = safety * jnp.minimum(1.0 / jnp.sqrt(jnp.maximum(kappa, 1e-300)), 1.0 / gamma)
    n = jnp.ceil(dt / h)
    return jnp.clip(jnp.where(jnp.isfinite(n), n, max_substeps), 1, max_substeps).astype(jnp.int32)


def rk4_step(state: FlockState, adj, sensing, reference, g: Gains, dt, substeps):
    """Integrate the flock over ``dt`` with ``substeps`` (traced or static) classical RK4
    steps at a fixed topology ``adj``. ``reference(τ) -> (ref_q, ref_p)`` gives the type-I
    nodes' target reference at time τ ∈ [0, dt] into the step. Returns ``(state,
    min_link_margin, min_distance)`` where ``min_link_margin`` is the smallest ``R − r_ij``
    over links and ``min_distance`` the smallest pairwise distance, both over the sub-step
    ends."""
    n = jnp.asarray(substeps)
    h = dt / n.astype(state.q.dtype)

    def f(s, tau):
        rq, rp = reference(tau)
        return derivative(s, adj, sensing, rq, rp, g)

    def body(i, carry):
        s, margin, dmin = carry
        s = _rk4_substep(f, s, i.astype(h.dtype) * h, h)
        return (s, *_track_margins(s, adj, g.R, margin, dmin))

    inf = jnp.asarray(jnp.inf, state.q.dtype)
    state, margin, dmin = jax.lax.fori_loop(0, n, body, (state, inf, inf))
    return state, margin, dmin


def stable_step(state: FlockState, adj, sensing, g: Gains, safety=1.0):
    """Largest sub-step (ours) at this state: ``safety · min(1/√κ, 1/γ, ½ min r_ij/|ṙ_ij|,
    ½ min (R − r_ij)/|ṙ_ij|)`` — the stability bounds of :func:`stable_substeps` plus a
    kinematic one: no linked pair may close half its gap to 0 or to R within one sub-step at
    its current closing speed."""
    kappa, gamma, rl, linked = _stability_bounds(state, adj, sensing, g)
    dq = state.q[:, None, :] - state.q[None, :, :]
    dv = state.p[:, None, :] - state.p[None, :, :]
    rate = jnp.abs(jnp.sum(dq * dv, -1)) / jnp.where(linked, rl, 1.0)          # |ṙ_ij|
    gap = jnp.minimum(rl, g.R - rl)
    kin = jnp.min(jnp.where(linked & (rate > 0), 0.5 * gap / jnp.where(rate > 0, rate, 1.0), jnp.inf))
    h = jnp.minimum(jnp.minimum(1.0 / jnp.sqrt(jnp.maximum(kappa, 1e-300)), 1.0 / gamma), kin)
    return safety * h


def rk4_adaptive(state: FlockState, adj, sensing, reference, g: Gains, dt, max_substeps: int, safety=1.0,
                 moving=None, barrier=None):
    """Integrate the flock over ``dt`` at a fixed topology with classical RK4 sub-steps whose
    size is chosen before each sub-step from the current state (:func:`stable_step`), so a
    pair that closes in mid-step gets smaller sub-steps (ours). At most ``max_substeps``: the
    last one allowed takes whatever time is left (and the step is reported as capped).
    ``moving`` (N,) bool, optional: only these nodes move (:func:`derivative`), and the
    smallest distance is over pairs of them. ``barrier``: the relaxation switch's soft links
    (:func:`potential_forces`; the sub-steps are sized and the margins taken over the links of
    weight > 1/2). Returns ``(state, min_link_margin, min_distance, substeps_taken, capped)``."""
    def f(s, tau):
        rq, rp = reference(tau)
        return derivative(s, adj, sensing, rq, rp, g, moving, barrier)

    def cond(carry):
        _, tau, k, _, _ = carry
        return (tau < dt) & (k < max_substeps)

    def body(carry):
        s, tau, k, margin, dmin = carry
        h = jnp.minimum(stable_step(s, adj, sensing, g, safety), dt - tau)
        h = jnp.where(k == max_substeps - 1, dt - tau, h)
        h = jnp.where(jnp.isfinite(h) & (h > 0), h, dt - tau)
        s = _rk4_substep(f, s, tau, h)
        margin, dmin = _track_margins(s, adj, g.R, margin, dmin, moving)
        # a NaN state ends the step (it is flagged by its NaN margin / distance)
        tau = jnp.where(jnp.all(jnp.isfinite(s.q)), tau + h, dt)
        return s, tau, k + 1, margin, dmin

    dtype = state.q.dtype
    inf = jnp.asarray(jnp.inf, dtype)
    zero = jnp.asarray(0.0, dtype)
    state, tau, k, margin, dmin = jax.lax.while_loop(
        cond, body, (state, zero, jnp.asarray(0, jnp.int32), inf, inf))
    margin = jnp.where(jnp.all(jnp.isfinite(state.q)), margin, jnp.nan)
    dmin = jnp.where(jnp.all(jnp.isfinite(state.q)), dmin, jnp.nan)
    return state, margin, dmin, k, k >= max_substeps


# ------------------------------------------------------------------ error-controlled integration (ours)

#: The Dormand–Prince 5(4) pair (Dormand & Prince 1980; Hairer, Nørsett & Wanner, Solving ODEs I,
#: Table II.5.2): stage nodes, stage weights, the 5th-order weights (the last stage is the new
#: state's derivative, "first same as last") and the 5th minus 4th-order weights (error estimate).
_DP_C = (0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0)
_DP_A = ((), (1 / 5,), (3 / 40, 9 / 40), (44 / 45, -56 / 15, 32 / 9),
         (19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729),
         (9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656),
         (35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84))
_DP_E = (71 / 57600, 0.0, -71 / 16695, 71 / 1920, -17253 / 339200, 22 / 525, -1 / 40)
#: The share of the tolerance each sub-step's error estimate may use (ours): a step's error adds
#: up over its sub-steps (~10 in steady flight, ~100 in the first second). With the whole
#: tolerance per sub-step, one 0.1 s step erred by up to 2.2x it (velocity, transient; 100
#: states, 2026-12-03); a tenth keeps the step's error within the tolerance (benchmarks/papers/lou2013_integrator.py).
SUBSTEP_SHARE = 0.1


def _combine(s, ks, h, weights):
    return jax.tree.map(lambda a, *d: a + h * sum(w * x for w, x in zip(weights, d) if w != 0.0), s, *ks)


def dopri5_substep(f, s: FlockState, k1: FlockState, tau, h):
    """One Dormand–Prince 5(4) step of size ``h`` from time ``tau`` of ``ds/dt = f(s, tau)``,
    given ``k1 = f(s, tau)``. Returns ``(new state, its derivative, error estimate)``: the
    5th-order solution (local extrapolation), ``f`` at it (the next step's ``k1``), and the
    difference of the 5th- and 4th-order solutions (a FlockState)."""
    ks = [k1]
    for i in range(1, 7):
        ks.append(f(_combine(s, ks, h, _DP_A[i]), tau + _DP_C[i] * h))
    new = _combine(s, ks[:6], h, _DP_A[6])
    err = jax.tree.map(lambda *d: h * sum(w * x for w, x in zip(_DP_E, d) if w != 0.0), *ks)
    return new, ks[6], err


def closing_step(state: FlockState, adj, R, moving=None, to_radius=True):
    """``½ min (R − r_ij)/|ṙ_ij|`` over links and ``½ min r_ij/|ṙ_ij|`` over pairs (of nodes
    ``moving``, if given) at this state (ours): the longest step in which no linked pair closes
    half its gap to R, and no pair half its distance, at its current closing speed (+∞ if none
    closes). ``to_radius`` False: the distances only (the relaxation switch's faded potential
    lets a pair cross R, which the cap would approach in ever shorter steps)."""
    _, r, eye = pair_vectors(state.q)
    linked = (adj > 0.5) & ~eye
    pairs = ~eye if moving is None else ~eye & moving[:, None] & moving[None, :]
    dq = state.q[:, None, :] - state.q[None, :, :]
    dv = state.p[:, None, :] - state.p[None, :, :]
    rs = jnp.where(eye, 1.0, r)
    rate = jnp.sum(dq * dv, -1) / rs                                   # ṙ_ij
    to_r = jnp.where(linked & (rate > 0) & to_radius, (R - r) / jnp.where(rate > 0, rate, 1.0), jnp.inf)
    to_0 = jnp.where(pairs & (rate < 0), r / jnp.where(rate < 0, -rate, 1.0), jnp.inf)
    return 0.5 * jnp.minimum(jnp.min(to_r), jnp.min(to_0))


def _pair_rates(s: FlockState):
    """Pair distances r_ij and their rates ṙ_ij = (q_i − q_j)·(p_i − p_j)/r_ij."""
    d, r, eye = pair_vectors(s.q)
    dv = s.p[:, None, :] - s.p[None, :, :]
    return r, jnp.sum(d * dv, -1) / jnp.where(eye, 1.0, r)


def hermite_extremes(r0, v0, r1, v1, h):
    """Smallest and largest value over ``[0, h]`` of the cubic Hermite interpolant of ``r(t)``
    from its values ``r0, r1`` and rates ``v0, v1`` at both ends (elementwise; ours): the ends
    and the interior zeros of the cubic's derivative. Its error is O(h⁴ r⁗), so the extremes of
    a pair's distance between two sub-step ends are not missed."""
    a = 2.0 * (r0 - r1) + h * (v0 + v1)
    b = 3.0 * (r1 - r0) - h * (2.0 * v0 + v1)
    c = h * v0                                       # r(s) = a s³ + b s² + c s + r0, s ∈ [0, 1]
    disc = b * b - 3.0 * a * c
    root = jnp.where(disc > 0, jnp.sqrt(jnp.where(disc > 0, disc, 1.0)), 0.0)   # finite derivatives at 0
    qq = -(b + jnp.where(b >= 0, 1.0, -1.0) * root)
    safe_q = jnp.where(qq == 0, 1.0, qq)
    s1 = jnp.where(a == 0, 0.0, qq / jnp.where(a == 0, 1.0, 3.0 * a))
    s2 = jnp.where(qq == 0, 0.0, c / safe_q)          # the stable pair of roots of 3a s² + 2b s + c
    lo, hi = jnp.minimum(r0, r1), jnp.maximum(r0, r1)
    for s in (s1, s2):
        # the extreme's derivative does not depend on where it lies (zero slope there, or an end)
        s = jax.lax.stop_gradient(jnp.clip(jnp.where(jnp.isfinite(s), s, 0.0), 0.0, 1.0))
        v = ((a * s + b) * s + c) * s + r0
        lo, hi = jnp.minimum(lo, v), jnp.maximum(hi, v)
    return lo, hi


def dopri5_adaptive(state: FlockState, adj, sensing, reference, g: Gains, dt, max_substeps: int, tolerance,
                    moving=None, barrier=None, first_step=None):
    """Integrate the flock over ``dt`` at a fixed topology with the Dormand–Prince 5(4) pair and
    a step-size controller (ours; the paper leaves the integration open). A sub-step is accepted
    when its error estimate in every component — each position (m), velocity (m/s) and gain
    b_ij (1/s), absolute, max norm — is at most ``SUBSTEP_SHARE × tolerance`` (a tenth, so the
    whole step's error stays within ``tolerance``), and the next size is
    ``h · clip(0.9 (bound/err)^{1/5}, 0.2, 5)`` (no growth right after a rejection). A
    sub-step is also at most :func:`closing_step` (no linked pair closes half its gap to R,
    no pair half its distance, at its closing speed; with ``barrier``, whose faded potential
    lets a link cross R, the distances only), and one whose stages meet a link at or
    beyond R or two nodes at one point (the potential's slope is NaN there) is rejected and
    retried at a fifth of its size, so a link event is not stepped over. Over each accepted
    sub-step the smallest pair distance and link margin ``R − r_ij`` are taken from the cubic
    Hermite interpolant of each pair's distance (:func:`hermite_extremes`). The first size is
    ``first_step`` or :func:`stable_step`'s. At most ``max_substeps`` attempts (rejections
    count); the last allowed one takes whatever time is left (and the step is reported as
    capped). The sizes follow the error estimate's value, not its derivative (which turned
    NaN under XLA's unoptimised code): forward-mode derivatives are those of the sub-steps
    taken, within O(tolerance) of the derivative of the adaptive result. ``moving``,
    ``barrier``: as :func:`rk4_adaptive`. Returns ``(state,
    min_link_margin, min_distance, attempts, capped)``."""
    def f(s, tau):
        rq, rp = reference(tau)
        return derivative(s, adj, sensing, rq, rp, g, moving, barrier)

    dtype = state.q.dtype
    eye = jnp.eye(state.q.shape[0], dtype=bool)
    linked = (adj > 0.5) & ~eye
    apart = eye if moving is None else eye | ~(moving[:, None] & moving[None, :])
    tol = jnp.asarray(SUBSTEP_SHARE * tolerance, dtype)

    def cond(carry):
        return (carry[1] < dt) & (carry[3] < max_substeps)

    def body(carry):
        s, tau, h, k, margin, dmin, k1, r0, v0 = carry
        last = k == max_substeps - 1
        h = jnp.minimum(jnp.minimum(h, closing_step(s, adj, g.R, moving, barrier is None)), dt - tau)
        h = jnp.where(last | ~(h > 0), dt - tau, h)
        final = h >= dt - tau
        new, k_new, err = dopri5_substep(f, s, k1, tau, h)
        e = jnp.max(jnp.stack([jnp.max(jnp.abs(x)) for x in jax.tree.leaves(jax.lax.stop_gradient(err))])) / tol
        ok = jnp.isfinite(e) & jnp.all(jnp.isfinite(k_new.q)) & jnp.all(jnp.isfinite(k_new.p))
        accept = (ok & (e <= 1.0)) | last
        factor = jnp.where(ok, jnp.clip(0.9 * jnp.maximum(jnp.where(ok, e, 1.0), 1e-10) ** -0.2, 0.2, 5.0), 0.2)
        factor = jnp.where(accept, factor, jnp.minimum(factor, 1.0))
        r1, v1 = _pair_rates(new)
        lo, hi = hermite_extremes(r0, v0, r1, v1, h)
        margin_new = jnp.minimum(margin, jnp.min(jnp.where(linked, g.R - hi, jnp.inf)))
        dmin_new = jnp.minimum(dmin, jnp.min(jnp.where(apart, jnp.inf, lo)))
        pick = lambda a, b: jax.tree.map(lambda x, y: jnp.where(accept, x, y), a, b)  # noqa: E731
        s, k1, r0, v0, margin, dmin = pick((new, k_new, r1, v1, margin_new, dmin_new), (s, k1, r0, v0, margin, dmin))
        # a non-finite accepted state (only at the cap) ends the step: its NaN margin flags it
        tau = jnp.where(accept, jnp.where(jnp.all(jnp.isfinite(s.q)) & ~final, tau + h, dt), tau)
        return s, tau, h * factor, k + 1, margin, dmin, k1, r0, v0

    h0 = stable_step(state, adj, sensing, g) if first_step is None else first_step
    inf = jnp.asarray(jnp.inf, dtype)
    r0, v0 = _pair_rates(state)
    carry = (state, jnp.asarray(0.0, dtype), jnp.asarray(h0, dtype), jnp.asarray(0, jnp.int32), inf, inf,
             f(state, jnp.asarray(0.0, dtype)), r0, v0)
    state, tau, _, k, margin, dmin, *_ = jax.lax.while_loop(cond, body, carry)
    fine = jnp.all(jnp.isfinite(state.q))
    return state, jnp.where(fine, margin, jnp.nan), jnp.where(fine, dmin, jnp.nan), k, k >= max_substeps
