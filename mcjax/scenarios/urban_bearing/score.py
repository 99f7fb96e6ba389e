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
(:func:`mcjax.models.platforms.braking_climb`). Inadmissible candidates cost +∞.

Smooth surrogates (for the gradient planner): indicators become sigmoids of signed slab
margins at the temperature ``T`` (metres): ``J_T`` sums the running product of "still
clear" probabilities, ``J_NLOS`` the product of the reflection conditions' sigmoids. The
reported score is always the exact one.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcjax.models.platforms import FixedWingLimits, braking_climb, command_box, fixed_wing_step
from mcjax.numerics import softmax_value, softmin
from mcjax.scenarios.urban_bearing import environment as env

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
    (:func:`mcjax.models.platforms.command_box`). Static shape: ``counts`` = (K_θ, K_ω) values
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


def _soft_inside_box(p, lo3, hi3, T):
    """Smooth membership of points ``p`` (..., 3) in boxes (B, 3): product of the six face
    sigmoids. (..., B)."""
    q = p[..., None, :]
    return jnp.prod(jax.nn.sigmoid((q - lo3) / T) * jax.nn.sigmoid((hi3 - q) / T), axis=-1)


def _soft_blocked_segment(a, c, lo3, hi3, T, n_samples: int = 16):
    """Smooth "the segment a–c meets a box": the soft maximum over points sampled along the
    segment of their soft box membership. (...,)."""
    t = (jnp.arange(n_samples) + 0.5) / n_samples
    pts = a[..., None, :] + t[:, None] * (c - a)[..., None, :]     # (..., S, 3)
    member = _soft_inside_box(pts, lo3, hi3, T)                    # (..., S, B)
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
    occupied = 1.0 - jnp.prod(1.0 - _soft_inside_box(pos, lo3, hi3, T), axis=-1)
    shadow = jax.vmap(lambda p: _soft_blocked_segment(emitter, p, lo3, hi3, T))(pos)
    free = (1.0 - occupied) * (1.0 - shadow)
    clear = jnp.sum(jnp.cumprod(free))
    nlos = jnp.sum(jax.vmap(lambda p: _soft_reflection(buildings, emitter, p, T))(pos))
    return Terms(j_fim, clear, nlos)


def _soft_reflection(buildings, emitter, uav, T):
    """Smooth "some wall reflects to ``uav``" (the region of eqs. 9–10): for each wall the
    product of sigmoids of the signed conditions of :func:`mcjax.scenarios.urban_bearing.environment.reflections`
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
# Smooth stand-ins used only by the training surrogate of mcjax tune
# (:func:`mcjax.scenarios.urban_bearing.scenario.step` with smoothing): every hard geometric test of the
# measurement model and of the grid planner becomes a smooth function of the positions, so
# the closed loop's outcome is a smooth function of the weights c1, c2, c3. The exact
# simulation never calls them.


def soft_segment_blocked(a, c, lo3, hi3, T):
    """Smooth "the segment ``a–c`` meets box b" (the slab test of the shadow, Chen & Hao 2022,
    eqs. 7–8, :func:`mcjax.scenarios.urban_bearing.environment.line_of_sight`): along the segment, measured
    in metres, the entry point is the largest of the three slabs' entries and 0, the exit the
    smallest of their exits and the length L; both are taken as soft maxima/minima
    (``T·logsumexp``) and the segment is blocked with weight ``sigmoid((exit − entry)/T)``
    (the length of segment inside the box, or minus the gap, at temperature T in metres).
    ``a``, ``c`` (..., 3), boxes ``lo3``, ``hi3`` (B, 3) -> (..., B)."""
    d = (c - a)[..., None, :]
    L = jnp.sqrt(jnp.sum(d * d, axis=-1) + 1e-12)                     # (..., 1)
    tiny = 1e-9
    d = jnp.where(d >= 0, jnp.maximum(d, tiny), jnp.minimum(d, -tiny))
    t1 = (lo3 - a[..., None, :]) / d
    t2 = (hi3 - a[..., None, :]) / d
    s_lo = jnp.minimum(t1, t2) * L[..., None]                         # (..., B, 3) metres
    s_hi = jnp.maximum(t1, t2) * L[..., None]
    zero = jnp.zeros_like(s_lo[..., :1])
    enter = softmax_value(jnp.concatenate([s_lo, zero], axis=-1), T)
    leave = softmin(jnp.concatenate([s_hi, jnp.broadcast_to(L[..., None], zero.shape)], axis=-1), T)
    return jax.nn.sigmoid((leave - enter) / T)


def soft_line_of_sight(buildings, a, c, T):
    """Smooth line of sight between ``a`` and ``c`` (..., 3): ``Π_b (1 − blocked_b)`` with
    :func:`soft_segment_blocked` — the complement of the shadow of Chen & Hao 2022, eqs. 7–8."""
    lo3, hi3 = env.boxes3(buildings)
    return jnp.prod(1.0 - soft_segment_blocked(a, c, lo3, hi3, T), axis=-1)


def soft_occupied(buildings, p, T):
    """Smooth "``p`` (..., 3) lies in a building" (``p ∈ A_Build``, Chen & Hao 2022, eq. 3):
    ``1 − Π_b (1 − Π_faces sigmoid(margin/T))``. (...)."""
    lo3, hi3 = env.boxes3(buildings)
    return 1.0 - jnp.prod(1.0 - _soft_inside_box(p, lo3, hi3, T), axis=-1)


def _soft_positive(x, T):
    """``T·softplus(x/T)`` > 0, ≈ x for x ≫ T."""
    return T * jax.nn.softplus(x / T)


def soft_reflection_region(buildings, emitter, uav, T):
    """Smooth membership of ``uav`` (3,) in each wall's reflection region ``A_NLOS,s`` (Chen &
    Hao 2022, eqs. 9–10; :func:`mcjax.scenarios.urban_bearing.environment.reflections` with
    ``check_legs=False``): the product of sigmoids of its signed conditions (emitter and UAV
    on the wall's outward side, the crossing point of the image–UAV segment within the wall's
    extent and height). The crossing fraction ``d_e/(d_e + d_u)`` uses soft-plus positive
    distances so that it is smooth everywhere; where both soft-plus distances underflow to 0
    (both points farther than ~745 T behind the wall's plane), the fraction is ½ (every
    sigmoid of the product is then 0, so the weight is 0 whatever the fraction). Returns ``(p (B, 4), crossing point (B, 4, 3),
    mirror image (B, 4, 3))``."""
    c, t_lo, t_hi, hh = env.wall_frame(buildings)
    sign = jnp.asarray(env.WALL_SIGN, dtype=c.dtype)
    d_e = sign * (env.per_wall(emitter, env.WALL_AXIS)[0] - c)
    d_u = sign * (env.per_wall(uav, env.WALL_AXIS)[0] - c)
    pe, pu = _soft_positive(d_e, T), _soft_positive(d_u, T)
    ok = pe + pu > 0
    frac = jnp.where(ok, pe / jnp.where(ok, pe + pu, 1.0), 0.5)
    e_t, u_t = env.per_wall(emitter, env.WALL_TANGENT)[0], env.per_wall(uav, env.WALL_TANGENT)[0]
    q_t = e_t + frac * (u_t - e_t)
    q_z = emitter[2] + frac * (uav[2] - emitter[2])
    s = jax.nn.sigmoid
    p = s(d_e / T) * s(d_u / T) * s((q_t - t_lo) / T) * s((t_hi - q_t) / T) * s(q_z / T) * s((hh - q_z) / T)
    normal_x = jnp.asarray([True, True, False, False])
    point = jnp.stack([jnp.where(normal_x, c, q_t), jnp.where(normal_x, q_t, c), q_z], -1)
    return p, point, env.mirror_images(buildings, emitter)


def soft_reflections(buildings, emitter, uav, T):
    """Smooth validity (B, 4) of every one-bounce path emitter → wall → ``uav`` (Chen & Hao
    2022, eqs. 9–10 with both legs clear of the other buildings, as
    :func:`mcjax.scenarios.urban_bearing.environment.reflections` with ``check_legs=True``): the region weight
    of :func:`soft_reflection_region` times, for each leg, ``Π (1 − blocked)`` over the
    other boxes (:func:`soft_segment_blocked`). Returns ``(weight (B, 4), images (B, 4, 3))``."""
    p, point, image = soft_reflection_region(buildings, emitter, uav, T)
    lo3, hi3 = env.boxes3(buildings)
    n_b = lo3.shape[0]
    e_b = jnp.broadcast_to(emitter, point.shape)
    u_b = jnp.broadcast_to(uav, point.shape)
    other = ~jnp.eye(n_b, dtype=bool)[:, None, :]                     # (B, 1, B): wall's box excluded
    leg1 = soft_segment_blocked(e_b, point, lo3, hi3, T)              # (B, 4, B)
    leg2 = soft_segment_blocked(point, u_b, lo3, hi3, T)
    clear = jnp.prod(jnp.where(other, (1.0 - leg1) * (1.0 - leg2), 1.0), axis=-1)
    return p * clear, image


def soft_measured_bearing(buildings, emitter, uav, R2, P, D, T):
    """Smooth version of :func:`mcjax.scenarios.urban_bearing.environment.measured_bearing` (Chen & Hao 2022,
    eqs. 5–6): the azimuth of the summed field where the direct path counts with the weight
    :func:`soft_line_of_sight` and wall s's reflected path with its weight from
    :func:`soft_reflections` (instead of 0/1). Returns ``(bearing, los weight, reflected
    weight)``; the reflected weight ``1 − Π_s (1 − w_s)`` is the smooth "a reflection
    arrives". A zero horizontal field gives bearing 0 with a zero gradient."""
    dtype = jnp.result_type(emitter, uav, float)
    k = env.FIELD_CONSTANT * jnp.sqrt(jnp.asarray(P, dtype) * jnp.asarray(D, dtype))
    los = soft_line_of_sight(buildings, emitter, uav, T)
    w, image = soft_reflections(buildings, emitter, uav, T)
    field = (env.inv_sq_field(emitter - uav, k * los)
             + jnp.sum(env.inv_sq_field(image - uav, k * jnp.asarray(R2, dtype) * w), axis=(0, 1)))
    ex, ey = field[0], field[1]
    zero = (ex == 0.0) & (ey == 0.0)
    bearing = jnp.where(zero, 0.0, jnp.arctan2(ey, jnp.where(zero, 1.0, ex)))
    return bearing, los, 1.0 - jnp.prod(1.0 - w)


def surrogate_score_terms(buildings, belief: Belief, track, fim_kind: str, T) -> Terms:
    """Smooth ``J_FIM``, ``J_T``, ``J_NLOS`` (Chen & Hao 2022, eqs. 16, 18, 19) for the
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


def soft_admissible_log(buildings, uav, command, track, limits: FixedWingLimits, speed, dt, theta_rate_step, T):
    """Log of a smooth :func:`admissible`: ``Σ_track log(1 − occupied)`` (eq. 3) plus
    ``log sigmoid`` of both margins of the altitude band of eq. 4 at the level-off height."""
    theta = command[0]
    z_end = uav[2] + speed * dt * jnp.sin(theta) + braking_climb(theta, speed, dt, theta_rate_step)
    band = jax.nn.log_sigmoid((z_end - limits.h_min) / T) + jax.nn.log_sigmoid((limits.h_max - z_end) / T)
    return band + jnp.sum(jnp.log1p(-soft_occupied(buildings, track[:, :3], T)))


def soft_command_box(previous, limits: FixedWingLimits, dt, T):
    """:func:`mcjax.models.platforms.command_box` (Chen & Hao 2022, Alg. 1, line 3) with its
    max/min taken as soft maxima/minima at temperature ``T`` (rad, rad/s): the box lies inside
    the exact one, closer than ``T·log 2`` to it."""
    prev = jnp.asarray(previous)
    bound = jnp.stack([limits.theta_max, limits.omega_max])
    step = jnp.stack([limits.theta_rate_max, limits.omega_rate_max]) * dt
    lo = T * jnp.logaddexp(-bound / T, (prev - step) / T)
    hi = -T * jnp.logaddexp(-bound / T, -(prev + step) / T)
    return lo, hi


def soft_candidate_commands(lo, hi, counts: tuple[int, int], T):
    """The grid of Chen & Hao 2022, Alg. 1, lines 3–5 as :func:`candidate_commands` (same
    shape and order, θ-major, the level-off θ last) but spread evenly over the box
    ``[lo, hi]``: ``lo + (hi − lo)·i/(K − 1)``, smooth in the box. It equals the exact lattice
    when the box is not cut by a bound and its width is a multiple of the step (the paper's
    rates, our steps); the level-off θ is a soft ``clip(0, lo, hi)``."""
    def spread(a, b, k):
        return a + (b - a) * jnp.arange(k, dtype=lo.dtype) / max(k - 1, 1)
    th = spread(lo[0], hi[0], counts[0])
    level = -T * jnp.logaddexp(-hi[0] / T, -(T * jnp.logaddexp(0.0, lo[0] / T)) / T)
    th = jnp.concatenate([th, level[None]])
    om = spread(lo[1], hi[1], counts[1])
    Th, Om = jnp.meshgrid(th, om, indexing="ij")
    return jnp.stack([Th.ravel(), Om.ravel()], axis=-1)


def soft_argmax_command(candidates, scores, log_admissible, temperature):
    """The smooth stand-in for the grid's choice (Chen & Hao 2022, Alg. 1, lines 7–9: the
    admissible candidate of the largest eq. 20 score): the mean of the candidates under
    ``softmax((J − mean J)/(τ·std J) + log p_adm)``. The scores are standardised over the
    candidates, so, like the argmax, the choice does not change when (c1, c2, c3) are
    multiplied by a positive number; τ (dimensionless) sets how sharp it is; inadmissible
    candidates are weighed down by their smooth admissibility. Returns ``(command (2,),
    weights (K,))``."""
    centred = scores - jnp.mean(scores)
    spread = jnp.sqrt(jnp.mean(centred**2) + 1e-12)
    w = jax.nn.softmax(centred / (temperature * spread) + log_admissible)
    return w @ candidates, w
