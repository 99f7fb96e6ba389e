"""Interacting multiple model filter, generic over the mode-matched filter (docs/equations.md).

Blom & Bar-Shalom 1988, as used by Ren & Lv 2017 (IMM-UKF) and Chen & Hao 2022 (LOS/NLOS IMM-EKF).
One IMM cycle is :func:`mix` → each mode's predict + update (any function returning the
mode's new mean, covariance and measurement log-likelihood) → :func:`mode_probabilities`
(in log space) → :func:`combine`. Modes sit on a leading axis; the per-mode filter runs
under ``vmap`` with its per-mode parameters (e.g. each mode's F and Q) stacked on that axis.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from mcjax.tracking.numerics import symmetrize


class IMMState(NamedTuple):
    mu: jax.Array  # (M,) mode probabilities
    x: jax.Array   # (M, d) mode-matched means
    P: jax.Array   # (M, d, d) mode-matched covariances


def mix(state: IMMState, transition):
    """Mixing step: ``c̄_j = Σ_l p_lj μ_l``, ``μ_{l|j} = p_lj μ_l / c̄_j``,
    ``x⁰ʲ = Σ_l μ_{l|j} x_l``, ``P⁰ʲ = Σ_l μ_{l|j} (P_l + (x_l − x⁰ʲ)(x_l − x⁰ʲ)ᵀ)``
    (docs/equations.md; ``transition[l, j] = P(mode j | mode l)``, rows sum to 1).
    Returns ``(c̄ (M,), x⁰ (M, d), P⁰ (M, d, d))``."""
    joint = transition * state.mu[:, None]               # p_lj μ_l
    cbar = jnp.sum(joint, axis=0)
    w = joint / jnp.where(cbar > 0, cbar, 1.0)[None, :]  # μ_{l|j}
    x0 = w.T @ state.x
    dx = state.x[None, :, :] - x0[:, None, :]            # (j, l, d)
    P0 = jnp.einsum("lj,jlab->jab", w, state.P[None] + dx[..., :, None] * dx[..., None, :])
    return cbar, x0, symmetrize(P0)


def mode_probabilities(cbar, loglik):
    """``μ_j ∝ Λ_j c̄_j`` computed as ``softmax(log Λ_j + log c̄_j)`` (docs/equations.md), so a
    measurement hundreds of σ off never under- or overflows. A non-finite log-likelihood
    counts as −inf (that mode is ruled out); if every mode is ruled out, μ = c̄."""
    loglik = jnp.where(jnp.isnan(loglik), -jnp.inf, loglik)
    logits = loglik + jnp.log(cbar)
    ok = jnp.any(jnp.isfinite(logits))
    return jnp.where(ok, jax.nn.softmax(jnp.where(ok, logits, 0.0)), cbar)


def combine(state: IMMState):
    """Combined estimate ``x = Σ_j μ_j x_j``, ``P = Σ_j μ_j (P_j + (x_j − x)(x_j − x)ᵀ)``."""
    x = state.mu @ state.x
    dx = state.x - x
    P = jnp.einsum("j,jab->ab", state.mu, state.P + dx[:, :, None] * dx[:, None, :])
    return x, symmetrize(P)


def imm_step(state: IMMState, transition, mode_filter: Callable, mode_params, *args):
    """One IMM cycle (docs/equations.md). ``mode_filter(x⁰, P⁰, params_j, *args) -> (x, P,
    log Λ)`` is vmapped over the modes with ``mode_params`` stacked on a leading mode axis;
    ``args`` (e.g. the measurement) are shared. Returns ``(new state, (x, P) combined)``."""
    cbar, x0, P0 = mix(state, transition)
    x, P, ll = jax.vmap(lambda a, b, p: mode_filter(a, b, p, *args))(x0, P0, mode_params)
    new = IMMState(mode_probabilities(cbar, ll), x, P)
    return new, combine(new)
