"""Platforms: the 2-D UAV with a heading autopilot."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcjax.numerics import wrap_angle


class UnicycleLimits(NamedTuple):
    """Limits of seed 000 eq. 4 (SI units: m/s, m/s², rad/s)."""

    v_min: jax.Array
    v_max: jax.Array
    a_min: jax.Array
    a_max: jax.Array
    turn_rate_max: jax.Array  # |φ̇| ≤ turn_rate_max


def unicycle_derivative(state, heading_cmd, accel_cmd, alpha_phi, limits: UnicycleLimits):
    """Time derivative of ``[x, y, v, φ]`` — Sun et al. 2011 (seed 000) eq. 3 with eq. 4 limits.

    ``ẋ = v cos φ, ẏ = v sin φ, v̇ = a, φ̇ = α_φ (φᶜ − φ)``; the heading error is wrapped
    (the shortest turn), ``a`` and ``φ̇`` are clipped to their limits, and ``v̇`` is zeroed
    when it would push the speed past its limits.
    """
    x, y, v, phi = state[..., 0], state[..., 1], state[..., 2], state[..., 3]
    rate = jnp.clip(alpha_phi * wrap_angle(heading_cmd - phi), -limits.turn_rate_max, limits.turn_rate_max)
    a = jnp.clip(accel_cmd, limits.a_min, limits.a_max)
    a = jnp.where((v >= limits.v_max) & (a > 0), 0.0, a)
    a = jnp.where((v <= limits.v_min) & (a < 0), 0.0, a)
    return jnp.stack([v * jnp.cos(phi), v * jnp.sin(phi), a, rate], axis=-1)


def unicycle_step(state, heading_cmd, accel_cmd, alpha_phi, limits: UnicycleLimits, dt):
    """Advance the UAV of seed 000 eq. 3 by ``dt`` with one classical RK4 step.

    The speed is clipped to ``[v_min, v_max]`` and the heading wrapped afterwards.
    """

    def f(s):
        return unicycle_derivative(s, heading_cmd, accel_cmd, alpha_phi, limits)

    k1 = f(state)
    k2 = f(state + 0.5 * dt * k1)
    k3 = f(state + 0.5 * dt * k2)
    k4 = f(state + dt * k3)
    new = state + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    v = jnp.clip(new[..., 2], limits.v_min, limits.v_max)
    return jnp.stack([new[..., 0], new[..., 1], v, wrap_angle(new[..., 3])], axis=-1)
