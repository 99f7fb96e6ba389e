"""Chen & Hao 2022's relaxation switch (ours: the paper has no smooth model): the temperatures
(:class:`Temperatures`) and the smooth stand-ins used by the training surrogate of ``mcjax tune``
(:func:`mcjax.scenarios.chen2022.step.step` with temperatures): every hard geometric test of the
measurement model and of the grid planner becomes a smooth function of the positions, so
the closed loop's outcome is a smooth function of the weights c1, c2, c3. The exact
simulation calls none of them but :func:`soft_inside_box`, through the gradient planner's
smooth score (:func:`.score.smooth_score_terms`)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcjax.scenarios.chen2022 import environment as env
from mcjax.tracking.models.platforms import FixedWingLimits, braking_climb
from mcjax.tracking.numerics import softmax_value, softmin


class Temperatures(NamedTuple):
    """Temperatures of the smooth system (:func:`.step.step` with ``temperatures``; ``[tune.relaxation]``
    of a tune spec, ``[sensitivity.relaxation]`` of a sweep). Ours: the paper has no smooth model."""

    geometry: float = 20.0   # m: every building test (LOS, shadow, reflections, occupancy, altitude band)
    plan: float = 0.1        # the soft argmax over the grid: τ in units of the candidates' score spread
    command: float = 1e-3    # rad, rad/s: the soft max/min of the command box's limits


def soft_inside_box(p, lo3, hi3, T):
    """Relaxation membership of points ``p`` (..., 3) in boxes (B, 3): product of the six face
    sigmoids. (..., B)."""
    q = p[..., None, :]
    return jnp.prod(jax.nn.sigmoid((q - lo3) / T) * jax.nn.sigmoid((hi3 - q) / T), axis=-1)


def soft_segment_blocked(a, c, lo3, hi3, T):
    """Relaxation "the segment ``a–c`` meets box b" (the slab test of the shadow, Chen & Hao 2022,
    eqs. 7–8, :func:`mcjax.scenarios.chen2022.environment.line_of_sight`): along the segment, measured
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
    """Relaxation line of sight between ``a`` and ``c`` (..., 3): ``Π_b (1 − blocked_b)`` with
    :func:`soft_segment_blocked` — the complement of the shadow of Chen & Hao 2022, eqs. 7–8."""
    lo3, hi3 = env.boxes3(buildings)
    return jnp.prod(1.0 - soft_segment_blocked(a, c, lo3, hi3, T), axis=-1)


def soft_occupied(buildings, p, T):
    """Relaxation "``p`` (..., 3) lies in a building" (``p ∈ A_Build``, Chen & Hao 2022, eq. 3):
    ``1 − Π_b (1 − Π_faces sigmoid(margin/T))``. (...)."""
    lo3, hi3 = env.boxes3(buildings)
    return 1.0 - jnp.prod(1.0 - soft_inside_box(p, lo3, hi3, T), axis=-1)


def _soft_positive(x, T):
    """``T·softplus(x/T)`` > 0, ≈ x for x ≫ T."""
    return T * jax.nn.softplus(x / T)


def soft_reflection_region(buildings, emitter, uav, T):
    """Relaxation membership of ``uav`` (3,) in each wall's reflection region ``A_NLOS,s`` (Chen &
    Hao 2022, eqs. 9–10; :func:`mcjax.scenarios.chen2022.environment.reflections` with
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
    """Relaxation validity (B, 4) of every one-bounce path emitter → wall → ``uav`` (Chen & Hao
    2022, eqs. 9–10 with both legs clear of the other buildings, as
    :func:`mcjax.scenarios.chen2022.environment.reflections` with ``check_legs=True``): the region weight
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
    """Relaxation version of :func:`mcjax.scenarios.chen2022.environment.measured_bearing` (Chen & Hao 2022,
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

def soft_admissible_log(buildings, uav, command, track, limits: FixedWingLimits, speed, dt, theta_rate_step, T):
    """Log of a smooth :func:`admissible`: ``Σ_track log(1 − occupied)`` (eq. 3) plus
    ``log sigmoid`` of both margins of the altitude band of eq. 4 at the level-off height."""
    theta = command[0]
    z_end = uav[2] + speed * dt * jnp.sin(theta) + braking_climb(theta, speed, dt, theta_rate_step)
    band = jax.nn.log_sigmoid((z_end - limits.h_min) / T) + jax.nn.log_sigmoid((limits.h_max - z_end) / T)
    return band + jnp.sum(jnp.log1p(-soft_occupied(buildings, track[:, :3], T)))


def soft_command_box(previous, limits: FixedWingLimits, dt, T):
    """:func:`mcjax.tracking.models.platforms.command_box` (Chen & Hao 2022, Alg. 1, line 3) with its
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
