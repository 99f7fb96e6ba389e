"""The track score of Chen & Hao 2022 (eqs. 13–20) for bearing-only localisation in a city.

A candidate command ``(θ, ω)`` is held over the whole horizon of ``n`` steps (Alg. 1, lines
4–6: one constant command per candidate), which predicts a track ``Tr_p`` of UAV positions.
The track's score (to be *maximised*) is

    J_p = c1 J_FIM + c2 J_T + c3 J_NLOS                                  (eq. 20)

* ``J_FIM`` (eqs. 13–17): for each IMM mode f, the Fisher information of the target
  position accumulated so far (``FIM_k^f``) plus the bearing information every predicted
  position adds (eq. 13 with Φ = I, eq. 14; the Jacobian of eq. 15 at mode f's own estimate
  and the noise σ_f of mode f's measurement model), scored by its determinant and weighted by
  the mode probabilities: ``Σ_f μ_f score(FIM_{k+n}^f)``. ``score`` is the paper's ``det``
  or (our default) ``log det``: the raw det grows like 1/range⁴ and swamps the step counts
  near the emitter, so its weight c1 means nothing there (docs/equations.md).
* ``J_T`` (eq. 18): the number of predicted steps before the track first enters a building
  or the estimated shadow Â_Shadow (the emitter placed at the current estimate, at its
  known height) — ``n`` for a clear track.
* ``J_NLOS`` (eq. 19): the number of predicted steps inside the estimated reflection region
  Â_NLOS (the paper's region membership, eqs. 9–10: ``reflections(check_legs=False)``).

Admissibility (ours, hard constraints for every weight vector, so no score can fly the UAV
into a building or out of its altitude band): a candidate is admissible when its track
stays out of every building for the whole horizon and when, after the step flown with θ,
the UAV could still level off within ``[h_min, h_max]`` at the rate limit
(:func:`mcjax.tracking.models.platforms.braking_climb`). Inadmissible candidates cost +∞.

Relaxation surrogates (for the gradient planner): indicators become sigmoids of signed slab
margins at the temperature ``T`` (metres): ``J_T`` sums the running product of "still
clear" probabilities, ``J_NLOS`` the product of the reflection conditions' sigmoids. The
reported score is always the exact one. The training surrogate of ``mcjax tune`` scores a track
with :func:`surrogate_score_terms`, from the smooth stand-ins of :mod:`.relaxation`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcjax.scenarios.chen2022 import environment as env
from mcjax.tracking.models.platforms import FixedWingLimits, braking_climb, command_box, fixed_wing_step
from mcjax.scenarios.chen2022.relaxation import (  # noqa: F401 (some used here; all defined here before)
    soft_admissible_log, soft_argmax_command, soft_candidate_commands, soft_command_box, soft_inside_box,
    soft_line_of_sight, soft_measured_bearing, soft_occupied, soft_reflection_region, soft_reflections,
    soft_segment_blocked,
)

FIM_SCORES = ("logdet", "det")


class Weights(NamedTuple):
    """``c1, c2, c3`` of eq. 20 (the paper's full score: 0.2, 0.5, −0.3)."""

    c1: jax.Array
    c2: jax.Array
    c3: jax.Array


class Belief(NamedTuple):
    """What the planner knows of the target (from the IMM-EKF): the combined position estimate
    ``xy`` (2,), the mode estimates ``mode_xy`` (M, 2), mode probabilities ``mu`` (M,), the
    accumulated FIM per mode ``fim`` (M, 2, 2), each mode's bearing noise ``sigma`` (M,) and
    the emitter's height ``z`` (known; the paper's emitter is on the ground)."""

    xy: jax.Array
    mode_xy: jax.Array
    mu: jax.Array
    fim: jax.Array
    sigma: jax.Array
    z: jax.Array | float = 0.0


class Terms(NamedTuple):
    fim: jax.Array
    clear_steps: jax.Array
    nlos_steps: jax.Array


# --------------------------------------------------------------------------- FIM


def bearing_information(target_xy, uav, sigma):
    """Information ``Hᵀ R⁻¹ H`` one azimuth measurement carries about a ground target
    (Chen & Hao 2022, eqs. 13 and 15): ``H = [−(y_T − y_U)/g², (x_T − x_U)/g²]`` with ``g`` the
    horizontal range, ``R = σ²``. ``target_xy`` (..., 2), ``uav`` (..., ≥2) -> (..., 2, 2).
    Zero when the UAV is straight above the target (the bearing is then undefined)."""
    dx = target_xy[..., 0] - uav[..., 0]
    dy = target_xy[..., 1] - uav[..., 1]
    g2 = dx * dx + dy * dy
    ok = g2 > 0
    safe = jnp.where(ok, g2, 1.0)
    h = jnp.stack([-dy / safe, dx / safe], axis=-1) * jnp.where(ok, 1.0, 0.0)[..., None]
    s2 = jnp.asarray(sigma) ** 2
    return h[..., :, None] * h[..., None, :] / s2[..., None, None]


def det2(m):
    """Determinant of (..., 2, 2) matrices."""
    return m[..., 0, 0] * m[..., 1, 1] - m[..., 0, 1] * m[..., 1, 0]


def fim_score(fim, kind: str):
    """``det FIM`` (the paper's eq. 16) or ``log det FIM`` (ours, the default; −∞ for a
    singular FIM) of (..., 2, 2) matrices."""
    d = det2(fim)
    if kind == "det":
        return d
    return jnp.log(jnp.maximum(d, 0.0))


# --------------------------------------------------------------------------- candidates, tracks


def grid_counts(theta_rate_max: float, omega_rate_max: float, dt: float, theta_step: float,
                omega_step: float) -> tuple[int, int]:
    """Static numbers of θ and ω lattice values: ``ceil(2 · rate · Δt / step) + 1`` each."""
    def count(rate, step):
        return int(math.ceil(2.0 * rate * dt / step - 1e-9)) + 1
    return count(theta_rate_max, theta_step), count(omega_rate_max, omega_step)


def candidate_commands(previous, limits: FixedWingLimits, dt, steps, counts: tuple[int, int]):
    """The grid of Chen & Hao 2022, Alg. 1, lines 3–5: θ from θ_min to θ_max by θ_step, ω from
    ω_min to ω_max by ω_step, inside the box the rate limits allow around the previous command
    (:func:`mcjax.tracking.models.platforms.command_box`). Static shape: ``counts`` = (K_θ, K_ω) values
    ``min(lo + i·step, hi)`` (the last is always ``hi``; a box cut by a bound repeats it), plus
    one extra θ: the level-off value ``clip(0, θ_lo, θ_hi)`` (ours; it keeps the altitude
    band reachable, :func:`admissible`). Returns ((K_θ + 1) · K_ω, 2) commands, θ-major."""
    lo, hi = command_box(previous, limits, dt)
    steps = jnp.asarray(steps, lo.dtype)
    th = jnp.minimum(lo[0] + jnp.arange(counts[0], dtype=lo.dtype) * steps[0], hi[0])
    th = jnp.concatenate([th, jnp.clip(0.0, lo[0], hi[0])[None]])
    om = jnp.minimum(lo[1] + jnp.arange(counts[1], dtype=lo.dtype) * steps[1], hi[1])
    T, O = jnp.meshgrid(th, om, indexing="ij")
    return jnp.stack([T.ravel(), O.ravel()], axis=-1)


def predicted_track(uav, command, speed, dt, n: int):
    """The positions ``[x, y, z, ψ]`` (n, 4) at steps k+1 … k+n when ``command = (θ, ω)`` is
    held from ``uav`` (Chen & Hao 2022, eq. 1; Alg. 1, line 6)."""
    def body(s, _):
        s = fixed_wing_step(s, command[0], command[1], speed, dt)
        return s, s
    _, track = jax.lax.scan(body, uav, None, length=n)
    return track


def admissible(buildings, uav, command, track, limits: FixedWingLimits, speed, dt, theta_rate_step):
    """The hard constraints (ours; module docstring): the track meets no building (eq. 3) and
    the altitude band of eq. 4 stays reachable after the step flown at θ."""
    theta = command[0]
    z_end = uav[2] + speed * dt * jnp.sin(theta) + braking_climb(theta, speed, dt, theta_rate_step)
    in_band = (z_end >= limits.h_min) & (z_end <= limits.h_max)
    return in_band & ~jnp.any(env.inside(buildings, track[:, :3]))


# --------------------------------------------------------------------------- exact terms


def score_terms(buildings, belief: Belief, track, fim_kind: str) -> Terms:
    """``J_FIM``, ``J_T`` and ``J_NLOS`` of one predicted ``track`` (n, ≥3) (eqs. 16, 18, 19)."""
    pos = track[:, :3]
    gained = jnp.sum(jax.vmap(lambda xy, s: bearing_information(xy, pos, s))(belief.mode_xy, belief.sigma),
                     axis=1)                                            # (M, 2, 2)
    j_fim = jnp.sum(belief.mu * fim_score(belief.fim + gained, fim_kind))
    emitter = jnp.concatenate([belief.xy, jnp.asarray(belief.z, belief.xy.dtype)[None]])
    blocked = env.inside(buildings, pos) | env.in_shadow(buildings, emitter, pos)
    clear = jnp.sum(jnp.cumprod(~blocked))
    nlos = jnp.sum(jnp.any(env.reflections(buildings, emitter, pos, check_legs=False).valid, axis=(-2, -1)))
    return Terms(j_fim, clear.astype(j_fim.dtype), nlos.astype(j_fim.dtype))


def track_score(terms: Terms, w: Weights):
    """``J_p = c1 J_FIM + c2 J_T + c3 J_NLOS`` (eq. 20)."""
    return w.c1 * terms.fim + w.c2 * terms.clear_steps + w.c3 * terms.nlos_steps


# --------------------------------------------------------------------------- smooth terms


def _soft_blocked_segment(a, c, lo3, hi3, T, n_samples: int = 16):
    """Relaxation "the segment a–c meets a box": the soft maximum over points sampled along the
    segment of their soft box membership. (...,)."""
    t = (jnp.arange(n_samples) + 0.5) / n_samples
    pts = a[..., None, :] + t[:, None] * (c - a)[..., None, :]     # (..., S, 3)
    member = soft_inside_box(pts, lo3, hi3, T)                     # (..., S, B)
    return 1.0 - jnp.prod(1.0 - member, axis=(-2, -1))


def smooth_score_terms(buildings, belief: Belief, track, fim_kind: str, T) -> Terms:
    """Differentiable stand-ins for :func:`score_terms` at temperature ``T`` (metres)."""
    pos = track[:, :3]
    gained = jnp.sum(jax.vmap(lambda xy, s: bearing_information(xy, pos, s))(belief.mode_xy, belief.sigma),
                     axis=1)
    fim = belief.fim + gained
    j_fim = jnp.sum(belief.mu * fim_score(fim, fim_kind))
    lo3, hi3 = env.boxes3(buildings)
    emitter = jnp.concatenate([belief.xy, jnp.asarray(belief.z, belief.xy.dtype)[None]])
    occupied = 1.0 - jnp.prod(1.0 - soft_inside_box(pos, lo3, hi3, T), axis=-1)
    shadow = jax.vmap(lambda p: _soft_blocked_segment(emitter, p, lo3, hi3, T))(pos)
    free = (1.0 - occupied) * (1.0 - shadow)
    clear = jnp.sum(jnp.cumprod(free))
    nlos = jnp.sum(jax.vmap(lambda p: _soft_reflection(buildings, emitter, p, T))(pos))
    return Terms(j_fim, clear, nlos)


def _soft_reflection(buildings, emitter, uav, T):
    """Relaxation "some wall reflects to ``uav``" (the region of eqs. 9–10): for each wall the
    product of sigmoids of the signed conditions of :func:`mcjax.scenarios.chen2022.environment.reflections`
    (both points on the outward side, the crossing point within the wall), combined over walls
    as ``1 − Π(1 − p)``."""
    c, t_lo, t_hi, hh = env.wall_frame(buildings)
    sign = jnp.asarray(env.WALL_SIGN, dtype=c.dtype)
    d_e = sign * (env.per_wall(emitter, env.WALL_AXIS)[0] - c)
    d_u = sign * (env.per_wall(uav, env.WALL_AXIS)[0] - c)
    denom = jnp.where(d_e + d_u > 0, d_e + d_u, 1.0)
    frac = jnp.clip(d_e / denom, 0.0, 1.0)
    e_t, u_t = env.per_wall(emitter, env.WALL_TANGENT)[0], env.per_wall(uav, env.WALL_TANGENT)[0]
    q_t = e_t + frac * (u_t - e_t)
    q_z = emitter[2] + frac * (uav[2] - emitter[2])
    s = jax.nn.sigmoid
    p = (s(d_e / T) * s(d_u / T) * s((q_t - t_lo) / T) * s((t_hi - q_t) / T) * s(q_z / T) * s((hh - q_z) / T))
    return 1.0 - jnp.prod(1.0 - p)


# --------------------------------------------------------------------------- surrogate for training
#
# The score terms of the training surrogate of mcjax tune (:func:`mcjax.scenarios.chen2022.step.step`
# with temperatures), from the smooth stand-ins of :mod:`.relaxation`.


def surrogate_score_terms(buildings, belief: Belief, track, fim_kind: str, T) -> Terms:
    """Relaxation ``J_FIM``, ``J_T``, ``J_NLOS`` (Chen & Hao 2022, eqs. 16, 18, 19) for the
    training surrogate: as :func:`smooth_score_terms`, but the estimated shadow of eq. 18 is
    the slab-based :func:`soft_line_of_sight` (not points sampled along the segment, which
    can miss a building 100 m wide between samples 400 m apart) and the reflection region of
    eq. 19 is :func:`soft_reflection_region` (smooth everywhere)."""
    pos = track[:, :3]
    gained = jnp.sum(jax.vmap(lambda xy, s: bearing_information(xy, pos, s))(belief.mode_xy, belief.sigma),
                     axis=1)
    j_fim = jnp.sum(belief.mu * fim_score(belief.fim + gained, fim_kind))
    emitter = jnp.concatenate([belief.xy, jnp.asarray(belief.z, belief.xy.dtype)[None]])
    free = (1.0 - soft_occupied(buildings, pos, T)) * soft_line_of_sight(buildings, emitter, pos, T)
    clear = jnp.sum(jnp.cumprod(free))
    region = jax.vmap(lambda p: soft_reflection_region(buildings, emitter, p, T)[0])(pos)   # (n, B, 4)
    nlos = jnp.sum(1.0 - jnp.prod(1.0 - region, axis=(-2, -1)))
    return Terms(j_fim, clear, nlos)
