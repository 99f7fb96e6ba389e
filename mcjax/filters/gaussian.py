"""Gaussian filter steps in moment and information form (EKF flavour).

Every function works on one run; agents sit on a leading axis where noted. Jacobians come
from ``jax.jacfwd`` of the measurement function (design.md, Numerics), never from
hand-typed formulas.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from mcjax.numerics import matmul, matvec, quad, spd_inverse, symmetrize, wrap_angle

MeasurementFn = Callable[[jax.Array, jax.Array], jax.Array]


class Gaussian(NamedTuple):
    """A posterior in both forms: mean ``x``, covariance ``P`` and information ``Y = P⁻¹``."""

    x: jax.Array
    P: jax.Array
    Y: jax.Array


def predict_moments(x, P, F, Q):
    """Moment-form prediction ``x̄ = F x``, ``P̄ = F P Fᵀ + Q`` (seed 000 eq. 1)."""
    return matvec(F, x), symmetrize(quad(F, P) + Q)


def predict_information(x, P, F, Q):
    """Information-filter prediction in the stable form of algorithms.md §2.

    Seed 000 eq. 8: ``Y⁻ = (F Y⁻¹ Fᵀ + G Q Gᵀ)⁻¹``, ``y⁻ = Y⁻ F x``. Carrying the previous
    posterior as ``(x, P)`` avoids the inverse of ``Y``; the one inverse left is an SPD
    Cholesky inverse. Returns ``(x̄, P̄, ȳ, Ȳ)``.
    """
    xb, Pb = predict_moments(x, P, F, Q)
    Yb = symmetrize(spd_inverse(Pb))
    return xb, Pb, matvec(Yb, xb), Yb


def information_contribution(h: MeasurementFn, z, sensor, x_lin, R_inv, angle_mask):
    """One sensor's information contribution ``(i, I)`` linearised at ``x_lin``.

    algorithms.md §2 (corrected seed 000 eq. 10):
    ``i = Hᵀ R⁻¹ (z − h(x̄) + H x̄)``, ``I = Hᵀ R⁻¹ H`` with ``H = ∂h/∂x (x̄)`` by autodiff and
    the angle components of the innovation (``angle_mask``) wrapped to (−π, π]. A
    measurement with any non-finite component contributes ``(0, 0)`` (out of range, not
    alive, or shadowed). Shapes: ``z`` (m,), ``x_lin`` (d,), ``R_inv`` (m, m).
    """
    valid = jnp.all(jnp.isfinite(z))
    z_safe = jnp.where(valid, z, 0.0)
    predicted = h(x_lin, sensor)
    H = jax.jacfwd(h)(x_lin, sensor)
    nu = z_safe - predicted
    nu = jnp.where(angle_mask, wrap_angle(nu), nu)
    HtRinv = matmul(H.T, R_inv)
    i = matvec(HtRinv, nu + matvec(H, x_lin))
    I = symmetrize(matmul(HtRinv, H))
    return jnp.where(valid, i, 0.0), jnp.where(valid, I, 0.0), valid


def contributions(h: MeasurementFn, z, sensors, x_lin, R_inv, angle_mask):
    """:func:`information_contribution` for every agent: ``z`` (n, m), ``sensors`` (n, ·),
    ``x_lin`` (n, d) or (d,) (one shared linearisation point), ``R_inv`` (n, m, m)."""
    x_axis = 0 if x_lin.ndim == 2 else None

    def one(z_i, s_i, x_i, r_i):
        return information_contribution(h, z_i, s_i, x_i, r_i, angle_mask)

    return jax.vmap(one, in_axes=(0, 0, x_axis, 0))(z, sensors, x_lin, R_inv)


def from_information(y, Y) -> Gaussian:
    """Moment form of an information pair: ``P = Y⁻¹``, ``x = P y`` (seed 000 eq. 12)."""
    Y = symmetrize(Y)
    P = symmetrize(spd_inverse(Y))
    return Gaussian(matvec(P, y), P, Y)
