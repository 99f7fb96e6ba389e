"""One UAV localises a static radio emitter among buildings by its azimuth — Chen & Hao 2022.

A fixed-wing UAV (eq. 1, limits of eq. 4 and Alg. 1) measures only the azimuth of a ground
emitter. Buildings (axis-aligned boxes) hide the emitter (shadow: no measurement) or
reflect its signal (NLOS: the measured azimuth is the direction of the summed field of the
direct and the reflected paths, eqs. 5–6, so it is biased towards the mirror images). The
UAV runs an IMM-EKF over three measurement modes — LOS (bias 0, σ 0.2°) and NLOS ± (bias
±20°, σ 1°), eqs. 11–12 — and every step picks its command (θ, ω) from a grid by the track
score ``c1 J_FIM + c2 J_T + c3 J_NLOS`` (eqs. 13–20, :mod:`mcjax.planning.urban`). In the
shadow it holds its previous command (the paper's rule), as long as that stays admissible.

Filters (``Config.filters``): ``"imm"`` — the paper's 3-mode IMM-EKF, which the planner
uses; ``"ekf"`` — a single EKF that assumes line of sight (ours: what the IMM buys). The
error of a filter is the horizontal distance of its estimate from the emitter; the mean of
the last step's error over runs is the paper's "RMSE" of eq. 23 (Table 1).

Units are SI (m, s, rad). The paper's values, and our choices where it is silent, are
listed in ``configs/chen2022.toml``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mcjax.contract import FAST_COMPILE, Output, Param, Scenario, Setting, Surrogate, config_type, params_type
from mcjax.filters.gaussian import ekf_update
from mcjax.filters.imm import IMMState, combine, imm_step
from mcjax.models import environment as env
from mcjax.models.platforms import FixedWingLimits, fixed_wing_step
from mcjax.models.sensors import azimuth
from mcjax.numerics import symmetrize, wrap_angle
from mcjax.planning import urban
from mcjax.planning.solvers import PlanCost, PlannerOptions, solve
from mcjax.scenarios import kit

NAME = "urban_bearing"

FILTER_KINDS = ("imm", "ekf")
PLANNERS = ("grid", "gradient")
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
    planner=Setting("grid", "grid = the paper's search over (theta, omega); gradient = optax on the smooth "
                    "surrogate", choices=PLANNERS),
    plan_iterations=Setting(20, "gradient planner: Adam steps per re-plan", low=1, integer=True),
    plan_learning_rate=Setting(0.3, "gradient planner: Adam step on the squashed command", low=0, low_open=True),
), __name__, _check)


_POS = dict(low=0.0, low_open=True)
_PROB = dict(low=0.0, high=1.0)
#: Our building layout (the paper gives heights only): rows [x_lo, y_lo, x_hi, y_hi, height] in m.
DEFAULT_BUILDINGS = np.array([[4750.0, 5050.0, 4850.0, 5150.0, 200.0],
                              [5100.0, 4800.0, 5250.0, 4900.0, 100.0]])
_TRANSITION = np.array([[0.90, 0.05, 0.05], [0.05, 0.90, 0.05], [0.05, 0.05, 0.90]])

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
                         "(ours)", **_PROB, shape=(3, 3)),
    mu0=Param(np.array([0.8, 0.1, 0.1]), "", "the IMM's initial mode probabilities (ours)", **_PROB, shape=(3,)),
    prior_sigma=Param(1000.0, "m", "std of the initial estimate about the emitter per axis; the initial FIM "
                      "is its inverse square (ours)", **_POS),
    process_noise=Param(0.0, "m", "std of the filters' random walk per step (paper: none)", low=0.0),
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
        b = _buildings_np(boxes)
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


def _buildings_np(boxes) -> env.Buildings:
    boxes = np.asarray(boxes, np.float64)
    return env.Buildings(boxes[:, 0:2], boxes[:, 2:4], boxes[:, 4])


def buildings_of(params) -> env.Buildings:
    b = params.buildings
    return env.Buildings(b[:, 0:2], b[:, 2:4], b[:, 4])


def limits_of(cfg, params) -> FixedWingLimits:
    return FixedWingLimits(params.theta_max, jnp.asarray(cfg.theta_rate_max, params.theta_max.dtype),
                           params.omega_max, jnp.asarray(cfg.omega_rate_max, params.theta_max.dtype),
                           params.h_min, params.h_max)


def mode_models(params, name: str):
    """Per-mode (bias, σ) of a filter (eqs. 11–12): the IMM's LOS, NLOS+, NLOS− or the
    single LOS EKF."""
    if name == "imm":
        bias = jnp.stack([params.bias_los, params.bias_nlos, -params.bias_nlos])
        sigma = jnp.stack([params.sigma_los, params.sigma_nlos, params.sigma_nlos])
    else:
        bias, sigma = params.bias_los[None], params.sigma_los[None]
    return bias, sigma


class State(NamedTuple):
    t: jax.Array
    uav: jax.Array        # (4,) [x, y, z, ψ]
    command: jax.Array    # (2,) the last applied (θ, ω)
    measured: jax.Array   # () bool: the last step brought a measurement
    filters: tuple        # one IMMState per filter: μ (M,), x (M, 2), P (M, 2, 2)
    fim: jax.Array        # (3, 2, 2) the IMM modes' accumulated FIM (eq. 13)


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
    """The UAV at ``uav0`` with command (0, 0); every filter at the prior: mean drawn about the
    emitter with std ``prior_sigma`` per axis (one draw per run, shared by the filters),
    covariance ``prior_sigma² I``; the IMM modes at ``mu0``; FIM_0 = the prior's information."""
    dtype = jnp.dtype(cfg.dtype)
    p = kit.cast(params, dtype)
    x0 = p.emitter[:2] + p.prior_sigma * jax.random.normal(key, (2,), dtype)
    P0 = p.prior_sigma**2 * jnp.eye(2, dtype=dtype)
    filters = []
    for name in cfg.filters:
        m = 3 if name == "imm" else 1
        mu = p.mu0 if m == 3 else kit.per_run(p.prior_sigma, jnp.ones(1, dtype))  # per-run: kit.per_run
        filters.append(IMMState(mu, jnp.broadcast_to(x0, (m, 2)), jnp.broadcast_to(P0, (m, 2, 2))))
    fim0 = jnp.broadcast_to(jnp.eye(2, dtype=dtype) / p.prior_sigma**2, (3, 2, 2))
    command, measured = kit.per_run(p.prior_sigma, jnp.zeros(2, dtype), jnp.asarray(True))
    return State(jnp.asarray(0, jnp.int32), p.uav0, command, measured, tuple(filters), fim0)


def _mode_filter(x, P, model, z, uav, q):
    """Mode-matched EKF (eqs. 2, 11–12): predict the static target (``P + q² I``), update with
    the azimuth biased by the mode's mean."""
    bias, sigma = model
    P = symmetrize(P + q**2 * jnp.eye(2, dtype=P.dtype))

    def h(xy):
        return (azimuth(xy, uav) + bias)[None]

    return ekf_update(x, P, z[None], h, (sigma**2)[None, None], angle_mask=jnp.array([True]))


def planner_options(cfg) -> PlannerOptions:
    return PlannerOptions(cfg.planner, cfg.plan_iterations, learning_rate=cfg.plan_learning_rate)


def plan_command(cfg, params, b: env.Buildings, uav, previous, belief: urban.Belief, key):
    """The planner's command: the grid of Alg. 1 (or the gradient planner on the smooth score)
    over the commands the rate limits allow, maximising eq. 20 among the admissible ones
    (:mod:`mcjax.planning.urban`). Plans live in the unit box: u ∈ [−1, 1]² maps to the
    command box. The gradient planner falls back to the grid's best admissible command when it
    ends on an inadmissible one. Returns ``(command (2,), exact score, admissible)``."""
    lim = limits_of(cfg, params)
    w = urban.Weights(params.c1, params.c2, params.c3)
    lo, hi = urban.command_box(previous, lim, cfg.dt)
    width = hi - lo
    safe_w = jnp.where(width > 0, width, 1.0)

    def to_command(u):
        return jnp.clip(lo + (u + 1.0) / 2.0 * width, lo, hi)

    def to_unit(c):
        return jnp.where(width > 0, 2.0 * (c - lo) / safe_w - 1.0, 0.0)

    def track_of(c):
        return urban.predicted_track(uav, c, params.speed, cfg.dt, cfg.horizon)

    def ok(c, track):
        return urban.admissible(b, uav, c, track, lim, params.speed, cfg.dt, cfg.theta_rate_max * cfg.dt)

    def exact(u):
        c = to_command(u)
        track = track_of(c)
        score = urban.track_score(urban.score_terms(b, belief, track, cfg.fim_score), w)
        return jnp.where(ok(c, track), -score, jnp.inf)

    def smooth(u):
        c = to_command(u)
        track = track_of(c)
        return -urban.track_score(urban.smooth_score_terms(b, belief, track, cfg.fim_score, params.plan_temperature), w)

    counts = urban.grid_counts(cfg.theta_rate_max, cfg.omega_rate_max, cfg.dt, cfg.theta_step, cfg.omega_step)
    commands = urban.candidate_commands(previous, lim, cfg.dt, (cfg.theta_step, cfg.omega_step), counts)
    candidates = jax.vmap(to_unit)(commands)
    warm = to_unit(previous)
    grid = solve(PlanCost(exact), warm, key, PlannerOptions("grid"), candidates)
    if cfg.planner == "grid":
        plan = grid
    else:
        # Adam from the better of the previous command and the level-off one; if it ends on an
        # inadmissible command (a track that was clear one step ago can meet a building at its
        # new last step), the grid's best admissible command is flown instead (ours: the hard
        # constraints hold whatever the planner)
        level = candidates[counts[0] * counts[1] + counts[1] // 2]
        warm = jnp.where(exact(level) < exact(warm), level, warm)
        plan = solve(PlanCost(exact, smooth), warm, key, planner_options(cfg))
        plan = jax.tree.map(lambda g, a: jnp.where(jnp.isfinite(plan.cost), a, g), grid, plan)
    return to_command(plan.u), -plan.cost, jnp.isfinite(plan.cost)


def _violation(cfg, params, previous, command, uav):
    lim = limits_of(cfg, params)
    tol = 1e-9
    return ((jnp.abs(command[0]) > lim.theta_max + tol) | (jnp.abs(command[1]) > lim.omega_max + tol)
            | (jnp.abs(command[0] - previous[0]) > lim.theta_rate_max * cfg.dt + tol)
            | (jnp.abs(command[1] - previous[1]) > lim.omega_rate_max * cfg.dt + tol)
            | (uav[2] < lim.h_min - tol) | (uav[2] > lim.h_max + tol))


def _filter_bank(cfg, p, state: State, mode_filter, z, uav, *gate):
    """Every configured filter's IMM cycle (eqs. 11–12; one mode for the single-model EKF) on
    the measurement ``z`` (``gate``: the surrogate's measurement weight); returns the new
    filter states and each filter's position error."""
    dtype = jnp.dtype(cfg.dtype)
    first = state.t == 0
    new_filters, errors = [], []
    for name, fstate in zip(cfg.filters, state.filters):
        bias, sg = mode_models(p, name)
        m = bias.shape[0]
        transition = p.imm_transition if m == 3 else jnp.ones((1, 1), dtype)
        transition = jnp.where(first, jnp.eye(m, dtype=dtype), transition)
        fnew, (x, _) = imm_step(fstate, transition, mode_filter, (bias, sg), z, uav, p.process_noise, *gate)
        new_filters.append(fnew)
        errors.append(jnp.sqrt(jnp.sum((x - p.emitter[:2]) ** 2))[None])
    return new_filters, errors


def step(cfg, params, state: State, key) -> tuple[State, Record]:
    """One step of Chen & Hao 2022, Alg. 1: plan (or hold the command after a step in the
    shadow), fly one step (eq. 1), measure the azimuth (eqs. 5–6 with the LOS or NLOS noise),
    run every filter (IMM-EKF, eqs. 11–12) and accumulate the IMM modes' FIM (eq. 13)."""
    dtype = jnp.dtype(cfg.dtype)
    p = kit.cast(params, dtype)
    b = buildings_of(p)
    k_plan, k_noise = jax.random.split(key)

    imm = state.filters[cfg.filters.index("imm")]
    xy, _ = combine(imm)
    _, sig = mode_models(p, "imm")
    belief = urban.Belief(xy, imm.x, imm.mu, state.fim, sig, p.emitter[2])
    planned, score, _ = plan_command(cfg, p, b, state.uav, state.command, belief, k_plan)
    # in the shadow the paper holds the previous command; ours: only while it stays admissible
    lim = limits_of(cfg, p)
    hold_track = urban.predicted_track(state.uav, state.command, p.speed, cfg.dt, cfg.horizon)
    hold_ok = urban.admissible(b, state.uav, state.command, hold_track, lim, p.speed, cfg.dt,
                               cfg.theta_rate_max * cfg.dt)
    held = ~state.measured & hold_ok
    command = jnp.where(held, state.command, planned)
    uav = fixed_wing_step(state.uav, command[0], command[1], p.speed, cfg.dt)

    # the measurement (eqs. 2, 5–6): no line of sight -> none; a reflection -> NLOS noise
    pos = uav[:3]
    los = env.line_of_sight(b, p.emitter, pos)
    reflected = jnp.any(env.reflections(b, p.emitter, pos).valid) & (p.R2 > 0)
    clean = env.measured_bearing(b, p.emitter, pos, p.R2, p.power, p.directivity)
    sigma = jnp.where(reflected, p.sigma_nlos, p.sigma_los)
    z = jnp.where(los, wrap_angle(clean + sigma * jax.random.normal(k_noise, (), dtype)), jnp.nan)

    new_filters, errors = _filter_bank(cfg, p, state, _mode_filter, z, uav)
    imm_new = new_filters[cfg.filters.index("imm")]
    gained = jax.vmap(lambda x, s: urban.bearing_information(x, uav, s))(imm_new.x, sig)
    fim = state.fim + jnp.where(los, gained, 0.0)

    rec = Record(
        error=jnp.stack(errors), uav=uav, command=command, held=held, shadow=~los, nlos=los & reflected,
        in_building=env.inside(b, pos), violation=_violation(cfg, p, state.command, command, uav),
        mu=imm_new.mu, score=jnp.where(held, jnp.nan, score))
    return State(state.t + 1, uav, command, los, tuple(new_filters), fim), rec


class Smoothing(NamedTuple):
    """Temperatures of the training surrogate (:func:`smooth_step`; ``[tune.smoothing]`` of a
    tune spec). Ours: the paper has no smooth model."""

    geometry: float = 20.0   # m: every building test (LOS, shadow, reflections, occupancy, altitude band)
    plan: float = 0.1        # the soft argmax over the grid: τ in units of the candidates' score spread
    command: float = 1e-3    # rad, rad/s: the soft max/min of the command box's limits


#: Weight of a measurement in deep shadow (the soft gate never reaches 0, so R/g stays finite).
_GATE_FLOOR = 1e-9


def _gated_mode_filter(x, P, model, z, uav, q, gate):
    """:func:`_mode_filter` (Chen & Hao 2022, eqs. 2, 11–12) for a measurement of weight
    ``gate`` ∈ (0, 1] (the smooth line of sight): the update with the tempered likelihood
    ``p(z|x)^g``, i.e. the EKF with noise ``σ²/g``, and its mode likelihood
    ``log N(ν; 0, S_g) + ½ log(2πσ²/g) − (g/2) log(2πσ²)`` — the IMM's eq. 12 likelihood at
    g = 1, and 0 (no information, as the exact filter's skipped update) as g → 0."""
    bias, sigma = model
    P = symmetrize(P + q**2 * jnp.eye(2, dtype=P.dtype))
    var = sigma**2

    def h(xy):
        return (azimuth(xy, uav) + bias)[None]

    x, P, ll = ekf_update(x, P, z[None], h, (var / gate)[None, None], angle_mask=jnp.array([True]))
    two_pi_var = 2.0 * jnp.pi * var
    return x, P, ll + 0.5 * jnp.log(two_pi_var / gate) - 0.5 * gate * jnp.log(two_pi_var)


def smooth_plan_command(cfg, params, b: env.Buildings, uav, previous, belief: urban.Belief, smoothing):
    """The training surrogate of :func:`plan_command`, for the grid planner of Chen & Hao 2022,
    Alg. 1 (lines 3–9) and eq. 20: the same grid of candidate commands (spread over a soft
    command box, :func:`mcjax.planning.urban.soft_candidate_commands`), each scored by the
    smooth eq. 20 score (:func:`mcjax.planning.urban.surrogate_score_terms`), the choice a
    soft argmax weighed by smooth admissibility (:func:`mcjax.planning.urban.soft_argmax_command`).
    No fallback and no warm-start switch: the command is a smooth function of the weights,
    the state and the belief. Used for either ``Config.planner`` (docs/tune.md)."""
    lim = limits_of(cfg, params)
    w = urban.Weights(params.c1, params.c2, params.c3)
    T = smoothing.geometry
    lo, hi = urban.soft_command_box(previous, lim, cfg.dt, smoothing.command)
    counts = urban.grid_counts(cfg.theta_rate_max, cfg.omega_rate_max, cfg.dt, cfg.theta_step, cfg.omega_step)
    commands = urban.soft_candidate_commands(lo, hi, counts, smoothing.command)

    def score(c):
        track = urban.predicted_track(uav, c, params.speed, cfg.dt, cfg.horizon)
        j = urban.track_score(urban.surrogate_score_terms(b, belief, track, cfg.fim_score, T), w)
        ok = urban.soft_admissible_log(b, uav, c, track, lim, params.speed, cfg.dt, cfg.theta_rate_max * cfg.dt, T)
        return j, ok

    scores, log_ok = jax.vmap(score)(commands)
    command, _ = urban.soft_argmax_command(commands, scores, log_ok, smoothing.plan)
    return command


def smooth_step(cfg, params, state: State, key, smoothing: Smoothing) -> tuple[State, jax.Array]:
    """:func:`step` (Chen & Hao 2022, Alg. 1) with every hard switch smooth, for training by
    gradient (``mcjax tune``); the same random draws. Replaced switches (docs/tune.md):

    * the planner's grid argmax (and, for the gradient planner, its clip to the command box,
      fallback and warm-start switch) -> :func:`smooth_plan_command`;
    * the shadow hold (``held = no LOS at the last step & the held command admissible``) ->
      the blend ``h·previous + (1 − h)·planned`` with ``h = (1 − los_prev)·p_adm(previous)``,
      ``los_prev`` the smooth line of sight at the UAV's position (where the last measurement
      was taken; 1 at step 0, as the exact ``measured`` starts True);
    * the measurement gate (no LOS -> no measurement) -> a measurement of weight
      ``g = los`` (:func:`_gated_mode_filter`), its bearing from the smooth field
      (:func:`mcjax.planning.urban.soft_measured_bearing`), its noise σ blended between LOS
      and NLOS by the smooth "a reflection arrives";
    * the FIM accumulation (eq. 13: only with LOS) -> weighted by ``los``.

    Returns the new state and the position errors (F, 1) of every filter."""
    dtype = jnp.dtype(cfg.dtype)
    p = kit.cast(params, dtype)
    b = buildings_of(p)
    T = smoothing.geometry
    k_plan, k_noise = jax.random.split(key)
    del k_plan

    imm = state.filters[cfg.filters.index("imm")]
    xy, _ = combine(imm)
    _, sig = mode_models(p, "imm")
    belief = urban.Belief(xy, imm.x, imm.mu, state.fim, sig, p.emitter[2])
    planned = smooth_plan_command(cfg, p, b, state.uav, state.command, belief, smoothing)
    lim = limits_of(cfg, p)
    hold_track = urban.predicted_track(state.uav, state.command, p.speed, cfg.dt, cfg.horizon)
    hold_ok = jnp.exp(urban.soft_admissible_log(b, state.uav, state.command, hold_track, lim, p.speed, cfg.dt,
                                                cfg.theta_rate_max * cfg.dt, T))
    los_prev = jnp.where(state.t == 0, 1.0, urban.soft_line_of_sight(b, p.emitter, state.uav[:3], T))
    held = (1.0 - los_prev) * hold_ok
    command = held * state.command + (1.0 - held) * planned
    uav = fixed_wing_step(state.uav, command[0], command[1], p.speed, cfg.dt)

    pos = uav[:3]
    clean, los, reflected = urban.soft_measured_bearing(b, p.emitter, pos, p.R2, p.power, p.directivity, T)
    reflected = jnp.where(p.R2 > 0, reflected, 0.0)
    sigma = p.sigma_los + reflected * (p.sigma_nlos - p.sigma_los)
    z = wrap_angle(clean + sigma * jax.random.normal(k_noise, (), dtype))
    gate = _GATE_FLOOR + (1.0 - _GATE_FLOOR) * los

    new_filters, errors = _filter_bank(cfg, p, state, _gated_mode_filter, z, uav, gate)
    imm_new = new_filters[cfg.filters.index("imm")]
    gained = jax.vmap(lambda x, s: urban.bearing_information(x, uav, s))(imm_new.x, sig)
    fim = state.fim + los * gained
    return State(state.t + 1, uav, command, los > 0.5, tuple(new_filters), fim), jnp.stack(errors)


def training_weights(cfg, params):
    """What the training loss of ``mcjax tune`` reads: one UAV, weight 1 (the errors
    :func:`smooth_step` returns are (F, 1))."""
    return jnp.ones(1, jnp.dtype(cfg.dtype))


def outputs(cfg) -> dict[str, Output]:
    """Per-run summary fields (:func:`reduce`)."""
    return dict(
        **kit.error_outputs("m", "distance of the estimate from the emitter"),
        shadow_steps=Output("steps", "steps with no line of sight (no measurement)", False),
        nlos_steps=Output("steps", "steps whose measurement carried a reflection (biased)", False),
        held_steps=Output("steps", "steps flying the previous command after a step in the shadow", False),
        building_steps=Output("steps", "steps with the UAV inside a building (must be 0)", False),
        limit_violations=Output("steps", "steps whose command or altitude broke a limit of eq. 4 (must be 0)",
                                False),
        min_altitude=Output("m", "lowest altitude flown", False),
        mu_nlos_when_nlos=Output("", "the IMM's mean NLOS probability on steps with a reflected measurement "
                                 "(NaN if there were none)", False),
    )


def reduce(cfg, records: Record, params) -> dict:
    """One run's records (stacked over time) -> the fields of :func:`outputs`."""
    e = records.error
    alive = jnp.ones(1, e.dtype)
    out = kit.error_summary(e, alive, cfg.warmup_steps, cfg.divergence_threshold)
    nlos = records.nlos
    mu_nlos = records.mu[:, NLOS_PLUS] + records.mu[:, NLOS_MINUS]
    out.update(
        shadow_steps=jnp.sum(records.shadow), nlos_steps=jnp.sum(nlos), held_steps=jnp.sum(records.held),
        building_steps=jnp.sum(records.in_building), limit_violations=jnp.sum(records.violation),
        min_altitude=jnp.min(records.uav[:, 2]),
        mu_nlos_when_nlos=jnp.sum(jnp.where(nlos, mu_nlos, 0.0)) / jnp.sum(nlos),
    )
    return out


def timeseries_outputs(cfg) -> dict[str, Output]:
    return dict(
        **kit.error_series_outputs("m", "distance of the estimate from the emitter"),
        x=Output("m", "UAV x", False), y=Output("m", "UAV y", False), z=Output("m", "UAV altitude", False),
        shadow=Output("", "1 = no line of sight (no measurement)", False),
        nlos=Output("", "1 = the measurement carried a reflection", False),
    )


def timeseries(cfg, records: Record, params) -> dict:
    e = records.error
    return dict(**{k: v for k, v in zip(("error_mean", "error_max"), (e[..., 0], e[..., 0]))},
                x=records.uav[:, 0], y=records.uav[:, 1], z=records.uav[:, 2],
                shadow=records.shadow.astype(e.dtype), nlos=records.nlos.astype(e.dtype))


SCENARIO = Scenario(
    name=NAME, title="Chen & Hao 2022: one UAV localises an emitter among buildings by azimuth (IMM-EKF, FIM "
    "planning)", Config=Config, Params=Params, init=init, step=step, reduce=reduce, outputs=outputs,
    timeseries=timeseries, timeseries_outputs=timeseries_outputs, check_params=check_params,
    surrogate=Surrogate(smooth_step, training_weights, Smoothing), compiler_options=FAST_COMPILE)
default_params = SCENARIO.default_params
