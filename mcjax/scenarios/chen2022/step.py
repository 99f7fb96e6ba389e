"""Chen & Hao 2022's scenario (:mod:`.scenario`): its State and Record, the measurement, the
filters' start and the step of Alg. 1 (exact, or smooth for ``mcjax tune``), and, when switched on,
the posterior Cramér–Rao bound of the emitter (``bound = "on"``) and the filters' NEES and NIS
(``consistency = "on"``).

The bound (Tichavský, Muravchik & Nehorai 1998; :mod:`mcjax.scenarios.kit.bound`) is that of the
emitter's horizontal position [x, y], the state the filters estimate (its height is known). The
emitter is static: F = I, Q = 0, so the recursion is ``J_{k+1} = J_k + J_z,k+1``. Its prior
information is the inverse of the filters' prior covariance P0 (the filters' prior read as the
initial state's distribution; with ``init = "first_bearing"`` that is the run's own P0). Each step
adds, if the UAV measured (line of sight: the only gate the scenario has), the Fisher information
``∇g ∇gᵀ / σ²`` of the measurement the simulation actually draws, at the TRUE emitter, in its TRUE
mode: ``g`` the noise-free bearing of the summed field (:func:`.environment.measured_bearing`,
eqs. 5–6) and σ = σ_NLOS when a reflection arrives, σ_LOS otherwise. The reflected measurement is
the bearing of the field summed over the direct path and the emitter's mirror images in the
reflecting walls, a deterministic function of the emitter's position given the set of arriving
paths, so it does carry information: the Jacobian of that function (by ``jax.jacfwd`` with the set
of paths held fixed; with no reflection it is the azimuth's Jacobian of eq. 15). It is not an
outlier without relation to the emitter, so its information is not 0. (The filters model NLOS as a
±20° bias instead; the bound uses the truth's model, not theirs.)

What the bound is conditioned on, and so what it bounds: it is the bound GIVEN the true mode
sequence (which steps are in the shadow, in line of sight, reflected), a valid but looser floor than
one that averages over the modes; the information that the pattern of shadow and reflections itself
carries about where the emitter is (it depends on the emitter's position) is not counted. In closed
loop (the planner flies the UAV by its estimate) it is moreover conditioned on the path flown
(Zuo, Niu & Varshney 2011). Compare it with the mean of the filters' squared error over runs.

The smooth step (``mcjax tune``) carries the same bound with the smooth measurement: the Jacobian of
the smooth bearing, weighted by the soft line of sight, σ blended as the smooth step blends it."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcjax.scenarios import kit
from mcjax.scenarios.chen2022 import environment as env
from mcjax.scenarios.chen2022 import score as urban
from mcjax.scenarios.kit import bound as pcrb
from mcjax.tracking import metrics
from mcjax.tracking.filters.bounds import measurement_information
from mcjax.tracking.filters.imm import IMMState, combine
from mcjax.tracking.models.platforms import fixed_wing_step
from mcjax.tracking.numerics import spd_inverse, wrap_angle
from mcjax.scenarios.chen2022.mode_filters import (
    GATE_FLOOR, filter_bank, filter_nis, gated_mode_filter, mode_filter, mode_models,
)
from mcjax.scenarios.chen2022.params import buildings_of
from mcjax.scenarios.chen2022.planner import limits_of, plan_command, smooth_plan_command
from mcjax.scenarios.chen2022.relaxation import (
    Temperatures, soft_admissible_log, soft_line_of_sight, soft_measured_bearing, soft_occupied,
)


class State(NamedTuple):
    t: jax.Array
    uav: jax.Array        # (4,) [x, y, z, ψ]
    command: jax.Array    # (2,) the last applied (θ, ω)
    measured: jax.Array   # () bool: the last step brought a measurement
    filters: tuple        # one IMMState per filter: μ (M,), x (M, 2), P (M, 2, 2)
    fim: jax.Array        # (3, 2, 2) the IMM modes' accumulated FIM (eq. 13)
    held_for: jax.Array   # () int32: steps in a row the command has been held (shadow)
    bound: pcrb.Bound | None = None  # the PCRB's covariance of the emitter [x, y], (2, 2) and (1, 2, 2) (None: off)


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
    bound: pcrb.Bound | None = None  # the PCRB's position variances P_xx + P_yy, () and (1,), m² (None: off)
    nees: jax.Array | None = None  # (F, 1) NEES of each filter's combined estimate of [x, y] (None: consistency off)
    nis: jax.Array | None = None   # (F, 1) NIS of the measurement against each filter's prediction, NaN without one


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
    return State(jnp.asarray(0, jnp.int32), p.uav0, command, measured, tuple(filters), fim0, held_for,
                 pcrb.initial(cfg, P0))


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


def bearing_information(bearing, p, sigma, weight):
    """The Fisher information (1, 2, 2) one azimuth carries about the emitter's [x, y] (module
    docstring): ``∇g ∇gᵀ / σ²`` at the true emitter, ``g(xy) = bearing(emitter at xy)`` the
    noise-free measured bearing, times ``weight`` (the exact step: 1 if measured, else 0)."""
    def g(xy):
        return bearing(jnp.concatenate([xy, p.emitter[2:]]))[None]

    info = measurement_information(g, p.emitter[:2], (1.0 / sigma**2)[None, None])
    return jnp.where(weight > 0, weight * info, 0.0)[None]


def update_bound(state: State, info):
    """The bound after this step's information ``info`` (1, 2, 2): the static emitter, F = I, Q = 0."""
    eye = jnp.eye(2, dtype=info.dtype)
    return pcrb.update_with(state.bound, eye, jnp.zeros_like(eye), info)


def filter_nees(filters, emitter_xy):
    """(F, 1) NEES ``eᵀ P⁻¹ e`` of every filter's combined estimate (the IMM's moment-matched mean and
    covariance, :func:`mcjax.tracking.filters.imm.combine`) of the emitter's [x, y] (2 dof)."""
    def one(f):
        x, P = combine(f)
        return metrics.nees(x, spd_inverse(P), emitter_xy)

    return jnp.stack([one(f) for f in filters])[:, None]


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


def _soft_plan_or_hold(cfg, p, b, state: State, belief, temperatures: Temperatures):
    """The smooth command: the soft grid choice (:func:`.planner.smooth_plan_command`, for any
    ``Config.planner``) blended with the previous command by the soft hold
    ``h = (1 − los_prev)·p_adm(previous)``, ``los_prev`` the soft line of sight where the last
    measurement was taken (1 at step 0, as the exact ``measured`` starts True). No step limit
    (``max_hold_steps`` has no smooth path). Returns ``(h, command, soft score of the plan)``."""
    T = temperatures.geometry
    planned, score = smooth_plan_command(cfg, p, b, state.uav, state.command, belief, temperatures)
    lim = limits_of(cfg, p)
    hold_track = urban.predicted_track(state.uav, state.command, p.speed, cfg.dt, cfg.horizon)
    hold_ok = jnp.exp(soft_admissible_log(b, state.uav, state.command, hold_track, lim, p.speed, cfg.dt,
                                          cfg.theta_rate_max * cfg.dt, T))
    los_prev = jnp.where(state.t == 0, 1.0, soft_line_of_sight(b, p.emitter, state.uav[:3], T))
    held = (1.0 - los_prev) * hold_ok
    return held, held * state.command + (1.0 - held) * planned, score


def step(cfg, params, state: State, key, temperatures: Temperatures | None = None) -> tuple[State, Record]:
    """One step of Chen & Hao 2022, Alg. 1: plan (or hold the command after a step in the
    shadow), fly one step (eq. 1), measure the azimuth (eqs. 5–6 with the LOS or NLOS noise),
    run every filter (IMM-EKF, eqs. 11–12) and accumulate the IMM modes' FIM (eq. 13).

    ``temperatures`` None: the exact simulation. A :class:`Temperatures`: the same step, with the same
    random draws, with every switch smooth (docs/tune.md), for ``mcjax tune`` and sensitivities:

    * the planner's grid argmax (and, for the gradient or sequence planner, its clip, fallback
      and warm start) -> the soft argmax over the grid (:func:`.planner.smooth_plan_command`);
    * the shadow hold -> the blend ``h·previous + (1 − h)·planned`` (:func:`_soft_plan_or_hold`);
    * the measurement gate (no LOS -> no measurement) -> a measurement of weight ``g = los``
      (:func:`.mode_filters.gated_mode_filter`), its bearing from the smooth field
      (:func:`.relaxation.soft_measured_bearing`), its noise σ blended between LOS and NLOS by the
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
    if temperatures is None:
        held, command, score = _plan_or_hold(cfg, p, b, state, belief, k_plan)
    else:
        held, command, score = _soft_plan_or_hold(cfg, p, b, state, belief, temperatures)
    uav = fixed_wing_step(state.uav, command[0], command[1], p.speed, cfg.dt)

    # the measurement (eqs. 2, 5–6): no line of sight -> none; a reflection -> NLOS noise
    pos = uav[:3]
    bound = None  # bound = "off"
    if temperatures is None:
        z, los, reflected = measure(p, b, pos, k_noise)
        nis = filter_nis(cfg, p, state, z, uav) if cfg.consistency == "on" else None
        new_filters, errors = filter_bank(cfg, p, state, mode_filter, z, uav)
        if cfg.bound == "on":  # the measurement's true model: the summed field's bearing, σ of its true mode
            bound = update_bound(state, bearing_information(
                lambda e: env.measured_bearing(b, e, pos, p.R2, p.power, p.directivity), p,
                jnp.where(reflected, p.sigma_nlos, p.sigma_los), los.astype(dtype)))
    else:
        T = temperatures.geometry
        clean, los, reflected = soft_measured_bearing(b, p.emitter, pos, p.R2, p.power, p.directivity, T)
        reflected = jnp.where(p.R2 > 0, reflected, 0.0)
        sigma = p.sigma_los + reflected * (p.sigma_nlos - p.sigma_los)
        z = wrap_angle(clean + sigma * jax.random.normal(k_noise, (), dtype))
        gate = GATE_FLOOR + (1.0 - GATE_FLOOR) * los
        nis = filter_nis(cfg, p, state, z, uav, gate) if cfg.consistency == "on" else None
        new_filters, errors = filter_bank(cfg, p, state, gated_mode_filter, z, uav, gate)
        if cfg.bound == "on":  # the smooth measurement: its bearing's Jacobian, weighted by the soft LOS
            bound = update_bound(state, bearing_information(
                lambda e: soft_measured_bearing(b, e, pos, p.R2, p.power, p.directivity, T)[0], p, sigma, los))
    nees = filter_nees(new_filters, p.emitter[:2]) if cfg.consistency == "on" else None
    imm_new = new_filters[cfg.filters.index("imm")]
    gained = jax.vmap(lambda x, s: urban.bearing_information(x, uav, s))(imm_new.x, sig)

    if temperatures is None:
        fim = state.fim + jnp.where(los, gained, 0.0)
        rec = Record(
            error=jnp.stack(errors), uav=uav, command=command, held=held, shadow=~los, nlos=los & reflected,
            in_building=env.inside(b, pos), violation=_violation(cfg, p, state.command, command, uav),
            mu=imm_new.mu, score=jnp.where(held, jnp.nan, score), bound=pcrb.position_variance(bound, (0, 1)),
            nees=nees, nis=nis)
        held_for = jnp.where(held, state.held_for + 1, 0)
        return State(state.t + 1, uav, command, los, tuple(new_filters), fim, held_for, bound), rec
    fim = state.fim + los * gained
    rec = Record(
        error=jnp.stack(errors), uav=uav, command=command, held=held, shadow=1.0 - los, nlos=los * reflected,
        in_building=soft_occupied(b, pos, T),
        violation=_violation(cfg, p, state.command, command, uav).astype(dtype), mu=imm_new.mu, score=score,
        bound=pcrb.position_variance(bound, (0, 1)), nees=nees, nis=nis)
    return State(state.t + 1, uav, command, los > 0.5, tuple(new_filters), fim, state.held_for, bound), rec
