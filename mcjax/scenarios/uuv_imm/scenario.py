"""Six UUVs tracking a manoeuvring (CV ↔ CT) target by consensus IMM-UKF — Ren & Lv 2017.

Six stationary UUVs with range–bearing sonars track a target that switches between
constant velocity (CV) and a coordinated turn (CT) at turn rate ω, either on a fixed
schedule (CV, then CT over ``[ct_start, ct_stop)``, then CV — as in the paper's figures) or
as a Markov chain drawn per run (``Config.schedule = "markov"``). Each UUV runs, per filter:

* ``"imm"`` — the consensus IMM-UKF of Ren & Lv 2017 (CV and CT modes,
  :func:`mcjax.filters.consensus_imm.consensus_imm_ukf_step`);
* ``"cv"`` / ``"ct"`` — the single-model baselines: consensus UKF with the CV model only, or
  the CT model only (the same step with one mode, whose IMM cycle reduces to a UKF).

Consensus runs over the comm graph of ``Params.comm_radius`` (UUVs are stationary, so the
graph is fixed within a run; the default radius gives a ring). Each step records every
UUV's position error per filter (the paper's error E, read as the Euclidean position
error), the true mode and the IMM's CT probability.

Faults (``Config.faults = "on"``, :mod:`mcjax.scenarios.faults`): a lost link drops the
step's consensus messages on it (every iteration of the step: the graph is the step's); a
lost UUV measures nothing, its links carry nothing and its filters hold their states; a
dropped-out sonar gives no measurement that step. The UUVs do not move, so a lost one
changes no geometry.

Units are SI (m, s, rad). The paper's values and our choices for what it leaves open are
listed in ``configs/ren2017.toml``.
"""

from __future__ import annotations

from functools import cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mcjax import graph, metrics
from mcjax.contract import Output, Param, Scenario, Setting, config_type, declare, params_type
from mcjax.filters.consensus_imm import LIKELIHOODS, consensus_imm_ukf_step
from mcjax.filters.gaussian import Unscented, first_step_model
from mcjax.filters.imm import IMMState, combine
from mcjax.models.motion import ct_matrix, cv_matrices, cv_process_noise
from mcjax.models.sensors import range_bearing
from mcjax.numerics import matvec, spd_inverse
from mcjax.scenarios import faults, kit
from mcjax.scenarios.uuv_imm.smoothing import (
    Smoothing, mode_hits,
)
from mcjax.smoothing import Smooth

NAME = "uuv_imm"

#: Filters: name → the target modes it models (0 = CV, 1 = CT).
FILTER_MODES = {"imm": (0, 1), "cv": (0,), "ct": (1,)}
FILTER_KINDS = tuple(FILTER_MODES)
SCHEDULES = ("fixed", "markov")
WEIGHT_KINDS = ("metropolis", "max_degree")
CV, CT = 0, 1

#: Config: everything that fixes shapes or the compiled program (changing it recompiles).
Config = config_type("Config", dict(
    **kit.common_settings(filter_kinds=FILTER_KINDS, n_agents=6, n_steps=100, min_steps=2, warmup_steps=5,
                      divergence_threshold=100.0),
    consensus_steps=Setting(3, "consensus iterations L per step and mode (ours)", low=0, integer=True),
    consensus_weights=Setting("metropolis", "consensus weights (paper: Metropolis)", choices=WEIGHT_KINDS),
    likelihood=Setting("fused", "mode likelihoods: fused by consensus (ours) or local (Li & Jia)",
                       choices=LIKELIHOODS),
    schedule=Setting("fixed", "target modes: fixed = CV, CT on [ct_start, ct_stop), CV; markov = drawn "
                     "per run from target_transition", choices=SCHEDULES),
    ut_alpha=Setting(1.0, "unscented transform alpha (ours; sigma-point spread, in (0, 1])", low=0, low_open=True,
                     high=1.0),
    ut_beta=Setting(2.0, "unscented transform beta (ours)", low=0),
    ut_kappa=Setting(0.0, "unscented transform kappa (ours; > -4, the state has 4 components)", low=-4,
                     low_open=True),
    **faults.SETTINGS,
), __name__, kit.check_common)


def unscented(cfg) -> Unscented:
    return Unscented(cfg.ut_alpha, cfg.ut_beta, cfg.ut_kappa)


def default_positions(cfg) -> np.ndarray:
    """Our UUV layout (the paper gives none): ``n`` UUVs on a circle of radius 400 m about
    (100 m, 200 m), the middle of the default target path, so neighbours on the circle are
    400 m apart for n = 6 and the default 450 m comm radius links each UUV to its two ring
    neighbours only (a ring: consensus needs several hops to spread information)."""
    n = cfg.n_agents
    angles = 2 * np.pi * np.arange(n) / max(n, 1)
    return np.stack([100.0 + 400.0 * np.cos(angles), 200.0 + 400.0 * np.sin(angles)], -1)


_POS = dict(low=0.0, low_open=True)
_NONNEG = dict(low=0.0)
_PROB = dict(low=0.0, high=1.0)
_CHAIN = np.array([[0.95, 0.05], [0.05, 0.95]])
#: Params: per-run values a sweep may vary without recompiling (Ren & Lv 2017, sec. 4, and
#: our choices where it is silent: configs/ren2017.toml says which).
Params = params_type("Params", dict(
    dt=Param(1.0, "s", "sampling = consensus interval (ours)", **_POS),
    comm_radius=Param(450.0, "m", "communication radius (ours: 450 m makes a ring)", **_NONNEG, per_agent=True),
    sensing_radius=Param(10e3, "m", "sonar range (ours: every UUV always measures)", **_NONNEG, per_agent=True,
                         display="km"),
    sigma_range=Param(float(np.sqrt(5.0)), "m", "range noise std (paper R = diag[5, 0.5] read as variances)",
                      **_POS),
    sigma_bearing=Param(float(np.deg2rad(np.sqrt(0.5))), "rad", "bearing noise std (0.5 deg^2 variance)",
                        **_POS, high=float(np.pi)),
    turn_rate=Param(float(np.deg2rad(3.0)), "rad/s", "omega of the CT mode (ours: 3 deg/s)", low=-1.0, high=1.0),
    model_turn_rate_error=Param(0.0, "rad/s", "the filters' CT model uses omega + this (0: known omega)",
                                low=-1.0, high=1.0),
    sigma_accel=Param(0.05, "m/s^2", "the filters' process-noise acceleration std (both modes)", **_POS),
    target_sigma_accel=Param(0.01, "m/s^2", "the true target's acceleration noise std", **_NONNEG),
    ct_start=Param(lambda cfg: float(cfg.n_steps // 3), "steps", "step the CT manoeuvre starts (schedule fixed)",
                   **_NONNEG),
    ct_stop=Param(lambda cfg: float(2 * cfg.n_steps // 3), "steps", "step it ends, exclusive (schedule fixed)",
                  **_NONNEG),
    target_transition=Param(_CHAIN, "", "the true mode chain P(j | l), rows from CV, CT (schedule markov)",
                            **_PROB, shape=(2, 2)),
    imm_transition=Param(_CHAIN, "", "the IMM's mode transition matrix", **_PROB, shape=(2, 2)),
    mu0=Param(np.array([0.5, 0.5]), "", "the IMM's initial mode probabilities [CV, CT]", **_PROB, shape=(2,)),
    uuv_positions=Param(default_positions, "m", "the stationary UUVs (ours: a hexagon)", shape=("n", 2)),
    target_x0=Param(np.array([0.0, 5.0, 0.0, 5.0]), "m, m/s", "initial target state [x, vx, y, vy] (paper)",
                    shape=(4,)),
    p0_diag=Param(np.array([10.0**2, 1.0, 10.0**2, 1.0]), "m^2, (m/s)^2",
                  "prior variances at the first measurement (ours)", **_POS, shape=(4,)),
    alive=Param(lambda cfg: np.ones(cfg.n_agents), "", "1 = alive, 0 = dropped out (masked, never removed)",
                choices=(0, 1), per_agent=True),
    **faults.PARAMS,
), __name__)


def check_params(cfg, values: dict) -> list[tuple[str, str]]:
    """Checks across fields: ``[(field, what is allowed), …]`` for the bad ones."""
    bad = []
    table = Params.TABLE
    for name in ("target_transition", "imm_transition"):
        m = np.asarray(values.get(name, table[name].default), np.float64)
        if np.any(np.abs(m.sum(-1) - 1.0) > 1e-9):
            bad.append((name, "a 2x2 matrix [[P(CV|CV), P(CT|CV)], [P(CV|CT), P(CT|CT)]] whose rows sum to 1"))
    mu0 = np.asarray(values.get("mu0", table["mu0"].default), np.float64)
    if np.any(np.abs(mu0.sum(-1) - 1.0) > 1e-9):
        bad.append(("mu0", "two probabilities [CV, CT] that sum to 1"))
    start = np.asarray(values.get("ct_start", table["ct_start"].default_value(cfg)), np.float64)
    stop = np.asarray(values.get("ct_stop", table["ct_stop"].default_value(cfg)), np.float64)
    if np.any(stop < start):
        bad.append(("ct_stop", "a step >= ct_start"))
    return bad + faults.check(cfg, values, Params)


class State(NamedTuple):
    t: jax.Array
    target: jax.Array   # (4,)
    mode: jax.Array     # () int, the target's current mode (0 = CV, 1 = CT)
    filters: tuple      # one IMMState per filter, node axis first: μ (n, M), x (n, M, 4), P (n, M, 4, 4)
    faults: faults.State | None  # lost links and UUVs (None: faults off)


class Record(NamedTuple):
    error: jax.Array    # (F, n) position error per filter and UUV, m
    nees: jax.Array     # (F, n) full-state NEES of the combined estimate
    mode: jax.Array     # () true mode during the step's transition (0 = CV, 1 = CT)
    mu_ct: jax.Array    # (n,) the IMM's CT probability per UUV (NaN without "imm")
    mode_hit: jax.Array  # (n,) 1.0 where the IMM's likelier mode is the true one (soft when smoothed)
    lambda2: jax.Array  # ()
    n_seeing: jax.Array  # () UUVs with a measurement (the sum of the soft gates when smoothed)
    target: jax.Array   # (4,)
    measurements: jax.Array  # (n, 2) range–bearing, NaN where none
    faults: faults.Record | None  # the step's faults (None: off)



def init(cfg, params, key) -> State:
    """State before step 0: the target at ``target_x0`` in CV, and every UUV's filters at the
    prior (the true initial state, covariance ``diag(p0_diag)``; IMM mode probabilities ``mu0``);
    no fault yet."""
    n, dtype = cfg.n_agents, jnp.dtype(cfg.dtype)
    params = kit.cast(params, dtype)
    x0 = params.target_x0
    P0 = jnp.diag(params.p0_diag)
    states = []
    for f in cfg.filters:
        m = len(FILTER_MODES[f])
        mu = params.mu0 if m == 2 else kit.per_run(params.dt, jnp.ones(1, dtype))  # per-run: kit.per_run
        states.append(IMMState(jnp.broadcast_to(mu, (n, m)), jnp.broadcast_to(x0, (n, m, 4)),
                               jnp.broadcast_to(P0, (n, m, 4, 4))))
    return State(jnp.asarray(0, jnp.int32), x0, kit.per_run(params.dt, jnp.asarray(CV, jnp.int32)), tuple(states),
                 faults.init(cfg, key, params))


def _true_mode(cfg, params, state: State, key):
    """The mode of the target's transition into step t: the fixed schedule (CT on
    ``[ct_start, ct_stop)``) or one draw of the Markov chain ``target_transition`` (Ren & Lv 2017)."""
    if cfg.schedule == "fixed":
        t = state.t.astype(params.ct_start.dtype)
        return ((t >= params.ct_start) & (t < params.ct_stop)).astype(jnp.int32)
    logp = jnp.log(params.target_transition[state.mode])
    return jax.random.categorical(key, logp).astype(jnp.int32)


def step(cfg, params, state: State, key, smoothing: Smoothing | None = None) -> tuple[State, Record]:
    """One step: move the target (CV or CT, docs/equations.md), measure range and bearing at
    every UUV, build the comm graph, run every filter's consensus IMM-UKF step (Ren & Lv 2017,
    docs/equations.md), record errors.

    Step 0 is the first measurement time: nothing moves and the filters update their prior
    without predicting or mixing (docs/equations.md).

    ``smoothing`` (the smoothing switch, :class:`Smoothing`; None: the exact simulation) swaps
    the sonar's range gate, the comm links (and so the Metropolis weights of Ren & Lv 2017's
    consensus, eq. 8, built from them), the component sizes of the information weighting and
    the IMM's "likelier mode" indicator for their smooth versions (:func:`kit.soft_team_measurements`,
    :func:`graph.soft_adjacency`, :func:`graph.soft_component_sizes`, :func:`mode_hits`), with the same
    random draws. The target's mode jumps stay exact (rough). The graph statistics are then
    those of the soft links' weights and ``n_seeing`` is the sum of the soft gates."""
    n, dtype = cfg.n_agents, jnp.dtype(cfg.dtype)
    params = kit.cast(params, dtype)
    first = state.t == 0
    k_mode, k_target, k_meas = jax.random.split(key, 3)
    dt = params.dt

    F_cv, G = cv_matrices(dt, dtype)
    mode = jnp.where(first, state.mode, _true_mode(cfg, params, state, k_mode))
    F_true = jnp.where(mode == CT, ct_matrix(dt, params.turn_rate, dtype), F_cv)
    w = params.target_sigma_accel * jax.random.normal(k_target, (2,), dtype)
    target = jnp.where(first, state.target, matvec(F_true, state.target) + matvec(G, w))

    sensors = jnp.asarray(params.uuv_positions, dtype)
    alive = kit.agents(params.alive, n, dtype) > 0.5
    fault_state, fault = faults.advance(key, state.faults, params, alive)
    sensing, comm = kit.agents(params.sensing_radius, n, dtype), kit.agents(params.comm_radius, n, dtype)
    if smoothing is None:
        z = faults.measurements(kit.team_measurements(k_meas, target, sensors, params.sigma_range,
                                                      params.sigma_bearing, sensing, alive), fault)
        comm_graph = graph.adjacency(sensors, comm, alive)
        gates = sizes = None
    else:  # (the smooth component sizes see lost UUVs, not lost links)
        z, gates = kit.soft_team_measurements(k_meas, target, sensors, params.sigma_range, params.sigma_bearing,
                                              sensing, alive, smoothing.sensing)
        z = faults.measurements(z, fault)
        comm_graph = graph.soft_adjacency(sensors, comm, smoothing.comm, alive)
        sizes = graph.soft_component_sizes(sensors, comm, smoothing.comm, alive & faults.alive(fault, n))
    adj = faults.messages(comm_graph, fault)

    Q = cv_process_noise(dt, params.sigma_accel, dtype)
    F_model, Q_model = first_step_model(
        first, jnp.stack([F_cv, ct_matrix(dt, params.turn_rate + params.model_turn_rate_error, dtype)]),
        jnp.stack([Q, Q]))
    R = jnp.diag(jnp.stack([params.sigma_range**2, params.sigma_bearing**2]))
    angle_mask = jnp.array([False, True])

    new_filters, err, ne = [], [], []
    mu_ct = jnp.full((n,), jnp.nan, dtype)
    for name, fstate in zip(cfg.filters, state.filters):
        modes = jnp.asarray(FILTER_MODES[name])
        m = len(FILTER_MODES[name])
        transition = params.imm_transition if m == 2 else jnp.ones((1, 1), dtype)
        transition = jnp.where(first, jnp.eye(m, dtype=dtype), transition)
        fnew, (x, P) = consensus_imm_ukf_step(
            faults.shield(fault, fstate), transition, F_model[modes], Q_model[modes], z, sensors, range_bearing, R, adj,
            steps=cfg.consensus_steps, weights=cfg.consensus_weights, likelihood=cfg.likelihood,
            ut=unscented(cfg), angle_mask=angle_mask, gates=gates, sizes=sizes)
        if fault is not None:  # a lost UUV's filter holds its state (and its combined estimate)
            fnew = faults.hold(fault, fnew, fstate)
            x, P = jax.vmap(combine)(fnew)
        new_filters.append(fnew)
        err.append(metrics.position_error(x, target))
        ne.append(metrics.nees(x, spd_inverse(P), target))
        if name == "imm":
            mu_ct = fnew.mu[:, CT]
    seeing = jnp.all(jnp.isfinite(z), axis=-1)
    rec = Record(
        error=jnp.stack(err),
        nees=jnp.stack(ne),
        mode=mode,
        mu_ct=mu_ct,
        mode_hit=mode_hits(mu_ct, mode == CT, None if smoothing is None else smoothing.mode),
        lambda2=graph.algebraic_connectivity(adj),
        n_seeing=jnp.sum(seeing) if gates is None else jnp.sum(jnp.where(seeing, gates, 0.0)),
        target=target,
        measurements=z,
        faults=faults.record(comm_graph, adj, fault, alive),
    )
    return State(state.t + 1, target, mode, tuple(new_filters), fault_state), rec


def _masked_mean(values, mask):
    mask = jnp.broadcast_to(mask, values.shape).astype(values.dtype)
    return jnp.sum(mask * values) / jnp.sum(mask)


def _per_filter(cfg, records: Record, alive, after, in_ct) -> dict:
    """Per filter (F,): the errors while the target is in CV (``~in_ct``) and in CT, the ANEES,
    and per UUV the max / min / mean of its own error over the steps ``after`` warm-up."""
    w, n = cfg.warmup_steps, cfg.n_agents
    extra = {k: [] for k in ("error_cv", "error_ct", "anees")}
    per_uuv = {f"uuv{i + 1}_{s}_error": [] for i in range(n) for s in ("max", "min", "mean")}
    for f in range(len(cfg.filters)):
        e, e_own = faults.masked(records.error[:, f, :], alive), records.error[:, f, :]
        extra["error_cv"].append(_masked_mean(e, (after & ~in_ct)[:, None] * alive))
        extra["error_ct"].append(_masked_mean(e, (after & in_ct)[:, None] * alive))
        extra["anees"].append(metrics.mean_over(faults.masked(records.nees[:, f, :], alive), w, alive))
        for i in range(n):
            ei = e_own[:, i]
            per_uuv[f"uuv{i + 1}_max_error"].append(jnp.max(jnp.where(after, ei, -jnp.inf)))
            per_uuv[f"uuv{i + 1}_min_error"].append(jnp.min(jnp.where(after, ei, jnp.inf)))
            per_uuv[f"uuv{i + 1}_mean_error"].append(jnp.sum(jnp.where(after, ei, 0.0)) / jnp.sum(after))
    return {k: jnp.stack(v) for k, v in {**extra, **per_uuv}.items()}


def summary(cfg, records: Record | None, params) -> dict:
    """One run's records (stacked over time) reduced to its outputs, each declared next to its
    value: the common error summary, the errors while the target flies straight and while it
    turns, and per UUV i (numbered from 1, as in the paper's Table 1) the max / min / mean over
    the steps after warm-up of its own position error."""
    r = records
    switched_on = cache(lambda: metrics.alive_weights(params.alive, cfg.n_agents, r.error.dtype))
    alive = cache(lambda: faults.weights(switched_on(), r.faults))
    after = cache(lambda: jnp.arange(r.error.shape[0]) >= cfg.warmup_steps)
    in_ct = cache(lambda: r.mode == CT)
    per_filter = cache(lambda: _per_filter(cfg, r, alive(), after(), in_ct()))

    def pick(name):
        return lambda: per_filter()[name]

    per_uuv = {f"uuv{i + 1}_{s}_error": (Output("m", f"{s} over the steps after warm-up of UUV {i + 1}'s position "
                                                "error (Table 1)"), pick(f"uuv{i + 1}_{s}_error"))
               for i in range(cfg.n_agents) for s in ("max", "min", "mean")}
    return declare(
        **kit.error_items(lambda: r.error, alive, cfg, "m"),
        error_cv=(Output("m", "mean position error over alive UUVs and steps after warm-up while the target is in "
                         "CV"), pick("error_cv")),
        error_ct=(Output("m", "the same while the target turns (CT); NaN if it never does"), pick("error_ct")),
        anees=(Output("", "mean full-state NEES over alive UUVs and steps after warm-up (4 dof)"), pick("anees")),
        **per_uuv,
        **kit.graph_items(lambda: r.lambda2),
        ct_steps=(Output("steps", "steps the target spent turning (CT)", False), lambda: jnp.sum(in_ct())),
        mode_accuracy=(Output("", "fraction of (UUV, step) after warm-up where the IMM's likelier mode is the true "
                              "one", False),
                       lambda: jnp.where(jnp.any(jnp.isnan(r.mu_ct)), jnp.nan,
                                         _masked_mean(r.mode_hit, after()[:, None] * alive()))),
        mu_ct_during_ct=(Output("", "the IMM's mean CT probability while the target turns", False),
                         lambda: _masked_mean(faults.masked(r.mu_ct, alive()), (after() & in_ct())[:, None] * alive())),
        **faults.summary_items(cfg, r and r.faults, switched_on),
    )


def series(cfg, records: Record | None, params) -> dict:
    """A few per-step series of one run, (T, F) per filter, (T,) otherwise, each declared next
    to its value; written when a sweep asks for them."""
    r = records
    switched_on = cache(lambda: metrics.alive_weights(params.alive, cfg.n_agents, r.error.dtype))
    alive = cache(lambda: faults.weights(switched_on(), r.faults))
    return declare(
        **kit.error_series_items(lambda: r.error, alive, "m"),
        mode=(Output("", "the target's true mode (0 = CV, 1 = CT)", False), lambda: r.mode),
        mu_ct=(Output("", "the IMM's CT probability, mean over alive UUVs (NaN without 'imm')", False),
               lambda: jnp.sum(faults.masked(r.mu_ct, alive()) * alive(), -1) / jnp.maximum(jnp.sum(alive(), -1), 1.0)),
        lambda2=(Output("", "algebraic connectivity of the comm graph", False), lambda: r.lambda2),
        **faults.series_items(cfg, r and r.faults, switched_on),
    )


def training_errors(cfg, params, record: Record):
    """What the training loss of ``mcjax tune`` reads from a step's record: the position errors
    (F, n) of every filter and UUV (the paper's error E)."""
    return record.error


def training_weights(cfg, params):
    """Each UUV's weight (n,) in the training loss: 1 if switched on (``alive``), else 0."""
    return metrics.alive_weights(params.alive, cfg.n_agents, jnp.dtype(cfg.dtype))


#: Params with no smooth path (:class:`mcjax.smoothing.Smooth`): the fault rates; the fixed
#: schedule's switch steps (step counts: the mode jumps at a threshold of t); the true mode
#: chain (each jump a threshold of a uniform draw).
ROUGH = (*faults.ROUGH, "ct_start", "ct_stop", "target_transition")

SCENARIO = Scenario(
    name=NAME, title="Ren & Lv 2017: six UUVs track a manoeuvring target by consensus IMM-UKF",
    Config=Config, Params=Params, init=init, step=step, summary=summary, series=series,
    check_params=check_params, smooth=Smooth(Smoothing, training_errors, training_weights, ROUGH),
    filter_words={
        "imm": "Ren & Lv 2017's consensus IMM-UKF: two motion models (constant velocity, coordinated turn) "
               "mixed by their probabilities, fused across UUVs by consensus",
        "cv": "the same consensus unscented Kalman filter with the constant-velocity model only",
        "ct": "the same consensus unscented Kalman filter with the coordinated-turn model only"})
default_params = SCENARIO.default_params
#: The record's derived functions (from :func:`summary` and :func:`series`), by their usual names.
reduce, outputs = SCENARIO.reduce, SCENARIO.outputs
timeseries, timeseries_outputs = SCENARIO.timeseries, SCENARIO.timeseries_outputs
