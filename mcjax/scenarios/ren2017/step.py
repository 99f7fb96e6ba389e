"""Ren & Lv 2017's UUV scenario, one step: the target moves in its true mode, the UUVs measure and
link, every filter runs its consensus IMM-UKF step; the state and the record."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcjax.scenarios import kit
from mcjax.scenarios.kit import bound as pcrb
from mcjax.scenarios.kit import consistency
from mcjax.scenarios.kit import faults
from mcjax.scenarios.ren2017.params import CT, CV, FILTER_MODES, unscented
from mcjax.scenarios.ren2017.relaxation import Temperatures, mode_hits
from mcjax.tracking import graph, metrics
from mcjax.tracking.filters.consensus_imm import consensus_imm_ukf_step
from mcjax.tracking.filters.gaussian import first_step_model
from mcjax.tracking.filters.imm import IMMState, combine
from mcjax.tracking.models.motion import ct_matrix, cv_matrices, cv_process_noise
from mcjax.tracking.models.sensors import range_bearing
from mcjax.tracking.numerics import matvec, spd_inverse


class State(NamedTuple):
    t: jax.Array
    target: jax.Array   # (4,)
    mode: jax.Array     # () int, the target's current mode (0 = CV, 1 = CT)
    filters: tuple      # one IMMState per filter, node axis first: μ (n, M), x (n, M, 4), P (n, M, 4, 4)
    faults: faults.State | None  # lost links and UUVs (None: faults off)
    bound: pcrb.Bound | None = None  # the PCRB's covariance of the target, team and per agent (None: off)


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
    bound: pcrb.Bound | None = None  # the PCRB's position variances, team () and per agent (n,), m² (None: off)
    nis: jax.Array | None = None  # (F, n) NIS of the combined prediction, NaN without a measurement (None: off)


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
                 faults.init(cfg, key, params), pcrb.initial(cfg, jnp.zeros_like(P0)))  # the filters start at the true state


def _true_mode(cfg, params, state: State, key):
    """The mode of the target's transition into step t: the fixed schedule (CT on
    ``[ct_start, ct_stop)``) or one draw of the Markov chain ``target_transition`` (Ren & Lv 2017)."""
    if cfg.schedule == "fixed":
        t = state.t.astype(params.ct_start.dtype)
        return ((t >= params.ct_start) & (t < params.ct_stop)).astype(jnp.int32)
    logp = jnp.log(params.target_transition[state.mode])
    return jax.random.categorical(key, logp).astype(jnp.int32)


def step(cfg, params, state: State, key, temperatures: Temperatures | None = None) -> tuple[State, Record]:
    """One step: move the target (CV or CT, docs/equations.md), measure range and bearing at
    every UUV, build the comm graph, run every filter's consensus IMM-UKF step (Ren & Lv 2017,
    docs/equations.md), record errors.

    Step 0 is the first measurement time: nothing moves and the filters update their prior
    without predicting or mixing (docs/equations.md).

    ``temperatures`` (the relaxation switch, :class:`Temperatures`; None: the exact simulation) swaps
    the sonar's range gate, the comm links (and so the Metropolis weights of Ren & Lv 2017's
    consensus, eq. 8, built from them), the component sizes of the information weighting and
    the IMM's "likelier mode" indicator for their smooth versions (:func:`kit.soft_team_measurements`,
    :func:`graph.soft_adjacency`, :func:`robustness.soft_component_sizes`, :func:`mode_hits`), with the same
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
    z, comm_graph, adj, gates, sizes = kit.sense_and_link(k_meas, target, sensors, params, sensing, comm, alive, fault,
                                                          temperatures)

    Q = cv_process_noise(dt, params.sigma_accel, dtype)
    F_model, Q_model = first_step_model(
        first, jnp.stack([F_cv, ct_matrix(dt, params.turn_rate + params.model_turn_rate_error, dtype)]),
        jnp.stack([Q, Q]))
    R = jnp.diag(jnp.stack([params.sigma_range**2, params.sigma_bearing**2]))
    # the bound (bound = "on"), given the true mode sequence (a valid, looser floor than one over the modes)
    bound = pcrb.update(state.bound, *first_step_model(first, F_true, cv_process_noise(dt, params.target_sigma_accel,
                                                                                         dtype)),
                        range_bearing, target, sensors, z, jnp.diag(1.0 / jnp.diag(R)))
    angle_mask = jnp.array([False, True])

    new_filters, err, ne, nis = [], [], [], []
    mu_ct = jnp.full((n,), jnp.nan, dtype)
    for name, fstate in zip(cfg.filters, state.filters):
        modes = jnp.asarray(FILTER_MODES[name])
        m = len(FILTER_MODES[name])
        transition = params.imm_transition if m == 2 else jnp.ones((1, 1), dtype)
        transition = jnp.where(first, jnp.eye(m, dtype=dtype), transition)
        if cfg.consistency == "on":  # each UUV's own measurement against its combined prediction
            prior = consistency.imm_prediction(fstate, transition, F_model[modes], Q_model[modes])
            eye, zero = jnp.eye(4, dtype=dtype), jnp.zeros((4, 4), dtype)
            nis.append(consistency.predicted_nis(prior, eye, zero, range_bearing, sensors, z, jnp.diag(1.0 / jnp.diag(R)),
                                                 angle_mask))
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
        mode_hit=mode_hits(mu_ct, mode == CT, None if temperatures is None else temperatures.mode),
        lambda2=graph.algebraic_connectivity(adj),
        n_seeing=jnp.sum(seeing) if gates is None else jnp.sum(jnp.where(seeing, gates, 0.0)),
        target=target,
        measurements=z,
        faults=faults.record(comm_graph, adj, fault, alive),
        bound=pcrb.position_variance(bound),
        nis=jnp.stack(nis) if nis else None,
    )
    return State(state.t + 1, target, mode, tuple(new_filters), fault_state, bound), rec

