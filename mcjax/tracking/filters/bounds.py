"""The posterior Cramér–Rao bound (PCRB): the error floor of any filter of the same measurements.

Tichavský, Muravchik & Nehorai 1998 give the Fisher information ``J_k`` of the state at step k as a
recursion. For linear Gaussian dynamics ``x_{k+1} = F x_k + w_k``, ``w_k ~ N(0, Q)``, their eq. 21
(``D11 = FᵀQ⁻¹F``, ``D12 = −FᵀQ⁻¹``, ``D22 = Q⁻¹ + J_z``) becomes, by the matrix inversion lemma,

    J_{k+1} = (Q + F J_k⁻¹ Fᵀ)⁻¹ + J_z,k+1 ,        J_z = E[ Hᵀ R⁻¹ H ]

(:func:`pcrb_step`), which needs no inverse of Q, so a singular Q (a white-acceleration model
driven per axis by one noise) is allowed. The same recursion on the bound's covariance ``C = J⁻¹``,

    C⁻ = F C Fᵀ + Q ,        C' = (I + C⁻ J_z)⁻¹ C⁻

(:func:`pcrb_covariance_step`; the two are equal by the matrix inversion lemma wherever J is
invertible), also allows a singular ``C`` — a state known exactly, e.g. an initial state the
filters are given (``C₀ = 0``), or one with no information yet along some direction. ``J_z`` is the information of the measurements taken at
k + 1: for an additive Gaussian measurement ``z = h(x) + v``, ``v ~ N(0, R)``, it is the expectation
of ``Hᵀ R⁻¹ H`` with H the Jacobian of h at the true state (:func:`measurement_information`); the
information of several independent measurements adds (:func:`pcrb_step` takes their sum).

Evaluated along each run's true trajectory and averaged over the runs, ``J_z`` is the Monte-Carlo
estimate of the expectation over the point's trajectories; a bound computed along one run is the
conditional bound given that trajectory (and, in closed loop, given the sensors' paths; Zuo, Niu &
Varshney 2011). For a linear measurement the recursion is the information filter's, so the bound is
the Kalman filter's covariance (tested to 1e-9).

Pure JAX, batched over leading axes.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mcjax.tracking.numerics import spd_inverse


def pcrb_step(J, F, Q, J_meas):
    """One step of the Tichavský et al. 1998 recursion (eq. 21) for linear Gaussian dynamics:
    ``J' = (Q + F J⁻¹ Fᵀ)⁻¹ + J_meas`` (module docstring). ``J`` (…, n, n) the information of
    the state now, ``F``, ``Q`` (n, n) the dynamics, ``J_meas`` (…, n, n) the information of the
    measurements taken at the next step (0 when none)."""
    prior = Q + F @ spd_inverse(J) @ F.T
    return spd_inverse(prior) + J_meas


def pcrb_covariance_step(C, F, Q, J_meas):
    """:func:`pcrb_step` on the bound's covariance ``C = J⁻¹`` (module docstring):
    ``C' = (I + C⁻ J_meas)⁻¹ C⁻`` with ``C⁻ = F C Fᵀ + Q``; ``C`` may be singular (0: the state
    known exactly). Batched over leading axes of ``C`` and ``J_meas``."""
    prior = F @ C @ F.T + Q
    eye = jnp.eye(C.shape[-1], dtype=C.dtype)
    post = jnp.linalg.solve(eye + prior @ J_meas, prior)
    return 0.5 * (post + jnp.swapaxes(post, -1, -2))


def measurement_information(h, x, R_inverse, taken=True):
    """``Hᵀ R⁻¹ H`` of an additive Gaussian measurement ``z = h(x) + v`` at the true state ``x``
    (H = ∂h/∂x by ``jax.jacfwd``), 0 where the measurement was not ``taken`` (gated out, dropped,
    no line of sight): the Fisher information it adds to the bound (Tichavský et al. 1998, eq. 34)."""
    H = jax.jacfwd(h)(x)
    info = H.T @ R_inverse @ H
    return jnp.where(jnp.asarray(taken), info, jnp.zeros_like(info))


def pcrb(J0, F, Q, J_meas):
    """The bound over a run: ``J0`` (n, n) the prior information, ``J_meas`` (T, n, n) the
    measurements' information per step; returns the bound's covariance ``J_k⁻¹`` per step (T, n, n),
    step k after the measurements of step k (the first step predicts from ``J0``)."""
    def body(J, Jz):
        J = pcrb_step(J, F, Q, Jz)
        return J, spd_inverse(J)

    return jax.lax.scan(body, J0, J_meas)[1]
