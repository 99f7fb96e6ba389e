"""Target motion models."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mcjax.tracking.numerics import matvec


def cv_matrices(dt: jax.Array | float, dtype=None) -> tuple[jax.Array, jax.Array]:
    """Constant-velocity transition ``F`` (4×4) and noise input ``G`` (4×2).

    Sun et al. 2011 eq. 1, state ``[x, ẋ, y, ẏ]``:
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
    """State process-noise covariance ``G diag(σ², σ²) Gᵀ`` of Sun et al. 2011 eq. 1 (4×4)."""
    _, g = cv_matrices(dt, dtype)
    s2 = jnp.asarray(sigma_accel, dtype=g.dtype) ** 2
    return s2 * jnp.sum(g[..., :, None, :] * g[..., None, :, :], axis=-1)


def cv_step(x: jax.Array, key: jax.Array, dt, sigma_accel) -> jax.Array:
    """One step of the CV target ``x ← F x + G w``, ``w ~ N(0, σ² I₂)`` (Sun et al. 2011 eq. 1)."""
    f, g = cv_matrices(dt, x.dtype)
    w = sigma_accel * jax.random.normal(key, (2,), dtype=x.dtype)
    return matvec(f, x) + matvec(g, w)


def ct_matrix(dt, omega, dtype=None) -> jax.Array:
    """Coordinated-turn transition (4×4) at a known turn rate ω, state ``[x, ẋ, y, ẏ]``.

    Bar-Shalom, Li & Kirubarajan 2001 §11.7; the CT mode of Ren & Lv 2017 (docs/equations.md):
    ``F = [[1, s/ω, 0, −(1−c)/ω], [0, c, 0, −s], [0, (1−c)/ω, 1, s/ω], [0, s, 0, c]]`` with
    ``s = sin ωT, c = cos ωT``. At ω = 0 the limits ``s/ω → T``, ``(1−c)/ω → 0`` give the
    CV matrix (taken by a Taylor series near 0, so gradients in ω stay finite)."""
    dt = jnp.asarray(dt, dtype=dtype)
    w = jnp.asarray(omega, dtype=dt.dtype)
    wt = w * dt
    small = jnp.abs(wt) < 1e-4
    w_safe = jnp.where(small, 1.0, w)
    s, c = jnp.sin(wt), jnp.cos(wt)
    sw = jnp.where(small, dt * (1.0 - wt**2 / 6.0), s / w_safe)        # sin(ωT)/ω
    cw = jnp.where(small, dt * wt / 2.0 * (1.0 - wt**2 / 12.0), (1.0 - c) / w_safe)  # (1−cos ωT)/ω
    one, zero = jnp.ones_like(wt), jnp.zeros_like(wt)
    return jnp.stack([
        jnp.stack([one, sw, zero, -cw], -1),
        jnp.stack([zero, c, zero, -s], -1),
        jnp.stack([zero, cw, one, sw], -1),
        jnp.stack([zero, s, zero, c], -1),
    ], -2)


def markov_modes(key, transition, first_mode, n_steps: int) -> jax.Array:
    """A mode sequence (n_steps,) of the Markov chain ``P(m_k = j | m_{k−1} = l) = transition[l, j]``
    starting at ``first_mode`` — the switching CV↔CT target of Ren & Lv 2017 (docs/equations.md)."""
    logp = jnp.log(jnp.asarray(transition))

    def body(m, k):
        nxt = jax.random.categorical(k, logp[m])
        return nxt, nxt

    _, rest = jax.lax.scan(body, jnp.asarray(first_mode), jax.random.split(key, n_steps - 1))
    return jnp.concatenate([jnp.asarray(first_mode)[None], rest])
