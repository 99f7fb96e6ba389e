"""The IMM-EKF of Chen & Hao 2022 (eqs. 2, 11–12) over the measurement modes LOS, NLOS+ and
NLOS− (a single LOS EKF for ``Config.filters`` ``"ekf"``), its gated form for the training
surrogate, and each filter's NIS of the measurement against its own prediction (``consistency =
"on"``, :func:`filter_nis`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mcjax.tracking import metrics
from mcjax.tracking.filters.gaussian import ekf_update
from mcjax.tracking.filters.imm import imm_step, mix
from mcjax.tracking.models.sensors import azimuth
from mcjax.tracking.numerics import symmetrize, wrap_angle


def mode_models(params, name: str):
    """Per-mode (bias, σ) of a filter (eqs. 11–12): the IMM's LOS, NLOS+, NLOS− or the
    single LOS EKF."""
    if name == "imm":
        bias = jnp.stack([params.bias_los, params.bias_nlos, -params.bias_nlos])
        sigma = jnp.stack([params.sigma_los, params.sigma_nlos, params.sigma_nlos])
    else:
        bias, sigma = params.bias_los[None], params.sigma_los[None]
    return bias, sigma


def mode_filter(x, P, model, z, uav, q):
    """Mode-matched EKF (eqs. 2, 11–12): predict the static target (``P + q² I``), update with
    the azimuth biased by the mode's mean."""
    bias, sigma = model
    P = symmetrize(P + q**2 * jnp.eye(2, dtype=P.dtype))

    def h(xy):
        return (azimuth(xy, uav) + bias)[None]

    return ekf_update(x, P, z[None], h, (sigma**2)[None, None], angle_mask=jnp.array([True]))


#: Weight of a measurement in deep shadow (the soft gate never reaches 0, so R/g stays finite).
GATE_FLOOR = 1e-9


def gated_mode_filter(x, P, model, z, uav, q, gate):
    """:func:`mode_filter` (Chen & Hao 2022, eqs. 2, 11–12) for a measurement of weight
    ``gate`` ∈ (0, 1] (the smooth line of sight): the update with the tempered likelihood
    ``p(z|x)^g``, i.e. the EKF with noise ``σ²/g``, and its mode likelihood
    ``log N(ν; 0, S_g) + ½ log(2πσ²/g) − (g/2) log(2πσ²)`` — the IMM's eq. 12 likelihood at
    g = 1, and 0 (no information, as the exact filter's skipped update) as g → 0."""
    bias, sigma = model
    P = symmetrize(P + q**2 * jnp.eye(2, dtype=P.dtype))
    var = sigma**2

    def h(xy):
        return (azimuth(xy, uav) + bias)[None]

    x, P, ll = ekf_update(x, P, z[None], h, (var / gate)[None, None], angle_mask=jnp.array([True]))
    two_pi_var = 2.0 * jnp.pi * var
    return x, P, ll + 0.5 * jnp.log(two_pi_var / gate) - 0.5 * gate * jnp.log(two_pi_var)


def _transition(p, name, first, dtype):
    """A filter's mode chain (the IMM's, or the EKF's single mode); the identity at the first step."""
    m = mode_models(p, name)[0].shape[0]
    transition = p.imm_transition if m == 3 else jnp.ones((1, 1), dtype)
    return jnp.where(first, jnp.eye(m, dtype=dtype), transition)


def mixture_nis(fstate, transition, model, z, uav, q, gate=1.0):
    """The NIS of the azimuth ``z`` against a filter's own prediction of it (Bar-Shalom, Li &
    Kirubarajan 2001, §5.4.2), NaN without a measurement. The IMM's modes differ in the
    measurement (bias, σ), not in the motion, so its predicted measurement is a mixture: each mode
    j, mixed (:func:`mcjax.tracking.filters.imm.mix`) and predicted as the filter does (``P + q² I``),
    predicts ``ẑ_j = η(x̄_j) + b_j`` with ``S_j = H_j P̄_j H_jᵀ + σ_j²/gate`` and weight c̄_j. The
    NIS is that of the mixture's first two moments: ``ν = Σ c̄_j ν_j`` (``ν_j = wrap(z − ẑ_j)``),
    ``S = Σ c̄_j (S_j + (ν_j − ν)²)``, ``NIS = ν² / S`` — its mean is 1 when the filter is
    consistent (its distribution is χ²(1) only for one mode: the EKF's NIS, or an IMM sure of its
    mode). For the single-mode EKF it is :func:`mcjax.scenarios.kit.consistency.predicted_nis`
    with ``F = I``, ``Q = q² I``. ``gate``: the smooth step's measurement weight (1: exact)."""
    cbar, x0, P0 = mix(fstate, transition)
    valid = jnp.isfinite(z)
    zz = jnp.where(valid, z, 0.0)

    def one(x, P, bias, sigma):
        Pb = symmetrize(P + q**2 * jnp.eye(2, dtype=P.dtype))
        H = jax.grad(lambda xy: azimuth(xy, uav))(x)
        nu = wrap_angle(zz - azimuth(x, uav) - bias)
        return nu, H @ Pb @ H + sigma**2 / gate

    nu, S = jax.vmap(one)(x0, P0, *model)
    nu_bar = cbar @ nu
    S_bar = cbar @ (S + (nu - nu_bar) ** 2)
    return jnp.where(valid, metrics.nis(nu_bar[None], (1.0 / S_bar)[None, None]), jnp.nan)


def filter_nis(cfg, p, state, z, uav, gate=1.0):
    """Every configured filter's :func:`mixture_nis` of this step's measurement ``z``, before its
    update, as (F, 1) (one UAV)."""
    dtype = jnp.dtype(cfg.dtype)
    return jnp.stack([mixture_nis(fstate, _transition(p, name, state.t == 0, dtype), mode_models(p, name), z, uav,
                                  p.process_noise, gate)
                      for name, fstate in zip(cfg.filters, state.filters)])[:, None]


def filter_bank(cfg, p, state, update, z, uav, *gate):
    """Every configured filter's IMM cycle (eqs. 11–12; one mode for the single-model EKF) on
    the measurement ``z``, each mode updated by ``update`` (:func:`mode_filter`, or
    :func:`gated_mode_filter` with the surrogate's measurement weight ``gate``); returns the
    new filter states and each filter's position error."""
    dtype = jnp.dtype(cfg.dtype)
    first = state.t == 0
    new_filters, errors = [], []
    for name, fstate in zip(cfg.filters, state.filters):
        bias, sg = mode_models(p, name)
        m = bias.shape[0]
        transition = p.imm_transition if m == 3 else jnp.ones((1, 1), dtype)
        transition = jnp.where(first, jnp.eye(m, dtype=dtype), transition)
        fnew, (x, _) = imm_step(fstate, transition, update, (bias, sg), z, uav, p.process_noise, *gate)
        new_filters.append(fnew)
        errors.append(jnp.sqrt(jnp.sum((x - p.emitter[:2]) ** 2))[None])
    return new_filters, errors
