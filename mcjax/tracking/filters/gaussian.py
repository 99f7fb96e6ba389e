"""Gaussian filter steps in moment and information form (EKF flavour).

Every function works on one run; agents sit on a leading axis where noted. Jacobians come
from ``jax.jacfwd`` of the measurement function (docs/architecture.md), never from
hand-typed formulas.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from mcjax.tracking.numerics import matmul, matvec, quad, spd_inverse, symmetrize, wrap_angle

MeasurementFn = Callable[[jax.Array, jax.Array], jax.Array]


class Gaussian(NamedTuple):
    """A posterior in both forms: mean ``x``, covariance ``P`` and information ``Y = P⁻¹``."""

    x: jax.Array
    P: jax.Array
    Y: jax.Array


def first_step_model(first, F, Q):
    """The ``(F, Q)`` of a step, or ``(I, 0)`` at the first measurement time, where the prior
    is updated without predicting (the filters' timing convention, docs/equations.md)."""
    return jnp.where(first, jnp.eye(F.shape[-1], dtype=F.dtype), F), jnp.where(first, 0.0, Q)


def predict_moments(x, P, F, Q):
    """Moment-form prediction ``x̄ = F x``, ``P̄ = F P Fᵀ + Q`` (Sun et al. 2011 eq. 1)."""
    return matvec(F, x), symmetrize(quad(F, P) + Q)


def predict_information(x, P, F, Q):
    """Information-filter prediction in the stable form of docs/equations.md.

    Sun et al. 2011 eq. 8 with the inverse of ``Y`` its print omits: ``Y⁻ = (F Y⁻¹ Fᵀ + G Q Gᵀ)⁻¹``,
    ``y⁻ = Y⁻ F x``. Carrying the previous
    posterior as ``(x, P)`` avoids the inverse of ``Y``; the one inverse left is an SPD
    Cholesky inverse. Returns ``(x̄, P̄, ȳ, Ȳ)``.
    """
    xb, Pb = predict_moments(x, P, F, Q)
    Yb = symmetrize(spd_inverse(Pb))
    return xb, Pb, matvec(Yb, xb), Yb


def information_contribution(h: MeasurementFn, z, sensor, x_lin, R_inv, angle_mask):
    """One sensor's information contribution ``(i, I)`` linearised at ``x_lin``.

    docs/equations.md (corrected Sun et al. 2011 eq. 10):
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
    """Moment form of an information pair: ``P = Y⁻¹``, ``x = P y`` (Sun et al. 2011 eq. 12)."""
    Y = symmetrize(Y)
    P = symmetrize(spd_inverse(Y))
    return Gaussian(matvec(P, y), P, Y)


# --------------------------------------------------------------------------- unscented


class Unscented(NamedTuple):
    """Scaling of the unscented transform (Julier & Uhlmann; Wan & van der Merwe's α, β, κ)."""

    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0
    jitter: float = 1e-12  # added to the diagonal (relative to its mean) before the Cholesky


def sigma_points(x, P, ut: Unscented = Unscented()):
    """The 2d+1 scaled sigma points and their mean / covariance weights (docs/equations.md).

    ``χ_0 = x``, ``χ_{±k} = x ± (√((d+λ)(P + εI)))_k`` with ``λ = α²(d+κ) − d``, the matrix
    square root a lower Cholesky factor and ε = ``jitter`` × mean diagonal of P.
    Returns ``(χ (2d+1, d), W_m (2d+1,), W_c (2d+1,))``."""
    d = x.shape[-1]
    lam = ut.alpha**2 * (d + ut.kappa) - d
    eps = ut.jitter * jnp.trace(P) / d
    L = jnp.linalg.cholesky(symmetrize(P) + eps * jnp.eye(d, dtype=P.dtype))
    S = jnp.sqrt(d + lam) * L
    chi = jnp.concatenate([x[None], x + S.T, x - S.T])
    wm = jnp.full(2 * d + 1, 0.5 / (d + lam), dtype=x.dtype).at[0].set(lam / (d + lam))
    wc = wm.at[0].add(1.0 - ut.alpha**2 + ut.beta)
    return chi, wm, wc


def unscented_transform(f: Callable, x, P, ut: Unscented = Unscented(), angle_mask=None):
    """Mean, covariance and cross-covariance of ``y = f(x)`` for ``x ~ N(x, P)`` by the
    unscented transform (docs/equations.md). Components of ``y`` flagged in ``angle_mask``
    are averaged as angles (residuals wrapped about the central point).
    Returns ``(ȳ, P_yy, P_xy)``."""
    chi, wm, wc = sigma_points(x, P, ut)
    Y = jax.vmap(f)(chi)
    dY = Y - Y[0]
    if angle_mask is not None:
        dY = jnp.where(angle_mask, wrap_angle(dY), dY)
    y_mean = Y[0] + wm @ dY
    r = dY - (y_mean - Y[0])
    if angle_mask is not None:
        r = jnp.where(angle_mask, wrap_angle(r), r)
        y_mean = jnp.where(angle_mask, wrap_angle(y_mean), y_mean)
    dx = chi - x
    P_yy = symmetrize((wc[:, None] * r).T @ r)
    P_xy = (wc[:, None] * dx).T @ r
    return y_mean, P_yy, P_xy


def ukf_predict(x, P, f: Callable, Q, ut: Unscented = Unscented()):
    """UKF prediction ``x̄, P̄ = UT(f)(x, P) + (0, Q)`` (docs/equations.md)."""
    xb, Pb, _ = unscented_transform(f, x, P, ut)
    return xb, symmetrize(Pb + Q)


def gaussian_loglik(nu, S):
    """``log N(ν; 0, S)`` via a Cholesky factor (IMM mode likelihood, docs/equations.md)."""
    L = jnp.linalg.cholesky(S)
    w = jax.scipy.linalg.solve_triangular(L, nu, lower=True)
    m = nu.shape[-1]
    return -0.5 * (w @ w) - jnp.sum(jnp.log(jnp.diag(L))) - 0.5 * m * jnp.log(2.0 * jnp.pi)


def ukf_update(x, P, z, h: Callable, R, ut: Unscented = Unscented(), angle_mask=None):
    """UKF measurement update in moment form (docs/equations.md).

    ``K = P_xz S⁻¹`` with ``S = P_zz + R``; ``x⁺ = x + K ν``, ``P⁺ = P − K S Kᵀ``. A
    measurement with a non-finite component leaves the state unchanged (log-likelihood 0).
    Returns ``(x⁺, P⁺, log N(ν; 0, S))``."""
    valid = jnp.all(jnp.isfinite(z))
    zh, Pzz, Pxz = unscented_transform(h, x, P, ut, angle_mask)
    S = symmetrize(Pzz + R)
    nu = jnp.where(valid, z, zh) - zh
    if angle_mask is not None:
        nu = jnp.where(angle_mask, wrap_angle(nu), nu)
    K = jnp.linalg.solve(S, Pxz.T).T
    x_new = x + K @ nu
    P_new = symmetrize(P - K @ S @ K.T)
    ll = gaussian_loglik(nu, S)
    return (jnp.where(valid, x_new, x), jnp.where(valid, P_new, P), jnp.where(valid, ll, 0.0))


def ekf_update(x, P, z, h: Callable, R, angle_mask=None):
    """EKF measurement update in moment form, returning the mode likelihood an IMM needs
    (docs/equations.md; the mode-matched filter of Chen & Hao 2022's LOS/NLOS IMM-EKF).

    ``H = ∂h/∂x (x̄)`` by autodiff, ``S = H P Hᵀ + R``, ``K = P Hᵀ S⁻¹``, ``x⁺ = x + K ν``,
    ``P⁺ = P − K S Kᵀ``, with the angle components of ``ν`` wrapped. A measurement with a
    non-finite component leaves the state unchanged (log-likelihood 0).
    Returns ``(x⁺, P⁺, log N(ν; 0, S))``."""
    valid = jnp.all(jnp.isfinite(z))
    zh = h(x)
    H = jax.jacfwd(h)(x)
    nu = jnp.where(valid, z, zh) - zh
    if angle_mask is not None:
        nu = jnp.where(angle_mask, wrap_angle(nu), nu)
    PHt = P @ H.T
    S = symmetrize(H @ PHt + R)
    K = jnp.linalg.solve(S, PHt.T).T
    x_new = x + K @ nu
    P_new = symmetrize(P - K @ S @ K.T)
    ll = gaussian_loglik(nu, S)
    return (jnp.where(valid, x_new, x), jnp.where(valid, P_new, P), jnp.where(valid, ll, 0.0))


def ukf_pseudo_measurement(x_pred, P_pred, z, h: Callable, R_inv, ut: Unscented = Unscented(),
                           angle_mask=None):
    """Information contribution ``(i, I)`` of one UKF measurement for consensus (docs/equations.md,
    Ren & Lv 2017): with ``H̃ = (P̄⁻¹ P_xz)ᵀ``, ``i = H̃ᵀ R⁻¹ (ν + H̃ x̄)`` and ``I = H̃ᵀ R⁻¹ H̃``.
    A non-finite measurement contributes ``(0, 0)``."""
    valid = jnp.all(jnp.isfinite(z))
    zh, _, Pxz = unscented_transform(h, x_pred, P_pred, ut, angle_mask)
    Ht = jnp.linalg.solve(P_pred, Pxz).T
    nu = jnp.where(valid, z, zh) - zh
    if angle_mask is not None:
        nu = jnp.where(angle_mask, wrap_angle(nu), nu)
    HtRinv = Ht.T @ R_inv
    i = HtRinv @ (nu + Ht @ x_pred)
    I = symmetrize(HtRinv @ Ht)
    return jnp.where(valid, i, 0.0), jnp.where(valid, I, 0.0), valid
