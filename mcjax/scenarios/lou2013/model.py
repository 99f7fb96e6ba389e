"""Connectivity-preserving flocking of double integrators — Lou, Cui & Li 2013.

Nodes ``i = 1 … N`` are double integrators ``q̇_i = p_i, ṗ_i = u_i`` (eq. 1) in the plane. The
first ``M`` (type I, ``h_i = 1``) sense the target and steer by their own estimate of it
(eq. 10); the others (type II, ``h_i = 0``) align their velocity with their neighbours'
through adaptive gains ``b_ij`` (eq. 11). Both use the pairwise potential of eq. 12 over the
links of the hysteresis graph:

    ψ(r) = 1/r² + r²/(R − r),   r ∈ (0, R)

which grows without bound as two linked nodes approach each other (no collision) or the
communication radius R (no link breaks). Eq. 13 writes both controllers as one:

    u_i = −Σ_{j∈N_i} ∇_{q_i} ψ(‖q_i − q_j‖) − (1 − h_i) Σ_{j∈N_i} b_ij (p_i − p_j)
          − h_i [c1 (q_i − q̂_i) + c2 (p_i − p̂_i)],      ḃ_ij = k_ij ‖p_i − p_j‖²  (type II rows)

and eqs. 14–15 define the energy whose decrease the paper's Theorem 2 proves (its flocking
part φ is :func:`energy`; the estimation term ``k/(2μ) V(η)`` belongs to the continuous-time
KCF of eq. 6 and is not computed: it is 0 when the controller is fed the true target).

Everything is pure and vmappable; positions are (N, 2), the adjacency (N, N) 0/1.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp


class FlockState(NamedTuple):
    q: jax.Array  # (N, 2) positions
    p: jax.Array  # (N, 2) velocities
    b: jax.Array  # (N, N) adaptive gains b_ij (used on type-II rows)


class Gains(NamedTuple):
    """Controller constants: ``c1, c2`` (eq. 10), ``k`` the adaptation rate k_ij (eq. 11, one
    value for every pair), ``R`` the communication radius of eq. 12."""

    c1: jax.Array
    c2: jax.Array
    k: jax.Array
    R: jax.Array


def potential(r, R):
    """ψ(r) = 1/r² + r²/(R − r) on (0, R) (Lou et al. 2013, eq. 12); +∞ outside."""
    inside = (r > 0) & (r < R)
    rs = jnp.where(inside, r, R / 2)
    return jnp.where(inside, 1.0 / rs**2 + rs**2 / (R - rs), jnp.inf)


def potential_slope(r, R):
    """ψ′(r) = −2/r³ + r (2R − r)/(R − r)² (exact derivative of eq. 12) on (0, R); NaN
    outside (a link at or beyond R, or two nodes on top of each other, is a broken run)."""
    inside = (r > 0) & (r < R)
    rs = jnp.where(inside, r, R / 2)
    return jnp.where(inside, -2.0 / rs**3 + rs * (2.0 * R - rs) / (R - rs) ** 2, jnp.nan)


def faded_potential(r, R, width):
    """The relaxation switch's version of eq. 12 (ours): ``ψ_w(r) = g((R − r)/w) ψ(r)`` with
    ``g(u) = 1 − exp(−u⁴)`` for ``u > 0`` and 0 beyond R, so the potential of a link fades out
    within a few ``w`` of R instead of growing without bound there: ``ψ_w`` is 0 at and beyond R,
    twice continuously differentiable at R (``ψ_w ≈ R² (R − r)³ / w⁴``), and equal to ψ in
    floating point wherever ``R − r > 2.5 w`` (``u⁴ > 37``). NaN at ``r ≤ 0``."""
    inside = (r > 0) & (r < R)
    rs = jnp.where(inside, r, R / 2)
    g = -jnp.expm1(-(((R - rs) / width) ** 4))
    return jnp.where(inside, g * (1.0 / rs**2 + rs**2 / (R - rs)), jnp.where(r > 0, 0.0, jnp.nan))


def faded_potential_slope(r, R, width):
    """``ψ_w′(r) = g ψ′(r) − ψ(r) · 4u³ exp(−u⁴) / w``, ``u = (R − r)/w``: the exact derivative
    of :func:`faded_potential` (ours); 0 at and beyond R, NaN at ``r ≤ 0``."""
    inside = (r > 0) & (r < R)
    rs = jnp.where(inside, r, R / 2)
    u = (R - rs) / width
    e = jnp.exp(-(u**4))
    psi = 1.0 / rs**2 + rs**2 / (R - rs)
    slope = -jnp.expm1(-(u**4)) * (-2.0 / rs**3 + rs * (2.0 * R - rs) / (R - rs) ** 2) - psi * 4.0 * u**3 * e / width
    return jnp.where(inside, slope, jnp.where(r > 0, 0.0, jnp.nan))


def pair_vectors(q):
    """``(q_i − q_j, r_ij, eye)`` of positions ``q`` (N, 2): the pair differences (N, N, 2), the
    distances (N, N) with 0 on the diagonal, and the diagonal mask."""
    d = q[:, None, :] - q[None, :, :]                  # q_i − q_j
    n = q.shape[0]
    eye = jnp.eye(n, dtype=bool)
    r2 = jnp.sum(d * d, -1)
    r = jnp.sqrt(jnp.where(eye, 1.0, r2))
    return d, jnp.where(eye, 0.0, r), eye


def potential_forces(q, adj, R, barrier=None):
    """``−Σ_{j∈N_i} ∇_{q_i} ψ(‖q_i − q_j‖) = −Σ_j a_ij ψ′(r_ij) (q_i − q_j)/r_ij`` (eqs. 10–12),
    (N, 2). Non-linked pairs contribute nothing (whatever their distance). ``barrier`` (the
    relaxation switch, ours; None: exact): the links' weights ``a_ij`` in [0, 1] multiply the
    faded potential's slope (:func:`faded_potential_slope` of width ``barrier``), so every pair
    contributes, finitely at any distance."""
    d, r, eye = pair_vectors(q)
    if barrier is not None:
        w = jnp.where(eye, 0.0, adj)
        rr = jnp.where(eye, R / 2, r)
        coef = jnp.where(w > 0, w * faded_potential_slope(rr, R, barrier) / rr, 0.0)
        return -jnp.sum(coef[..., None] * d, axis=1)
    linked = (adj > 0.5) & ~eye
    slope = potential_slope(jnp.where(linked, r, R / 2), R)
    coef = jnp.where(linked, slope / jnp.where(linked, r, 1.0), 0.0)
    return -jnp.sum(coef[..., None] * d, axis=1)


def controls(state: FlockState, adj, sensing, ref_q, ref_p, g: Gains, barrier=None):
    """Eq. 13 (eqs. 10 and 11 in one): ``sensing`` (N,) is h_i ∈ {0, 1}; ``ref_q``, ``ref_p``
    (N, 2) are each type-I node's target position and velocity (its estimate). Returns u (N, 2).
    ``barrier``: the relaxation switch's soft links (:func:`potential_forces`)."""
    h = sensing[:, None]
    linked = adj * (1.0 - jnp.eye(adj.shape[0], dtype=adj.dtype))
    dp = state.p[:, None, :] - state.p[None, :, :]
    align = jnp.sum((state.b * linked)[..., None] * dp, axis=1)
    track = g.c1 * (state.q - ref_q) + g.c2 * (state.p - ref_p)
    return potential_forces(state.q, adj, g.R, barrier) - (1.0 - h) * align - h * track


def derivative(state: FlockState, adj, sensing, ref_q, ref_p, g: Gains, moving=None, barrier=None) -> FlockState:
    """Time derivative of the flock (eqs. 1, 11, 13): ``(p, u, ḃ)`` with
    ``ḃ_ij = k ‖p_i − p_j‖²`` on the links of type-II rows (0 elsewhere). ``moving`` (N,)
    bool, optional: the nodes not in it are frozen (derivative 0, whatever their control; a node
    lost to faults, which has no link). ``barrier``: the relaxation switch's soft links
    (:func:`potential_forces`; the weights also scale ḃ and the alignment)."""
    u = controls(state, adj, sensing, ref_q, ref_p, g, barrier)
    dp = state.p[:, None, :] - state.p[None, :, :]
    linked = adj * (1.0 - jnp.eye(adj.shape[0], dtype=adj.dtype))
    bdot = g.k * jnp.sum(dp * dp, -1) * linked * (1.0 - sensing)[:, None]
    if moving is None:
        return FlockState(state.p, u, bdot)
    m = moving[:, None]
    return FlockState(jnp.where(m, state.p, 0.0), jnp.where(m, u, 0.0), jnp.where(m, bdot, 0.0))


def potential_curvature(r, R):
    """ψ″(r) = 6/r⁴ + 2R²/(R − r)³ (exact second derivative of eq. 12) on (0, R); +∞ outside."""
    inside = (r > 0) & (r < R)
    rs = jnp.where(inside, r, R / 2)
    return jnp.where(inside, 6.0 / rs**4 + 2.0 * R**2 / (R - rs) ** 3, jnp.inf)


def energy(state: FlockState, adj, sensing, target_q, target_p, g: Gains, l, nodes=None, barrier=None):
    """The flocking energy φ of Lou et al. 2013, eq. 15:
    ``½ Σ_i [Σ_{j∈N_i} ψ(‖q_i − q_j‖) + h_i c1 ‖q_i − q_γ‖² + ‖p_i − p_γ‖²
    + Σ_{j∈N_i} (1 − h_i)(b_ij − l)²/(2 k_ij)]`` for the true target ``(q_γ, p_γ)`` (2,) each.
    Eq. 16 takes ``l = c2``. +∞ if a link is at or beyond R. ``nodes`` (N,) bool, optional:
    the sum over i runs over these nodes only (the flock less the nodes lost to faults).
    ``barrier`` (the relaxation switch, ours): each pair's terms weighted by its soft link
    ``a_ij``, with the faded potential (:func:`faded_potential`)."""
    _, r, eye = pair_vectors(state.q)
    h = sensing
    if barrier is None:
        linked = (adj > 0.5) & ~eye
        psi = jnp.where(linked, potential(jnp.where(linked, r, g.R / 2), g.R), 0.0)
        pair_gains = jnp.where(linked, (state.b - l) ** 2, 0.0)
    else:
        w = jnp.where(eye, 0.0, adj)
        psi = jnp.where(w > 0, w * faded_potential(jnp.where(eye, g.R / 2, r), g.R, barrier), 0.0)
        pair_gains = w * (state.b - l) ** 2
    U = jnp.sum(psi, axis=1) + h * g.c1 * jnp.sum((state.q - target_q) ** 2, -1)
    kin = jnp.sum((state.p - target_p) ** 2, -1)
    gains = jnp.sum(pair_gains, axis=1) * (1.0 - h) / (2.0 * g.k)
    if nodes is None:
        return 0.5 * jnp.sum(U + kin + gains)
    return 0.5 * jnp.sum(jnp.where(nodes, U + kin + gains, 0.0))
