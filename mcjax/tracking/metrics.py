"""Run metrics: position errors, RMSE, NEES and NIS, the divergence rule (docs/equations.md)."""

from __future__ import annotations

import jax.numpy as jnp

from mcjax.tracking.numerics import matvec, safe_norm


def position_error(estimate, truth):
    """Euclidean position error of ``[x, ẋ, y, ẏ]`` estimates (…, 4) against the truth."""
    d = jnp.stack([estimate[..., 0] - truth[..., 0], estimate[..., 2] - truth[..., 2]], -1)
    return safe_norm(d)


def nees(estimate, information, truth):
    """Normalised estimation error squared ``eᵀ P⁻¹ e`` of the full state (Bar-Shalom),
    computed with the information matrix ``Y = P⁻¹`` (no inverse)."""
    e = estimate - truth
    return jnp.sum(e * matvec(information, e), axis=-1)


def nis(innovation, innovation_information):
    """Normalised innovation squared ``νᵀ S⁻¹ ν`` of an innovation ``ν = z − ẑ`` with the inverse of
    its covariance ``S`` (Bar-Shalom, Li & Kirubarajan 2001, §5.4.2): χ² with dim(z) degrees of
    freedom when the filter is consistent."""
    return jnp.sum(innovation * matvec(innovation_information, innovation), axis=-1)


def alive_weights(alive, n: int, dtype):
    """Per-agent weights (n,): 1 for alive agents, 0 for dropped-out ones, from a scalar or
    per-agent 0/1 ``alive`` (``None``: every agent alive) — the masks of the summaries."""
    if alive is None:
        return jnp.ones(n, dtype)
    return (jnp.broadcast_to(jnp.asarray(alive, dtype), (n,)) > 0.5).astype(dtype)


def _after_warmup(n_steps, warmup):
    return (jnp.arange(n_steps) >= warmup)


def rmse(errors, warmup: int = 0, weights=None):
    """Root-mean-square of ``errors`` (T, …) over steps ≥ ``warmup`` and the other axes
    (docs/equations.md)."""
    mask = _after_warmup(errors.shape[0], warmup).reshape((-1,) + (1,) * (errors.ndim - 1))
    w = jnp.broadcast_to(mask, errors.shape).astype(errors.dtype)
    if weights is not None:
        w = w * weights
    return jnp.sqrt(jnp.sum(w * errors**2) / jnp.maximum(jnp.sum(w), 1.0))


def mean_over(errors, warmup: int = 0, weights=None):
    """Mean of ``errors`` over steps ≥ ``warmup`` (the paper tables' "estimated position
    error")."""
    mask = _after_warmup(errors.shape[0], warmup).reshape((-1,) + (1,) * (errors.ndim - 1))
    w = jnp.broadcast_to(mask, errors.shape).astype(errors.dtype)
    if weights is not None:
        w = w * weights
    return jnp.sum(w * errors) / jnp.maximum(jnp.sum(w), 1.0)


def nan_max(x, axis=None):
    """``jnp.max`` that returns NaN when any entry is NaN. XLA's CPU reductions over large
    arrays can drop NaN (jax 0.10.2: a (100, 300) min over axis 1 ignores a NaN in its row),
    so a summary that must show a blow-up checks ``isnan`` explicitly."""
    return jnp.where(jnp.any(jnp.isnan(x), axis=axis), jnp.nan, jnp.max(x, axis=axis))


def nan_min(x, axis=None):
    """``jnp.min`` that returns NaN when any entry is NaN (see :func:`nan_max`)."""
    return jnp.where(jnp.any(jnp.isnan(x), axis=axis), jnp.nan, jnp.min(x, axis=axis))


def nonfinite(errors):
    """True if any error is NaN or infinite."""
    return jnp.any(~jnp.isfinite(errors))


def diverged(errors, threshold, warmup: int = 0, weights=None):
    """Divergence rule of docs/equations.md: the error exceeded ``threshold`` (metres) at
    any step ≥ ``warmup`` (for any agent with non-zero weight), or went non-finite."""
    mask = _after_warmup(errors.shape[0], warmup).reshape((-1,) + (1,) * (errors.ndim - 1))
    if weights is not None:
        mask = jnp.logical_and(mask, weights > 0)
    big = jnp.where(mask, errors > threshold, False)
    return jnp.logical_or(jnp.any(big), nonfinite(errors))


def graph_summary(lambda2):
    """Per-run graph statistics of a λ2 series (T,) (docs/equations.md): ``lambda2_min``,
    ``lambda2_mean`` and ``disconnected_steps`` (steps with λ2 ≤ 1e-9)."""
    return dict(lambda2_min=jnp.min(lambda2), lambda2_mean=jnp.mean(lambda2),
                disconnected_steps=jnp.sum(lambda2 <= 1e-9))


def error_series(errors, weights):
    """Per-step ``error_mean`` and ``error_max`` over the agents (last axis) with non-zero
    ``weights`` (n,), or per step (T, n) — the per-step series of a sweep's timeseries table."""
    return dict(error_mean=jnp.sum(errors * weights, -1) / jnp.maximum(jnp.sum(weights, -1), 1.0),
                error_max=jnp.max(jnp.where(weights > 0, errors, -jnp.inf), -1))
