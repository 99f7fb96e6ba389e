"""Platforms: the 2-D UAV with a heading autopilot."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcjax.tracking.numerics import wrap_angle


class UnicycleLimits(NamedTuple):
    """Limits of Sun et al. 2011 eq. 4 (SI units: m/s, m/s², rad/s)."""

    v_min: jax.Array
    v_max: jax.Array
    a_min: jax.Array
    a_max: jax.Array
    turn_rate_max: jax.Array  # |φ̇| ≤ turn_rate_max


def heading_at(phi0, heading_cmd, alpha_phi, turn_rate_max, t):
    """Exact heading at time ``t`` of the autopilot of Sun et al. 2011 eq. 3 with the eq. 4 rate limit.

    ``φ̇ = clip(α_φ (φᶜ − φ), ±φ̇_max)`` with the error wrapped (shortest turn): the heading
    turns at the limit rate until the error falls to ``φ̇_max/α_φ``, then decays as
    ``exp(−α_φ t)``. Solving it exactly keeps the step stable for any gain (RK4 on this
    stiff loop stalls short of the command once ``α_φ·dt`` exceeds ~2.8).
    """
    e0 = wrap_angle(heading_cmd - phi0)
    sign, mag = jnp.sign(e0), jnp.abs(e0)
    alpha = jnp.where(alpha_phi > 0, alpha_phi, 1.0)
    rate = jnp.where(turn_rate_max > 0, turn_rate_max, 1.0)
    e_sat = jnp.where(alpha_phi > 0, turn_rate_max / alpha, jnp.inf)
    # unsaturated: e(t) = e0 exp(−α t) — written in e0 (not |e0|) so gradients are right at e0 = 0
    linear = e0 * jnp.exp(-alpha_phi * t)
    # saturated: turn at the limit until |e| = e_sat, then decay
    t_sat = jnp.where(turn_rate_max > 0, (mag - jnp.minimum(e_sat, mag)) / rate, jnp.inf)
    late = sign * jnp.minimum(e_sat, mag) * jnp.exp(-alpha * jnp.maximum(t - t_sat, 0.0))
    saturated = jnp.where(t <= t_sat, e0 - sign * turn_rate_max * t, late)
    err = jnp.where(mag <= e_sat, linear, saturated)
    return wrap_angle(phi0 + (e0 - err))


def speed_at(v0, accel_cmd, limits: UnicycleLimits, t):
    """Exact speed at time ``t``: ``v̇ = a`` with ``a`` clipped to its limits and the speed
    held at ``[v_min, v_max]`` (Sun et al. 2011 eqs. 3–4)."""
    a = jnp.clip(accel_cmd, limits.a_min, limits.a_max)
    return jnp.clip(v0 + a * t, limits.v_min, limits.v_max)


def unicycle_step(state, heading_cmd, accel_cmd, alpha_phi, limits: UnicycleLimits, dt, substeps: int = 4):
    """Advance the UAV ``[x, y, v, φ]`` of Sun et al. 2011 eq. 3 (eq. 4 limits) by ``dt``.

    Heading and speed follow their exact solutions (:func:`heading_at`, :func:`speed_at`);
    the position integrates ``v cos φ, v sin φ`` by composite Simpson over ``substeps``
    sub-intervals — the quadrature RK4 reduces to when heading and speed are known functions
    of time. docs/equations.md asks for RK4 over the step; the exact heading replaces it
    because RK4 is unstable on the stiff heading loop (see :func:`heading_at`).
    """
    x, y, v, phi = state[..., 0], state[..., 1], state[..., 2], state[..., 3]
    m = 2 * substeps
    h = dt / m
    # every quadrature node at once (one set of operations, not m + 1: a smaller program), the
    # nodes on a new last axis (a gradient then sums the inputs over a contiguous axis: on the
    # CPU, under vmap, faster than over a leading one); the weighted sum keeps the node order
    t = jnp.arange(m + 1, dtype=x.dtype) * h

    def node(a):
        return jnp.asarray(a)[..., None]

    at_nodes = UnicycleLimits(*map(node, limits))
    vk = speed_at(node(v), node(accel_cmd), at_nodes, t)
    pk = heading_at(node(phi), node(heading_cmd), node(alpha_phi), at_nodes.turn_rate_max, t)
    fx, fy = vk * jnp.cos(pk), vk * jnp.sin(pk)
    vx, vy = 0.0, 0.0
    for k in range(m + 1):
        w = 1.0 if k in (0, m) else (4.0 if k % 2 else 2.0)
        vx = vx + w * fx[..., k]
        vy = vy + w * fy[..., k]
    return jnp.stack([x + vx * h / 3.0, y + vy * h / 3.0,
                      speed_at(v, accel_cmd, limits, dt),
                      heading_at(phi, heading_cmd, alpha_phi, limits.turn_rate_max, dt)], axis=-1)


# --------------------------------------------------------------------------- 3-D fixed wing


class FixedWingLimits(NamedTuple):
    """Limits of the 3-D UAV of Chen & Hao 2022, eqs. 1 and 4 (SI: rad, rad/s, rad/s², m).

    ``|θ| ≤ theta_max``, ``|θ̇| ≤ theta_rate_max``, ``|ω| ≤ omega_max``,
    ``|ω̇| ≤ omega_rate_max``, ``h_min ≤ z ≤ h_max``. The rates bound the change of a
    command between two steps: ``|θ_k − θ_{k−1}| ≤ theta_rate_max · Δt`` (Alg. 1, line 3).
    """

    theta_max: jax.Array
    theta_rate_max: jax.Array
    omega_max: jax.Array
    omega_rate_max: jax.Array
    h_min: jax.Array
    h_max: jax.Array


def fixed_wing_step(state, theta, omega, speed, dt):
    """One step of the UAV of Chen & Hao 2022, eq. 1: state ``[x, y, z, ψ]`` (..., 4), flight
    path angle ``θ`` and turn rate ``ω`` held over the step, speed ``V``:
    ``x += V Δt cos ψ cos θ``, ``y += V Δt sin ψ cos θ``, ``z += V Δt sin θ``, ``ψ += Δt ω``
    (the paper's forward-Euler discretisation, kept as printed; ψ is not wrapped)."""
    x, y, z, psi = state[..., 0], state[..., 1], state[..., 2], state[..., 3]
    d = speed * dt
    return jnp.stack([x + d * jnp.cos(psi) * jnp.cos(theta), y + d * jnp.sin(psi) * jnp.cos(theta),
                      z + d * jnp.sin(theta), psi + dt * omega], axis=-1)


def command_box(previous, limits: FixedWingLimits, dt):
    """The commands reachable from the previous one ``previous = (θ, ω)``: the box
    ``[max(−θ_max, θ − θ̇_max Δt), min(θ_max, θ + θ̇_max Δt)] × [same for ω]`` of Chen & Hao
    2022, Alg. 1, line 3 (whose ``V_min`` in the first line is a slip for ``θ_min``).
    Returns ``(lo (2,), hi (2,))``."""
    prev = jnp.asarray(previous)
    bound = jnp.stack([limits.theta_max, limits.omega_max])
    step = jnp.stack([limits.theta_rate_max, limits.omega_rate_max]) * dt
    return jnp.maximum(-bound, prev - step), jnp.minimum(bound, prev + step)


def braking_climb(theta, speed, dt, theta_step):
    """Height the UAV still gains after a step flown at ``θ`` if it then levels off as fast
    as the rate limit allows (``θ − δ, θ − 2δ, …`` down to 0 with ``δ = theta_step``, the
    largest change per step): ``V Δt Σ_{j=1}^{J} sin(θ − j δ)`` with ``J = floor(θ/δ)``, summed
    in closed form ``sin(θ − (J+1)δ/2) sin(Jδ/2) / sin(δ/2)``. For ``θ < 0`` it is the
    (negative) height still lost, by symmetry. Used to keep the altitude limits of
    Chen & Hao 2022, eq. 4 reachable (ours)."""
    a = jnp.abs(theta)
    delta = jnp.asarray(theta_step, a.dtype)
    ok = delta > 0
    d = jnp.where(ok, delta, 1.0)
    J = jnp.where(ok, jnp.floor(a / d), 0.0)
    s = jnp.sin(a - (J + 1.0) * d / 2.0) * jnp.sin(J * d / 2.0) / jnp.sin(d / 2.0)
    return jnp.sign(theta) * speed * dt * jnp.where(J > 0, s, 0.0)
