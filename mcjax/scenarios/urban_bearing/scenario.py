"""One UAV localises a static radio emitter among buildings by its azimuth — Chen & Hao 2022.

A fixed-wing UAV (eq. 1, limits of eq. 4 and Alg. 1) measures only the azimuth of a ground
emitter. Buildings (axis-aligned boxes) hide the emitter (shadow: no measurement) or
reflect its signal (NLOS: the measured azimuth is the direction of the summed field of the
direct and the reflected paths, eqs. 5–6, so it is biased towards the mirror images). The
UAV runs an IMM-EKF over three measurement modes — LOS (bias 0, σ 0.2°) and NLOS ± (bias
±20°, σ 1°), eqs. 11–12 — and every step picks its command (θ, ω) from a grid by the track
score ``c1 J_FIM + c2 J_T + c3 J_NLOS`` (eqs. 13–20, :mod:`.score`, :mod:`.planner`). In the
shadow it holds its previous command (the paper's rule), as long as that stays admissible and (ours,
``max_hold_steps`` > 0) at most that many steps in a row. The filters start on the first measured
bearing (``Config.init = "first_bearing"``, ours) or from an isotropic prior (``"prior"``).

Filters (``Config.filters``): ``"imm"`` — the paper's 3-mode IMM-EKF, which the planner
uses; ``"ekf"`` — a single EKF that assumes line of sight (ours: what the IMM buys). The
error of a filter is the horizontal distance of its estimate from the emitter; the mean of
the last step's error over runs is the paper's "RMSE" of eq. 23 (Table 1).

Units are SI (m, s, rad). The paper's values, and our choices where it is silent, are
listed in ``configs/chen2022.toml``.
"""

from __future__ import annotations

from functools import cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mcjax.contract import (
    FAST_COMPILE, Output, Param, Scenario, Setting, config_type, declare, params_type,
)
from mcjax.filters.imm import IMMState, combine
from mcjax.models.platforms import fixed_wing_step
from mcjax.numerics import wrap_angle
from mcjax.scenarios import kit
from mcjax.scenarios.urban_bearing import environment as env
from mcjax.scenarios.urban_bearing import score as urban
from mcjax.scenarios.urban_bearing.mode_filters import GATE_FLOOR, filter_bank, gated_mode_filter, mode_filter, mode_models
from mcjax.scenarios.urban_bearing.planner import limits_of, plan_command, smooth_plan_command
from mcjax.smoothing import Smooth

NAME = "urban_bearing"

FILTER_KINDS = ("imm", "ekf")
PLANNERS = ("grid", "gradient", "sequence")
INITS = ("first_bearing", "prior")
LOS, NLOS_PLUS, NLOS_MINUS = 0, 1, 2
DEG = float(np.pi / 180.0)


def _check(cfg) -> None:
    kit.check_common(cfg)
    if "imm" not in cfg.filters:
        raise ValueError("filters must include 'imm': the planner scores tracks with the IMM-EKF's "
                         "mode estimates and probabilities (Chen & Hao 2022, eq. 16)")


_settings = kit.common_settings(filter_kinds=FILTER_KINDS, n_agents=1, n_steps=250, warmup_steps=25,
                                divergence_threshold=2000.0)
_settings["n_agents"] = Setting(1, "number of UAVs (the paper's system has one)", choices=(1,))

#: Config: what fixes shapes or the compiled program (the grid's size follows from the rates,
#: the step and Δt, so they live here).
Config = config_type("Config", dict(
    **_settings,
    dt=Setting(2.0, "time step (paper: 2 s)", "s", low=0, low_open=True),
    theta_rate_max=Setting(1.0 * DEG, "largest |d theta/dt| (paper: 1 deg/s)", "rad/s", low=0, low_open=True),
    omega_rate_max=Setting(1.0 * DEG, "largest |d omega/dt| (paper: 1 deg/s^2)", "rad/s^2", low=0,
                           low_open=True),
    theta_step=Setting(1.0 * DEG, "grid step of theta (ours: 1 deg)", "rad", low=0, low_open=True),
    omega_step=Setting(0.5 * DEG, "grid step of omega (ours: 0.5 deg/s)", "rad/s", low=0, low_open=True),
    horizon=Setting(10, "predicted steps n of a candidate track (ours)", "steps", low=1, integer=True),
    fim_score=Setting("logdet", "J_FIM scores log det FIM (ours) or the paper's raw det", choices=urban.FIM_SCORES),
    planner=Setting("grid", "grid = the paper's search over constant (theta, omega); gradient = optax on the smooth "
                    "score of a constant command; sequence = optax on a command per horizon step (ours)",
                    choices=PLANNERS),
    plan_iterations=Setting(20, "gradient / sequence planner: Adam steps per re-plan", low=1, integer=True),
    plan_learning_rate=Setting(0.3, "gradient / sequence planner: Adam step, in units of one step's largest "
                               "command change", low=0, low_open=True),
    sequence_grid_stride=Setting(2, "sequence planner: its warm start's grid steps are theta_step and omega_step "
                                 "times this (ours; 1 = the grid planner's grid)", low=1, integer=True),
    init=Setting("first_bearing", "the filters' start: first_bearing = on the bearing measured at uav0, at a range "
                 "drawn with std prior_sigma (ours: bearings-only practice); prior = a point drawn with std prior_sigma "
                 "per axis about the emitter", choices=INITS),
), __name__, _check)


_POS = dict(low=0.0, low_open=True)
_PROB = dict(low=0.0, high=1.0)
#: Our building layout (the paper gives heights only): rows [x_lo, y_lo, x_hi, y_hi, height] in m, chosen by
#: the criterion of benchmarks/urban_layout_check.py (configs/chen2022.toml; the first layout is in
#: configs/chen2022_wide_prior.toml).
DEFAULT_BUILDINGS = np.array([[4950.0, 4650.0, 5050.0, 4750.0, 200.0],
                              [5270.0, 5300.0, 5400.0, 5400.0, 100.0]])
#: The IMM's chain from dwell times (benchmarks/urban_dwell_times.py; configs/chen2022.toml).
_TRANSITION = np.array([[0.9819, 0.00905, 0.00905], [0.0676, 0.9324, 0.0], [0.0676, 0.0, 0.9324]])

#: Params: per-run values a sweep may vary without recompiling.
Params = params_type("Params", dict(
    speed=Param(25.0, "m/s", "UAV speed V (paper)", **_POS),
    theta_max=Param(5.0 * DEG, "rad", "largest |theta| (paper: 5 deg)", low=0.0, high=float(np.pi / 2)),
    omega_max=Param(8.0 * DEG, "rad/s", "largest |omega| (paper: 8 deg/s)", low=0.0),
    h_min=Param(100.0, "m", "lowest altitude (paper)", low=0.0),
    h_max=Param(400.0, "m", "highest altitude (paper)", low=0.0),
    emitter=Param(np.array([5000.0, 5000.0, 0.0]), "m", "the emitter's position (paper)", shape=(3,)),
    uav0=Param(np.array([0.0, 0.0, 200.0, 0.0]), "m, rad", "UAV start [x, y, z, heading] (paper)", shape=(4,)),
    buildings=Param(DEFAULT_BUILDINGS, "m", "boxes [x_lo, y_lo, x_hi, y_hi, height] (ours: layout; paper: "
                    "heights 100 and 200 m)"),
    R2=Param(0.5, "", "reflectance of the walls (paper)", **_PROB),
    power=Param(1.0, "W", "transmit power P (paper; scales every path alike)", **_POS),
    directivity=Param(1.0, "", "antenna directivity D (paper: omnidirectional)", **_POS),
    sigma_los=Param(0.2 * DEG, "rad", "LOS bearing noise std (paper: 0.2 deg)", **_POS,
                    high=float(np.pi)),
    sigma_nlos=Param(1.0 * DEG, "rad", "NLOS bearing noise std (paper: 1 deg)", **_POS,
                     high=float(np.pi)),
    bias_los=Param(0.0, "rad", "the LOS mode's bearing bias (paper: 0)", low=-np.pi, high=np.pi),
    bias_nlos=Param(20.0 * DEG, "rad", "the NLOS modes' bearing bias +/- (paper: 20 deg)", low=0.0, high=np.pi),
    imm_transition=Param(_TRANSITION, "", "the IMM's mode transition matrix P(j | l), modes LOS, NLOS+, NLOS- "
                         "(ours: from dwell times)", **_PROB, shape=(3, 3)),
    mu0=Param(np.array([0.8, 0.1, 0.1]), "", "the IMM's initial mode probabilities (ours)", **_PROB, shape=(3,)),
    prior_sigma=Param(1000.0, "m", "std of the initial estimate about the emitter per axis; the initial FIM "
                      "is its inverse square (ours)", **_POS),
    process_noise=Param(0.0, "m", "std of the filters' random walk per step (paper: none)", low=0.0),
    max_hold_steps=Param(0, "steps", "most steps in a row the shadow's hold may last, then the planner flies "
                         "(ours; 0 = no limit, the paper's rule)", low=0, integer=True),
    c1=Param(0.2, "", "weight of J_FIM (paper: 0.2)"),
    c2=Param(0.5, "", "weight of J_T, steps clear of buildings and shadow (paper: 0.5)"),
    c3=Param(-0.3, "", "weight of J_NLOS, steps in the reflection region (paper: -0.3)"),
    plan_temperature=Param(20.0, "m", "temperature of the smooth indicators (gradient planner)", **_POS),
), __name__)


def check_params(cfg, values: dict) -> list[tuple[str, str]]:
    """Checks across fields and of the building layout: ``[(field, what is allowed), …]``."""
    def get(name):
        return kit.param_value(Params, cfg, values, name)

    bad = []
    boxes = get("buildings")
    layout_ok = boxes.ndim == 2 and boxes.shape[1] == 5 and np.all(np.isfinite(boxes))
    if not layout_ok:
        bad.append(("buildings", "a list of boxes [x_lo, y_lo, x_hi, y_hi, height] (m)"))
    else:
        degenerate = np.nonzero((boxes[:, 0] >= boxes[:, 2]) | (boxes[:, 1] >= boxes[:, 3]) | (boxes[:, 4] <= 0))[0]
        if degenerate.size:
            bad.append(("buildings", f"boxes with x_lo < x_hi, y_lo < y_hi and height > 0 (box(es) "
                        f"{degenerate.tolist()} are degenerate)"))
    h_min, h_max = get("h_min"), get("h_max")
    if np.any(h_min >= h_max):
        bad.append(("h_min", "an altitude below h_max"))
    uav0 = get("uav0")
    if np.any((uav0[..., 2] < h_min) | (uav0[..., 2] > h_max)):
        bad.append(("uav0", "a start altitude within [h_min, h_max]"))
    if layout_ok and not bad:
        b = buildings_np(boxes)
        for name, point in (("emitter", get("emitter")), ("uav0", uav0[..., :3])):
            if np.any(np.asarray(env.inside(b, point))):
                bad.append((name, "a point outside every building (boxes are closed: walls and roofs count)"))
    for name in ("imm_transition",):
        m = get(name)
        if np.any(np.abs(m.sum(-1) - 1.0) > 1e-9):
            bad.append((name, "a 3x3 matrix whose rows (from LOS, NLOS+, NLOS-) sum to 1"))
    if np.any(np.abs(get("mu0").sum(-1) - 1.0) > 1e-9):
        bad.append(("mu0", "three probabilities [LOS, NLOS+, NLOS-] that sum to 1"))
    return bad


def buildings_np(boxes) -> env.Buildings:
    """A building layout ``[x_lo, y_lo, x_hi, y_hi, height]`` rows as numpy :class:`~.environment.Buildings`."""
    boxes = np.asarray(boxes, np.float64)
    return env.Buildings(boxes[:, 0:2], boxes[:, 2:4], boxes[:, 4])


def buildings_of(params) -> env.Buildings:
    """The Params' building layout as :class:`~.environment.Buildings` (arrays of its dtype)."""
    b = params.buildings
    return env.Buildings(b[:, 0:2], b[:, 2:4], b[:, 4])


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
    dtype = jnp.dtype(cfg.dtype)
    p = kit.cast(params, dtype)
    if cfg.init == "prior":
        x0 = p.emitter[:2] + p.prior_sigma * jax.random.normal(key, (2,), dtype)
        P0 = p.prior_sigma**2 * jnp.eye(2, dtype=dtype)
        fim0 = jnp.broadcast_to(jnp.eye(2, dtype=dtype) / p.prior_sigma**2, (3, 2, 2))
    else:
        k_prior, k_range, k_noise = jax.random.split(key, 3)
        b = buildings_of(p)
        z0, los = measure(p, b, p.uav0[:3], k_noise)
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
    without line of sight. Returns ``(z, los)``."""
    los, reflected, clean = _measurement_geometry(p, b, pos)
    sigma = jnp.where(reflected, p.sigma_nlos, p.sigma_los)
    z = jnp.where(los, wrap_angle(clean + sigma * jax.random.normal(key, (), clean.dtype)), jnp.nan)
    return z, los


def _measurement_geometry(p, b, pos):
    los = env.line_of_sight(b, p.emitter, pos)
    reflected = jnp.any(env.reflections(b, p.emitter, pos).valid) & (p.R2 > 0)
    clean = env.measured_bearing(b, p.emitter, pos, p.R2, p.power, p.directivity)
    return los, reflected, clean


def _violation(cfg, params, previous, command, uav):
    lim = limits_of(cfg, params)
    tol = 1e-9
    return ((jnp.abs(command[0]) > lim.theta_max + tol) | (jnp.abs(command[1]) > lim.omega_max + tol)
            | (jnp.abs(command[0] - previous[0]) > lim.theta_rate_max * cfg.dt + tol)
            | (jnp.abs(command[1] - previous[1]) > lim.omega_rate_max * cfg.dt + tol)
            | (uav[2] < lim.h_min - tol) | (uav[2] > lim.h_max + tol))


class Smoothing(NamedTuple):
    """Temperatures of the smooth system (:func:`step` with ``smoothing``; ``[tune.smoothing]``
    of a tune spec, ``[sensitivity.smoothing]`` of a sweep). Ours: the paper has no smooth model."""

    geometry: float = 20.0   # m: every building test (LOS, shadow, reflections, occupancy, altitude band)
    plan: float = 0.1        # the soft argmax over the grid: τ in units of the candidates' score spread
    command: float = 1e-3    # rad, rad/s: the soft max/min of the command box's limits


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
    hold_ok = jnp.exp(urban.soft_admissible_log(b, state.uav, state.command, hold_track, lim, p.speed, cfg.dt,
                                                cfg.theta_rate_max * cfg.dt, T))
    los_prev = jnp.where(state.t == 0, 1.0, urban.soft_line_of_sight(b, p.emitter, state.uav[:3], T))
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
      (:func:`.score.soft_measured_bearing`), its noise σ blended between LOS and NLOS by the
      smooth "a reflection arrives";
    * the FIM accumulation (eq. 13: only with LOS) -> weighted by ``los``.

    The smooth Record has the exact one's fields: ``held``, ``shadow`` (1 − los), ``nlos``
    (los · reflected) and ``in_building`` (soft occupancy) are floats in [0, 1];
    ``violation`` is the exact test of the smooth command as 0/1; ``score`` is the soft
    argmax's mean surrogate score of the plan (not NaN when held)."""
    dtype = jnp.dtype(cfg.dtype)
    p = kit.cast(params, dtype)
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
        los, reflected, clean = _measurement_geometry(p, b, pos)
        sigma = jnp.where(reflected, p.sigma_nlos, p.sigma_los)
        z = jnp.where(los, wrap_angle(clean + sigma * jax.random.normal(k_noise, (), dtype)), jnp.nan)
        new_filters, errors = filter_bank(cfg, p, state, mode_filter, z, uav)
    else:
        T = smoothing.geometry
        clean, los, reflected = urban.soft_measured_bearing(b, p.emitter, pos, p.R2, p.power, p.directivity, T)
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
        in_building=urban.soft_occupied(b, pos, T),
        violation=_violation(cfg, p, state.command, command, uav).astype(dtype), mu=imm_new.mu, score=score)
    return State(state.t + 1, uav, command, los > 0.5, tuple(new_filters), fim, state.held_for), rec


def training_weights(cfg, params):
    """What the training loss of ``mcjax tune`` reads: one UAV, weight 1 (the errors of
    :class:`Record` are (F, 1))."""
    return jnp.ones(1, jnp.dtype(cfg.dtype))


def _nlos_mean(nlos, value):
    """The mean of ``value`` over the NLOS steps: ``nlos`` a 0/1 indicator (the exact record) or
    a weight in [0, 1] (the smooth one)."""
    if nlos.dtype == jnp.bool_:
        return jnp.sum(jnp.where(nlos, value, 0.0)) / jnp.sum(nlos)
    return jnp.sum(nlos * value) / jnp.sum(nlos)


def summary(cfg, records: Record | None, params) -> dict:
    """One run's records (stacked over time) reduced to its outputs, each declared next to its
    value (:func:`mcjax.contract.declare`; ``records`` None: the declarations alone)."""
    r = records
    nlos_mu = cache(lambda: r.mu[:, NLOS_PLUS] + r.mu[:, NLOS_MINUS])
    return declare(
        **kit.error_items(lambda: r.error, lambda: jnp.ones(1, r.error.dtype), cfg, "m",
                          "distance of the estimate from the emitter"),
        shadow_steps=(Output("steps", "steps with no line of sight (no measurement)", False),
                      lambda: jnp.sum(r.shadow)),
        nlos_steps=(Output("steps", "steps whose measurement carried a reflection (biased)", False),
                    lambda: jnp.sum(r.nlos)),
        held_steps=(Output("steps", "steps flying the previous command after a step in the shadow", False),
                    lambda: jnp.sum(r.held)),
        building_steps=(Output("steps", "steps with the UAV inside a building (must be 0)", False),
                        lambda: jnp.sum(r.in_building)),
        limit_violations=(Output("steps", "steps whose command or altitude broke a limit of eq. 4 (must be 0)",
                                 False), lambda: jnp.sum(r.violation)),
        min_altitude=(Output("m", "lowest altitude flown", False), lambda: jnp.min(r.uav[:, 2])),
        mu_nlos_when_nlos=(Output("", "the IMM's mean NLOS probability on steps with a reflected measurement "
                                  "(NaN if there were none)", False),
                           lambda: _nlos_mean(r.nlos, nlos_mu())),
    )


def series(cfg, records: Record | None, params) -> dict:
    """Per-step series of one run, each declared next to its value."""
    r = records
    what = "distance of the estimate from the emitter"
    return declare(
        error_mean=(Output("m", f"mean {what} over alive agents"), lambda: r.error[..., 0]),
        error_max=(Output("m", f"largest {what} of any alive agent"), lambda: r.error[..., 0]),
        x=(Output("m", "UAV x", False), lambda: r.uav[:, 0]),
        y=(Output("m", "UAV y", False), lambda: r.uav[:, 1]),
        z=(Output("m", "UAV altitude", False), lambda: r.uav[:, 2]),
        shadow=(Output("", "1 = no line of sight (no measurement)", False), lambda: r.shadow.astype(r.error.dtype)),
        nlos=(Output("", "1 = the measurement carried a reflection", False), lambda: r.nlos.astype(r.error.dtype)),
    )


SCENARIO = Scenario(
    name=NAME, title="Chen & Hao 2022: one UAV localises an emitter among buildings by azimuth (IMM-EKF, FIM "
    "planning)", Config=Config, Params=Params, init=init, step=step, summary=summary, series=series,
    check_params=check_params,
    # rough: max_hold_steps (a step count; the soft hold has no limit), plan_temperature (only the exact
    # gradient planner's smooth objective reads it; the smooth system's soft grid does not)
    smooth=Smooth(Smoothing, lambda cfg, params, record: record.error, training_weights,
                  ("max_hold_steps", "plan_temperature")),
    compiler_options=FAST_COMPILE,
    filter_words={
        "imm": "Chen & Hao 2022's IMM-EKF over three measurement modes (line of sight, and reflected paths "
               "biased either way); the planner steers by it",
        "ekf": "a single extended Kalman filter that assumes every bearing has line of sight (what the IMM buys)"})
default_params = SCENARIO.default_params
#: The record's derived functions (from :func:`summary` and :func:`series`), by their usual names.
reduce, outputs = SCENARIO.reduce, SCENARIO.outputs
timeseries, timeseries_outputs = SCENARIO.timeseries, SCENARIO.timeseries_outputs
