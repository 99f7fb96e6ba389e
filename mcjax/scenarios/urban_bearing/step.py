"""Chen & Hao 2022's scenario (:mod:`.scenario`): its State and Record, the measurement, the
filters' start and the step of Alg. 1 (exact, or smooth for ``mcjax tune``)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcjax.filters.imm import IMMState, combine
from mcjax.models.platforms import fixed_wing_step
from mcjax.numerics import wrap_angle
from mcjax.scenarios import kit
from mcjax.scenarios.urban_bearing import environment as env
from mcjax.scenarios.urban_bearing import score as urban
from mcjax.scenarios.urban_bearing.mode_filters import GATE_FLOOR, filter_bank, gated_mode_filter, mode_filter, mode_models
from mcjax.scenarios.urban_bearing.params import buildings_of
from mcjax.scenarios.urban_bearing.planner import limits_of, plan_command, smooth_plan_command
from mcjax.scenarios.urban_bearing.smoothing import (
    Smoothing, soft_admissible_log, soft_line_of_sight, soft_measured_bearing, soft_occupied,
)


class State(NamedTuple):
    t: jax.Array
    uav: jax.Array        # (4,) [x, y, z, ψ]
    command: jax.Array    # (2,) the last applied (θ, ω)
    measured: jax.Array   # () bool: the last step brought a measurement
    filters: tuple        # one IMMState per filter: μ (M,), x (M, 2), P (M, 2, 2)
    fim: jax.Array        # (3, 2, 2) the IMM modes' accumulated FIM (eq. 13)
    held_for: jax.Array   # () int32: steps in a row the command has been held (shadow)


class Record(NamedTuple):
    error: jax.Array      # (F, 1) horizontal distance of each filter's estimate from the emitter
    uav: jax.Array        # (4,) after the step
    command: jax.Array    # (2,) applied (θ, ω)
    held: jax.Array       # () the previous command was held (shadow)
    shadow: jax.Array     # () no line of sight at the measurement (no measurement)
    nlos: jax.Array       # () line of sight and at least one reflection arrived (biased measurement)
    in_building: jax.Array  # ()
    violation: jax.Array  # () the applied command or the altitude broke a limit
    mu: jax.Array         # (3,) the IMM's mode probabilities
    score: jax.Array      # () exact score J of the applied command (NaN when held)


def init(cfg, params, key) -> State:
    """The UAV at ``uav0`` with command (0, 0); every filter (the IMM's modes and the LOS EKF)
    at one initial estimate (x0, P0) per run; the IMM modes at ``mu0``; FIM_0 = P0⁻¹, the
    initial information (Chen & Hao 2022, Alg. 1's initialisation of X̂_T,0 and FIM).
    ``Config.init`` chooses (x0, P0):

    * ``"prior"``: x0 drawn about the emitter with std ``prior_sigma`` per axis, P0 =
      ``prior_sigma² I``.
    * ``"first_bearing"`` (ours; bearings-only practice: Ristic, Arulampalam & Gordon 2004,
      ch. 6, and the range-parameterised EKF): :func:`first_bearing_prior` at the bearing the
      UAV measures at ``uav0`` (the measurement model of :func:`step`), as a line-of-sight
      bearing; if ``uav0`` has no line of sight, the ``"prior"`` start."""
    dtype, p = kit.typed(cfg, params)
    if cfg.init == "prior":
        x0 = p.emitter[:2] + p.prior_sigma * jax.random.normal(key, (2,), dtype)
        P0 = p.prior_sigma**2 * jnp.eye(2, dtype=dtype)
        fim0 = jnp.broadcast_to(jnp.eye(2, dtype=dtype) / p.prior_sigma**2, (3, 2, 2))
    else:
        k_prior, k_range, k_noise = jax.random.split(key, 3)
        b = buildings_of(p)
        z0, los, _ = measure(p, b, p.uav0[:3], k_noise)
        true_range = jnp.sqrt(jnp.sum((p.emitter[:2] - p.uav0[:2]) ** 2))
        r0 = true_range + p.prior_sigma * jax.random.normal(k_range, (), dtype)
        xb, Pb = first_bearing_prior(p.uav0[:2], jnp.where(los, z0, 0.0), r0, p.prior_sigma, p.sigma_los)
        xp = p.emitter[:2] + p.prior_sigma * jax.random.normal(k_prior, (2,), dtype)
        x0 = jnp.where(los, xb, xp)
        P0 = jnp.where(los, Pb, p.prior_sigma**2 * jnp.eye(2, dtype=dtype))
        fim0 = jnp.broadcast_to(inv2(P0), (3, 2, 2))
    filters = []
    for name in cfg.filters:
        m = 3 if name == "imm" else 1
        mu = p.mu0 if m == 3 else kit.per_run(p.prior_sigma, jnp.ones(1, dtype))  # per-run: kit.per_run
        filters.append(IMMState(mu, jnp.broadcast_to(x0, (m, 2)), jnp.broadcast_to(P0, (m, 2, 2))))
    command, measured = kit.per_run(p.prior_sigma, jnp.zeros(2, dtype), jnp.asarray(True))
    held_for = kit.per_run(p.prior_sigma, jnp.asarray(0, jnp.int32))
    return State(jnp.asarray(0, jnp.int32), p.uav0, command, measured, tuple(filters), fim0, held_for)


def first_bearing_prior(uav_xy, bearing, range_, sigma_range, sigma_bearing):
    """A bearings-only start (Ristic, Arulampalam & Gordon 2004, ch. 6; the range-parameterised
    EKF's single-filter case): the target at ``range_`` along the measured ``bearing`` from
    ``uav_xy``, x0 = uav + r (cos β, sin β), with the covariance of a range σ_r along the
    bearing and a cross-range σ_c = r σ_β across it: P0 = R(β) diag(σ_r², (r σ_β)²) R(β)ᵀ.
    ``range_`` is clipped at 1 m (a range is positive). Returns ``(x0 (2,), P0 (2, 2))``."""
    r = jnp.maximum(range_, 1.0)
    c, s = jnp.cos(bearing), jnp.sin(bearing)
    x0 = uav_xy + r * jnp.stack([c, s])
    vr, vc = sigma_range**2, (r * sigma_bearing) ** 2
    P0 = jnp.stack([jnp.stack([vr * c * c + vc * s * s, (vr - vc) * c * s]),
                    jnp.stack([(vr - vc) * c * s, vr * s * s + vc * c * c])])
    return x0, P0


def inv2(m):
    """Inverse of a 2 x 2 matrix (closed form; the initial information P0⁻¹)."""
    det = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    return jnp.stack([jnp.stack([m[1, 1], -m[0, 1]]), jnp.stack([-m[1, 0], m[0, 0]])]) / det


def measure(p, b, pos, key):
    """The azimuth the UAV measures at ``pos`` (3,) (Chen & Hao 2022, eqs. 2, 5–6): the bearing of
    the summed field plus noise of std σ_NLOS when a reflection arrives, σ_LOS otherwise; NaN
    without line of sight. Returns ``(z, los, reflected)``, ``reflected``: a reflection arrives."""
    los = env.line_of_sight(b, p.emitter, pos)
    reflected = jnp.any(env.reflections(b, p.emitter, pos).valid) & (p.R2 > 0)
    clean = env.measured_bearing(b, p.emitter, pos, p.R2, p.power, p.directivity)
    sigma = jnp.where(reflected, p.sigma_nlos, p.sigma_los)
    z = jnp.where(los, wrap_angle(clean + sigma * jax.random.normal(key, (), clean.dtype)), jnp.nan)
    return z, los, reflected


def _violation(cfg, params, previous, command, uav):
    lim = limits_of(cfg, params)
    tol = 1e-9
    return ((jnp.abs(command[0]) > lim.theta_max + tol) | (jnp.abs(command[1]) > lim.omega_max + tol)
            | (jnp.abs(command[0] - previous[0]) > lim.theta_rate_max * cfg.dt + tol)
            | (jnp.abs(command[1] - previous[1]) > lim.omega_rate_max * cfg.dt + tol)
            | (uav[2] < lim.h_min - tol) | (uav[2] > lim.h_max + tol))


def _plan_or_hold(cfg, p, b, state: State, belief, key):
    """The exact command (Alg. 1): the planner's, or the previous one held after a step in the
    shadow. Returns ``(held, command, exact score of the planned command)``."""
    planned, score, _ = plan_command(cfg, p, b, state.uav, state.command, belief, key)
    # in the shadow the paper holds the previous command; ours: only while it stays admissible
    lim = limits_of(cfg, p)
    hold_track = urban.predicted_track(state.uav, state.command, p.speed, cfg.dt, cfg.horizon)
    hold_ok = urban.admissible(b, state.uav, state.command, hold_track, lim, p.speed, cfg.dt,
                               cfg.theta_rate_max * cfg.dt)
    # ours: at most max_hold_steps in a row (0: no limit, the paper's rule); then the planner flies
    within_limit = (p.max_hold_steps <= 0) | (state.held_for < p.max_hold_steps)
    held = ~state.measured & hold_ok & within_limit
    return held, jnp.where(held, state.command, planned), score


def _soft_plan_or_hold(cfg, p, b, state: State, belief, smoothing: Smoothing):
    """The smooth command: the soft grid choice (:func:`.planner.smooth_plan_command`, for any
    ``Config.planner``) blended with the previous command by the soft hold
    ``h = (1 − los_prev)·p_adm(previous)``, ``los_prev`` the soft line of sight where the last
    measurement was taken (1 at step 0, as the exact ``measured`` starts True). No step limit
    (``max_hold_steps`` has no smooth path). Returns ``(h, command, soft score of the plan)``."""
    T = smoothing.geometry
    planned, score = smooth_plan_command(cfg, p, b, state.uav, state.command, belief, smoothing)
    lim = limits_of(cfg, p)
    hold_track = urban.predicted_track(state.uav, state.command, p.speed, cfg.dt, cfg.horizon)
    hold_ok = jnp.exp(soft_admissible_log(b, state.uav, state.command, hold_track, lim, p.speed, cfg.dt,
                                          cfg.theta_rate_max * cfg.dt, T))
    los_prev = jnp.where(state.t == 0, 1.0, soft_line_of_sight(b, p.emitter, state.uav[:3], T))
    held = (1.0 - los_prev) * hold_ok
    return held, held * state.command + (1.0 - held) * planned, score


def step(cfg, params, state: State, key, smoothing: Smoothing | None = None) -> tuple[State, Record]:
    """One step of Chen & Hao 2022, Alg. 1: plan (or hold the command after a step in the
    shadow), fly one step (eq. 1), measure the azimuth (eqs. 5–6 with the LOS or NLOS noise),
    run every filter (IMM-EKF, eqs. 11–12) and accumulate the IMM modes' FIM (eq. 13).

    ``smoothing`` None: the exact simulation. A :class:`Smoothing`: the same step, with the same
    random draws, with every switch smooth (docs/tune.md), for ``mcjax tune`` and sensitivities:

    * the planner's grid argmax (and, for the gradient or sequence planner, its clip, fallback
      and warm start) -> the soft argmax over the grid (:func:`.planner.smooth_plan_command`);
    * the shadow hold -> the blend ``h·previous + (1 − h)·planned`` (:func:`_soft_plan_or_hold`);
    * the measurement gate (no LOS -> no measurement) -> a measurement of weight ``g = los``
      (:func:`.mode_filters.gated_mode_filter`), its bearing from the smooth field
      (:func:`.smoothing.soft_measured_bearing`), its noise σ blended between LOS and NLOS by the
      smooth "a reflection arrives";
    * the FIM accumulation (eq. 13: only with LOS) -> weighted by ``los``.

    The smooth Record has the exact one's fields: ``held``, ``shadow`` (1 − los), ``nlos``
    (los · reflected) and ``in_building`` (soft occupancy) are floats in [0, 1];
    ``violation`` is the exact test of the smooth command as 0/1; ``score`` is the soft
    argmax's mean surrogate score of the plan (not NaN when held)."""
    dtype, p = kit.typed(cfg, params)
    b = buildings_of(p)
    k_plan, k_noise = jax.random.split(key)

    imm = state.filters[cfg.filters.index("imm")]
    xy, _ = combine(imm)
    _, sig = mode_models(p, "imm")
    belief = urban.Belief(xy, imm.x, imm.mu, state.fim, sig, p.emitter[2])
    if smoothing is None:
        held, command, score = _plan_or_hold(cfg, p, b, state, belief, k_plan)
    else:
        held, command, score = _soft_plan_or_hold(cfg, p, b, state, belief, smoothing)
    uav = fixed_wing_step(state.uav, command[0], command[1], p.speed, cfg.dt)

    # the measurement (eqs. 2, 5–6): no line of sight -> none; a reflection -> NLOS noise
    pos = uav[:3]
    if smoothing is None:
        z, los, reflected = measure(p, b, pos, k_noise)
        new_filters, errors = filter_bank(cfg, p, state, mode_filter, z, uav)
    else:
        T = smoothing.geometry
        clean, los, reflected = soft_measured_bearing(b, p.emitter, pos, p.R2, p.power, p.directivity, T)
        reflected = jnp.where(p.R2 > 0, reflected, 0.0)
        sigma = p.sigma_los + reflected * (p.sigma_nlos - p.sigma_los)
        z = wrap_angle(clean + sigma * jax.random.normal(k_noise, (), dtype))
        gate = GATE_FLOOR + (1.0 - GATE_FLOOR) * los
        new_filters, errors = filter_bank(cfg, p, state, gated_mode_filter, z, uav, gate)
    imm_new = new_filters[cfg.filters.index("imm")]
    gained = jax.vmap(lambda x, s: urban.bearing_information(x, uav, s))(imm_new.x, sig)

    if smoothing is None:
        fim = state.fim + jnp.where(los, gained, 0.0)
        rec = Record(
            error=jnp.stack(errors), uav=uav, command=command, held=held, shadow=~los, nlos=los & reflected,
            in_building=env.inside(b, pos), violation=_violation(cfg, p, state.command, command, uav),
            mu=imm_new.mu, score=jnp.where(held, jnp.nan, score))
        held_for = jnp.where(held, state.held_for + 1, 0)
        return State(state.t + 1, uav, command, los, tuple(new_filters), fim, held_for), rec
    fim = state.fim + los * gained
    rec = Record(
        error=jnp.stack(errors), uav=uav, command=command, held=held, shadow=1.0 - los, nlos=los * reflected,
        in_building=soft_occupied(b, pos, T),
        violation=_violation(cfg, p, state.command, command, uav).astype(dtype), mu=imm_new.mu, score=score)
    return State(state.t + 1, uav, command, los > 0.5, tuple(new_filters), fim, state.held_for), rec
