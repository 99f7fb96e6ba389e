"""Lou, Cui & Li 2013's flock (:mod:`.scenario`): its per-run state and per-step record, the
initial draw and the sampling step.

The bound (``Config.bound = "on"``; :mod:`mcjax.scenarios.kit.bound`, Tichavský, Muravchik &
Nehorai 1998). The target's path is deterministic (:func:`target_state`: y = sin x, or a line), so
no Bayesian floor above zero exists for it: an estimator that knows the path has zero error.
The bound computed is the floor for a target that moves as the filters' own model says — CV
driven by white acceleration of std ``sigma_accel`` (the filters' F and Q, no prediction at
step 0), prior ``diag(p0_diag)`` — seen by the type-I nodes' position measurements actually
taken (R = ``sigma_meas``² I; none from type-II, dropped-out or lost nodes). For this
linear-Gaussian model the recursion is exactly the covariance of the centralised Kalman filter
of those measurements (team) and of each node's own Kalman filter (local). It is the model's
floor, not a floor of the sine path: the path is smoother than the model's random
accelerations, so a filter's error on it may fall below the bound. Only type-I nodes measure,
so the local bound is averaged over them (:mod:`.scenario`).

Consistency (``Config.consistency = "on"``; :mod:`mcjax.scenarios.kit.consistency`): each
filter's and node's NEES of its 4-D ``[x, ẋ, y, ẏ]`` estimate against the true target and the
NIS of each type-I node's own position measurement against its own prediction (its state
before this step's update through the filters' F, Q), 4 and 2 dof; the outputs average the
type-I nodes only. On the sine path the filters' model is not the truth's, so χ² holds only as
far as the CV model covers the path."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcjax.scenarios import kit
from mcjax.scenarios.kit import bound as pcrb
from mcjax.scenarios.kit import consistency
from mcjax.scenarios.kit import faults
from mcjax.scenarios.lou2013 import dynamics as fl
from mcjax.scenarios.lou2013.params import lattice_sites
from mcjax.scenarios.lou2013.relaxation import Temperatures, soft_hysteresis, soft_link_changes
from mcjax.tracking import graph, metrics
from mcjax.tracking.filters.consensus import FilterOptions, Measurements
from mcjax.tracking.filters.gaussian import Gaussian, first_step_model
from mcjax.tracking.models.motion import cv_matrices, cv_process_noise
from mcjax.tracking.models.sensors import position
from mcjax.tracking.numerics import spd_inverse, symmetrize


class State(NamedTuple):
    t: jax.Array
    flock: fl.FlockState
    adj: jax.Array          # (N, N) hysteresis graph
    filters: tuple          # one Gaussian per filter, node axis first
    start_failed: jax.Array
    attempts: jax.Array
    faults: faults.State | None  # lost links and nodes (mcjax.scenarios.kit.faults; None: off)
    mailbox: faults.Mailbox | None  # the KCF's consensus messages in flight (None: message_delay = 0)
    bound: pcrb.Bound | None = None  # the PCRB's covariance of the model's target, team and per node (None: off)


class Record(NamedTuple):
    error: jax.Array        # (F, N) position error of each node's estimate (type-II rows: 0, weight 0)
    lambda2: jax.Array
    edges: jax.Array
    added: jax.Array
    removed: jax.Array
    min_distance: jax.Array      # smallest pairwise distance over the step's sub-steps
    min_link_margin: jax.Array   # smallest R - r over links and sub-steps (<= 0: a link reached R)
    energy: jax.Array            # φ of eq. 15 at the step's end (true target)
    speed_mismatch: jax.Array    # Σ_i |p_i - p_target|² at the step's end
    substeps: jax.Array          # sub-steps taken (dopri5: attempted, rejected ones included)
    capped: jax.Array            # the step needed more than max_substeps (its last took the rest)
    target: jax.Array            # (4,) [x, vx, y, vy]
    start_failed: jax.Array      # () no valid initial draw (the same at every step)
    attempts: jax.Array          # () initial draws used (the same at every step)
    faults: faults.Record | None  # the step's faults (None: off)
    bound: pcrb.Bound | None = None  # the PCRB's position variances, team () and per node (N,), m² (None: off)
    nees: jax.Array | None = None  # (F, N) NEES of each node's 4-D estimate (None: consistency off)
    nis: jax.Array | None = None   # (F, N) NIS of each node's own measurement, NaN without one (None: off)


def target_state(cfg, params, t):
    """The true target ``[x, ẋ, y, ẏ]`` at time t: along ``y = sin x`` at ẋ = ``target_speed``
    (Lou et al. 2013, Section 3; ours: the speed), or a straight line along x."""
    v = params.target_speed
    x = v * t
    if cfg.target_path == "sine":
        return jnp.stack([x, v, jnp.sin(x), v * jnp.cos(x)])
    return jnp.stack([x, v, jnp.zeros_like(x), jnp.zeros_like(x)])


def sensing_mask(cfg, params, dtype):
    return (jnp.arange(cfg.n_agents) < params.n_sensing).astype(dtype)


def _draw_start(cfg, p, key):
    """One draw of the initial flock (:mod:`.scenario`) and whether it meets the start rule."""
    n = cfg.n_agents
    kq, kp = jax.random.split(key)
    if cfg.start_layout == "uniform":
        q = p.box * jax.random.uniform(kq, (n, 2), p.box.dtype)
    else:
        sites = jnp.asarray(lattice_sites(n), p.box.dtype)
        q = p.lattice_spacing * sites + p.lattice_jitter * jax.random.uniform(kq, (n, 2), p.box.dtype, -1.0, 1.0)
    v = p.v0 * jax.random.uniform(kp, (n, 2), p.box.dtype)
    d = graph.pairwise_distances(q) + jnp.eye(n, dtype=q.dtype) * 1e9
    adj = ((d < p.R) & ~jnp.eye(n, dtype=bool)).astype(q.dtype)
    ok = ((graph.algebraic_connectivity(adj) > 1e-9) | (n == 1)) \
        & ~jnp.any((d >= p.R - p.start_margin) & (d < p.R)) & (jnp.min(d) >= p.start_min_distance)
    return q, v, adj, ok


def init(cfg, params, key) -> State:
    """The first valid draw of the initial flock (:mod:`.scenario`), every filter at the true
    target state with covariance ``diag(p0_diag)``, the adaptive gains at 0; no fault yet."""
    dtype, p = kit.typed(cfg, params)
    n = cfg.n_agents
    q, v, adj, ok = jax.vmap(lambda k: _draw_start(cfg, p, k))(jax.random.split(key, cfg.start_attempts))
    first = jnp.argmax(ok)
    found = jnp.any(ok)
    pick = jnp.where(found, first, cfg.start_attempts - 1)
    flock = fl.FlockState(q[pick], v[pick], kit.per_run(p.dt, jnp.zeros((n, n), dtype)))  # per-run: kit.per_run
    x0 = target_state(cfg, p, jnp.asarray(0.0, dtype))
    P0 = jnp.diag(p.p0_diag)
    g = Gaussian(x0, P0, symmetrize(spd_inverse(P0)))
    filters = tuple(jax.tree.map(lambda a: jnp.broadcast_to(a, (n,) + a.shape), g) for _ in cfg.filters)
    return State(jnp.asarray(0, jnp.int32), flock, adj[pick], filters, ~found, pick + 1,
                 faults.init(cfg, key, p), kit.kcf_mailbox(cfg, p, x0),
                 pcrb.initial(cfg, jnp.zeros_like(P0)))  # the filters start at the true target


def step(cfg, params, state: State, key, temperatures: Temperatures | None = None) -> tuple[State, Record]:
    """One sampling step (:mod:`.scenario`): measure, filter (Lou et al. 2013 Alg. 1), fly
    (eqs. 1, 10–13), update the hysteresis graph (Section 1.1, rules 2–3).

    ``temperatures`` (the relaxation switch, :class:`~.relaxation.Temperatures`; None: the exact
    simulation) makes the graph's links weights in [0, 1] with a soft hysteresis
    (:func:`~.relaxation.soft_hysteresis`) and fades each link's potential out at R
    (:func:`.model.faded_potential`); the filters, the controllers (eqs. 10–13), the
    integrator and the random draws are the same. The record's graph statistics and link
    counts are then those of the weights (``last_change_time`` is not meaningful).

    Faults (``Config.faults = "on"``, :mod:`.scenario` "Faults"): a dropped-out or lost node
    measures nothing; a lost link drops the step's KCF exchange on it, not the link of the
    flocking control (eqs. 11–12: sensed, not sent); a lost node leaves the flock at once — no
    link of the graph, frozen where it is, its filter states held, out of every statistic."""
    dtype, p = kit.typed(cfg, params)
    n = cfg.n_agents
    t = state.t.astype(dtype) * p.dt
    h = sensing_mask(cfg, p, dtype)
    target = target_state(cfg, p, t)
    gains = fl.Gains(p.c1, p.c2, p.k, p.R)
    switched_on = jnp.ones(n, bool)
    fault_state, fault = faults.advance(key, state.faults, p, switched_on)
    graph_now = state.adj
    if fault is not None:  # a node lost this step takes its links with it
        a = fault.alive.astype(dtype)
        graph_now = graph_now * a[:, None] * a[None, :]

    # 1. measurements of the type-I nodes; the filters (step 0 updates the prior without predicting)
    noise = p.sigma_meas * jax.random.normal(key, (n, 2), dtype)
    z = faults.measurements(jnp.where(h[:, None] > 0.5, position(target, None)[None, :] + noise, jnp.nan), fault)
    runs_filter = h if cfg.filter_nodes == "sensing" else jnp.ones(n, dtype)
    adj_f = graph_now * runs_filter[:, None] * runs_filter[None, :]
    carried = faults.messages(adj_f, fault)
    R_inv = jnp.broadcast_to(jnp.eye(2, dtype=dtype) / p.sigma_meas**2, (n, 2, 2))
    meas = Measurements(z, state.flock.q, carried, R_inv)
    F, _ = cv_matrices(p.dt, dtype)
    F, Q = first_step_model(state.t == 0, F, cv_process_noise(p.dt, p.sigma_accel, dtype))
    opts = FilterOptions(kcf_gain=cfg.kcf_gain)
    no_angle = jnp.array([False, False])
    nis = None if cfg.consistency != "on" else jnp.stack([  # each node's own measurement against its prediction
        consistency.predicted_nis(f, F, Q, position, state.flock.q, z, R_inv, no_angle) for f in state.filters])
    filters, mailbox = kit.filter_update(cfg.filters, opts, position, no_angle, state.filters, meas,
                                         F, Q, p.kcf_epsilon, fault, state.mailbox)
    errors = jnp.stack([metrics.position_error(f.x, target) * h for f in filters])
    # the bound (bound = "on"; module docstring): the filters' own CV model, the type-I measurements taken
    bound = pcrb.update(state.bound, F, Q, position, target, state.flock.q, z, R_inv)

    # 2. fly: type-I nodes steer to their KCF estimate (the first filter's without a KCF) or the
    #    truth, CV-extrapolated within the step
    if cfg.control_reference == "estimate":
        est = filters[cfg.filters.index("kcf") if "kcf" in cfg.filters else 0].x
        ref_q0, ref_p0 = est[:, jnp.array([0, 2])], est[:, jnp.array([1, 3])]

        def reference(tau):
            return ref_q0 + tau * ref_p0, ref_p0
    else:
        def reference(tau):
            x = target_state(cfg, p, t + tau)
            rq = jnp.broadcast_to(x[jnp.array([0, 2])], (n, 2))
            return rq, jnp.broadcast_to(x[jnp.array([1, 3])], (n, 2))

    moving = None if fault is None else fault.alive
    barrier = None if temperatures is None else jnp.asarray(temperatures.barrier, dtype)
    if cfg.integrator == "dopri5":
        flock, margin, dmin, n_sub, capped = fl.dopri5_adaptive(state.flock, graph_now, h, reference, gains, p.dt,
                                                                cfg.max_substeps, cfg.tolerance, moving, barrier)
    else:
        flock, margin, dmin, n_sub, capped = fl.rk4_adaptive(state.flock, graph_now, h, reference, gains, p.dt,
                                                             cfg.max_substeps, p.substep_safety, moving, barrier)
    if fault is not None:  # a lost node has stopped
        flock = flock._replace(p=jnp.where(moving[:, None], flock.p, 0.0))

    # 3. the hysteresis graph at the step's end (a lost node forms no link)
    if temperatures is None:
        adj = graph.hysteresis_adjacency(graph_now, flock.q, p.R, p.epsilon)
    else:
        adj = soft_hysteresis(graph_now, flock.q, p.R, p.epsilon, jnp.asarray(temperatures.links, dtype))
    if fault is not None:
        adj = adj * a[:, None] * a[None, :]
    if temperatures is None:
        added = jnp.sum((adj > 0.5) & (graph_now < 0.5)) // 2
        removed = jnp.sum((adj < 0.5) & (graph_now > 0.5)) // 2
    else:
        added, removed = soft_link_changes(graph_now, adj)
    target_end = target_state(cfg, p, t + p.dt)
    tq, tp = target_end[jnp.array([0, 2])], target_end[jnp.array([1, 3])]
    mismatch = jnp.sum((flock.p - tp) ** 2)
    record = faults.record(adj_f, carried, fault, runs_filter > 0.5)
    if fault is not None:
        mismatch = jnp.sum(jnp.where(moving[:, None], (flock.p - tp) ** 2, 0.0))
        record = record._replace(dropouts=jnp.sum(fault.alive & (h > 0.5) & ~fault.sensing))  # sensors: type I
    rec = Record(
        error=errors, lambda2=graph.algebraic_connectivity(adj), edges=jnp.sum(adj) / 2, added=added,
        removed=removed, min_distance=dmin, min_link_margin=margin,
        energy=fl.energy(flock, adj, h, tq, tp, gains, p.c2, moving, barrier),
        speed_mismatch=mismatch, substeps=n_sub, capped=capped, target=target,
        start_failed=state.start_failed,
        attempts=state.attempts,
        faults=record,
        bound=pcrb.position_variance(bound),
        nees=None if cfg.consistency != "on" else jnp.stack([metrics.nees(f.x, f.Y, target) for f in filters]),
        nis=nis)
    return (State(state.t + 1, flock, adj, filters, state.start_failed, state.attempts, fault_state, mailbox, bound),
            rec)
