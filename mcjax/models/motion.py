"""Target motion models."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mcjax.numerics import matvec


def cv_matrices(dt: jax.Array | float, dtype=None) -> tuple[jax.Array, jax.Array]:
    """Constant-velocity transition ``F`` (4×4) and noise input ``G`` (4×2).

    Sun et al. 2011 (seed 000) eq. 1, state ``[x, ẋ, y, ẏ]``:
    ``F = [[1,T,0,0],[0,1,0,0],[0,0,1,T],[0,0,0,1]]``, ``G = [[T²/2,0],[T,0],[0,T²/2],[0,T]]``.
    """
    dt = jnp.asarray(dt, dtype=dtype)
    one, zero = jnp.ones_like(dt), jnp.zeros_like(dt)
    f = jnp.stack(
        [
            jnp.stack([one, dt, zero, zero], -1),
            jnp.stack([zero, one, zero, zero], -1),
            jnp.stack([zero, zero, one, dt], -1),
            jnp.stack([zero, zero, zero, one], -1),
        ],
        -2,
    )
    half = 0.5 * dt * dt
    g = jnp.stack(
        [
            jnp.stack([half, zero], -1),
            jnp.stack([dt, zero], -1),
            jnp.stack([zero, half], -1),
            jnp.stack([zero, dt], -1),
        ],
        -2,
    )
    return f, g


def cv_process_noise(dt, sigma_accel, dtype=None) -> jax.Array:
    """State process-noise covariance ``G diag(σ², σ²) Gᵀ`` of seed 000 eq. 1 (4×4)."""
    _, g = cv_matrices(dt, dtype)
    s2 = jnp.asarray(sigma_accel, dtype=g.dtype) ** 2
    return s2 * jnp.sum(g[..., :, None, :] * g[..., None, :, :], axis=-1)


def cv_step(x: jax.Array, key: jax.Array, dt, sigma_accel) -> jax.Array:
    """One step of the CV target ``x ← F x + G w``, ``w ~ N(0, σ² I₂)`` (seed 000 eq. 1)."""
    f, g = cv_matrices(dt, x.dtype)
    w = sigma_accel * jax.random.normal(key, (2,), dtype=x.dtype)
    return matvec(f, x) + matvec(g, w)
