"""Sensors: range–bearing radar with a maximum sensing range; the azimuth-only direction finder."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mcjax.tracking.numerics import safe_norm, wrap_angle


def range_bearing(x: jax.Array, sensor: jax.Array) -> jax.Array:
    """Range–bearing of a ``[x, ẋ, y, ẏ]`` target from a sensor at ``(sx, sy)``.

    Sun et al. 2011 §1.3: ``h = [√((x−sx)² + (y−sy)²), atan2(y−sy, x−sx)]``
    (the paper prints ``arctan``; the four-quadrant form is meant). The norm is the safe
    form and the bearing is guarded, so ``jax.jacfwd`` is finite even when the target sits
    on the sensor.
    """
    d = jnp.stack([x[..., 0] - sensor[..., 0], x[..., 2] - sensor[..., 1]], axis=-1)
    # double-where: at the sensor itself the bearing is 0 with a zero (finite) derivative
    on_sensor = (d[..., 0] == 0.0) & (d[..., 1] == 0.0)
    dx = jnp.where(on_sensor, 1.0, d[..., 0])
    bearing = jnp.where(on_sensor, 0.0, jnp.arctan2(d[..., 1], dx))
    return jnp.stack([safe_norm(d), bearing], axis=-1)


def in_range(x: jax.Array, sensor: jax.Array, max_range) -> jax.Array:
    """True where the target lies within the sensing radius (range gate, Sun et al. 2011 §5)."""
    return range_bearing(x, sensor)[..., 0] <= max_range


def measure_range_bearing(key, x, sensor, sigma_range, sigma_bearing, max_range, valid=True):
    """A noisy range–bearing measurement, NaN where gated out (beyond ``max_range``) or
    where ``valid`` is False (agent not alive). Bearing wrapped to (−π, π]."""
    clean = range_bearing(x, sensor)
    noise = jax.random.normal(key, clean.shape, dtype=clean.dtype)
    z = clean + noise * jnp.stack([jnp.asarray(sigma_range, clean.dtype),
                                   jnp.asarray(sigma_bearing, clean.dtype)], -1)
    z = z.at[..., 1].set(wrap_angle(z[..., 1]))
    ok = jnp.logical_and(clean[..., 0] <= max_range, valid)
    return jnp.where(ok[..., None], z, jnp.nan)


def azimuth(target_xy: jax.Array, uav: jax.Array) -> jax.Array:
    """Azimuth of a ground target ``[x_T, y_T]`` (..., 2) seen from a UAV at ``[x, y, …]``:
    ``η = atan2(y_T − y_U, x_T − x_U)`` (Chen & Hao 2022, eq. 2 without its noise; the paper
    prints ``arctan``, the four-quadrant form is meant). Guarded like :func:`range_bearing`:
    0 with a zero derivative when the UAV is straight above the target."""
    dx = target_xy[..., 0] - uav[..., 0]
    dy = target_xy[..., 1] - uav[..., 1]
    above = (dx == 0.0) & (dy == 0.0)
    return jnp.where(above, 0.0, jnp.arctan2(dy, jnp.where(above, 1.0, dx)))


def position(x: jax.Array, sensor: jax.Array) -> jax.Array:
    """A linear position fix of a CV state ``[x, vx, y, vy]``: ``[x, y]`` (the sensor's own
    position does not enter; Lou, Cui & Li 2013, the type-I nodes' measurement)."""
    del sensor
    return jnp.stack([x[0], x[2]])
