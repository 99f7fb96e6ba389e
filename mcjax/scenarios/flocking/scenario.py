"""A flocking mobile sensor network tracks a target with the Kalman-consensus filter — Lou,
Cui & Li 2013.

``N`` double-integrator nodes (eq. 1) in the plane follow a target moving along ``y = sin x``.
Only the first ``M`` (type I) measure the target's position; they estimate it with the
Kalman-consensus filter of Alg. 1 (``kcf``, the ``μ P`` gain form) and steer by their own
estimate (eq. 10). Type-II nodes run no filter and align their velocities through adaptive
gains (eq. 11). Every node feels the potential of eq. 12 from its neighbours in the
hysteresis graph (links form below ``R − ε`` and break only at ``R``), which should keep
every link and prevent collisions (Theorem 2). Each step of ``dt``:

1. the type-I nodes measure the target and run the filters over the graph of the nodes
   that run one (``Config.filter_nodes``);
2. the flock is integrated over ``dt`` at the current topology by the Dormand–Prince 5(4)
   pair with step-size control, each 0.1 s step's error within ``Config.tolerance`` (m, m/s;
   :func:`.dynamics.dopri5_adaptive`; ``Config.integrator = "rk4"``: the RK4 sub-steps sized
   from the flock's stiffness and closing speeds used before, :func:`.dynamics.rk4_adaptive`),
   at most ``Config.max_substeps`` sub-steps, each type-I node steering to its estimate
   extrapolated at constant velocity within the step;
3. the hysteresis graph is updated; links that broke (never expected) and sub-steps where
   a link reached ``R`` are counted and flag the run.

The initial flock is drawn inside the compiled program: positions U[0, box]², velocities
U[0, v0]² (the paper: box 8, v0 0.1), redrawn up to ``Config.start_attempts`` times until
the initial graph is connected, no pair sits within ``start_margin`` below R (the potential
is stiff there) and no two nodes are closer than ``start_min_distance``. A run whose draws
all fail is flagged (``start_failed``) and runs from its last draw. ``Config.start_layout =
"lattice"`` (ours, for scaling studies; not the paper's) places the nodes instead on a square
lattice of ``lattice_spacing`` jittered by U[−lattice_jitter, lattice_jitter]² per node
(:func:`lattice_sites`); :func:`check_params` rejects a spacing or jitter with which some
draw could break the rule above, and the same test still flags any draw that does.

Filters (``Config.filters``): ``kcf`` and ``local`` (each type-I node's standalone Kalman
filter: the paper's Fig. 2–3 baseline). Errors are the position errors of the type-I
nodes' estimates. Units: the paper's (m, s). Our choices where it is silent are marked in
``configs/lou2013.toml``.

Faults (:mod:`mcjax.scenarios.faults`, ``Config.faults = "on"``; ours, the paper has none).
The graph of the flocking control is the hysteresis graph of radius R, the same as the
filters'; its interactions — the potential of eq. 12 and the velocity alignment of eq. 11 —
are relative positions and velocities a node senses, not messages. So a *lost link* drops only
that step's KCF exchange (the neighbour's prior and measurement information), never a link of
the control; a *sensor dropout* leaves a type-I node without its measurement. A *lost node*
leaves the flock at once: it measures, sends and receives nothing, has no link of the graph
(so no neighbour feels its potential, and none forms with it later — kept, the potential's
barrier at R would tie the flock to a stopped node and break at R, which Theorem 2 excludes),
stops where it is, its filter states hold, and it leaves the error statistics, the energy of
eq. 15, the speed mismatch and the smallest distance. Its links' removal is not a link broken
(``edges_removed``). The fault counts count the links between filter nodes and the type-I
nodes' sensors. With ``Config.message_delay = k > 0`` the KCF's consensus messages arrive k
steps late (:func:`mcjax.filters.consensus.kcf_step`: the disagreement of k steps ago; the
neighbours' old measurement information is not fused); the control, sensed, is not delayed.
"""

from __future__ import annotations

import math
from functools import cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mcjax import graph, metrics
from mcjax.contract import FAST_COMPILE, Output, Param, Scenario, Setting, config_type, declare, params_type
from mcjax.filters.consensus import KCF_GAINS, FilterOptions, Measurements, filter_step
from mcjax.filters.gaussian import Gaussian, first_step_model
from mcjax.models.motion import cv_matrices, cv_process_noise
from mcjax.numerics import spd_inverse, symmetrize
from mcjax.scenarios import faults, kit
from mcjax.scenarios.flocking import dynamics as fl
from mcjax.scenarios.flocking.smoothing import ROUGH, Smoothing, soft_hysteresis, soft_link_changes
from mcjax.smoothing import Smooth

NAME = "flocking"
FILTER_KINDS = ("kcf", "local")
FILTER_NODES = ("sensing", "all")
CONTROL_REFERENCES = ("estimate", "truth")
TARGET_PATHS = ("sine", "line")
START_LAYOUTS = ("uniform", "lattice")
INTEGRATORS = ("dopri5", "rk4")


def _check(cfg) -> None:
    kit.check_common(cfg)
    if cfg.message_delay > 0 and cfg.kcf_gain == "prior_consensus":
        raise ValueError("kcf_gain must be mu_P or gamma_M when message_delay > 0 (prior_consensus averages "
                         "this step's priors); got 'prior_consensus'")


Config = config_type("Config", dict(
    **kit.common_settings(filter_kinds=FILTER_KINDS, n_agents=20, n_steps=300, min_steps=2, warmup_steps=20,
                          divergence_threshold=5.0),
    max_substeps=Setting(200, "most sub-steps per step (dopri5: attempts, rejected ones included; rk4: each "
                         "sized from the flock's stiffness and closing speeds) (ours)", low=1, integer=True),
    integrator=Setting("dopri5", "dopri5 = Dormand-Prince 5(4) pair with step-size control at tolerance; rk4 = "
                       "classical RK4 sub-steps sized for stability at substep_safety (before issue 37) (ours)",
                       choices=INTEGRATORS),
    tolerance=Setting(1e-6, "dopri5: bound on each sub-step's error estimate, absolute, per position (m), "
                      "velocity (m/s) and gain b_ij (1/s) component (ours)", "m, m/s", low=0.0, low_open=True),
    filter_nodes=Setting("sensing", "nodes that run a filter and join its consensus: sensing = type I only "
                         "(paper), all = type II too (with no measurement)", choices=FILTER_NODES),
    control_reference=Setting("estimate", "what type-I nodes steer to: their KCF estimate (paper) or the true "
                              "target (the ideal case of Theorem 2)", choices=CONTROL_REFERENCES),
    target_path=Setting("sine", "sine = along y = sin x (paper); line = straight along x at constant speed",
                        choices=TARGET_PATHS),
    kcf_gain=Setting("mu_P", "KCF consensus gain: mu_P = Lou et al. 2013 Alg. 1; gamma_M = Olfati-Saber 2009",
                     choices=KCF_GAINS),
    start_attempts=Setting(64, "initial draws tried per run before the run is flagged", low=1, integer=True),
    start_layout=Setting("uniform", "initial positions: uniform = U[0, box]^2 (paper); lattice = a square lattice "
                         "of lattice_spacing jittered by lattice_jitter (ours: a valid start for any n_agents)",
                         choices=START_LAYOUTS),
    **faults.SETTINGS,
    **faults.DELAY_SETTINGS,
), __name__, _check)


def _default_m(cfg):
    return float(max(1, cfg.n_agents // 2))


_POS = dict(low=0.0, low_open=True)
Params = params_type("Params", dict(
    dt=Param(0.1, "s", "sampling step of the filters and the controllers (ours)", **_POS),
    R=Param(8.4, "m", "communication radius (paper)", **_POS),
    epsilon=Param(0.4, "m", "hysteresis: a new link forms below R - epsilon (ours)", **_POS),
    n_sensing=Param(_default_m, "", "M, the number of type-I (sensing) nodes (paper: 10 of 20)", low=1.0,
                    integer=True),
    c1=Param(1.0, "1/s^2", "position gain of eq. 10 (ours)", **_POS),
    c2=Param(2.0, "1/s", "velocity gain of eq. 10; also l of eqs. 15-16 (ours)", **_POS),
    k=Param(0.1, "", "adaptation rate k_ij of eq. 11 (ours, every pair; see configs/lou2013.toml)", **_POS),
    target_speed=Param(1.0, "m/s", "the target's speed along x (ours)", **_POS),
    sigma_meas=Param(0.1, "m", "position measurement noise std per axis (ours)", **_POS),
    sigma_accel=Param(1.0, "m/s^2", "the filters' CV process noise std (ours)", **_POS),
    kcf_epsilon=Param(0.1, "", "KCF consensus step epsilon of Alg. 1 (ours)", **_POS),
    p0_diag=Param(np.array([0.1, 0.1, 0.1, 0.1]), "m^2, (m/s)^2", "prior variances; the filters start at the "
                  "true state (paper: x(0))", **_POS, shape=(4,)),
    box=Param(8.0, "m", "initial positions U[0, box]^2 (paper: 8)", **_POS),
    v0=Param(0.1, "m/s", "initial velocities U[0, v0]^2 (paper: 0.1)", low=0.0),
    start_margin=Param(0.2, "m", "no pair may start in [R - start_margin, R) (ours)", low=0.0),
    substep_safety=Param(1.0, "", "sub-step h = safety x min(1/sqrt(stiffness), 1/damping, half a gap / "
                         "closing speed) (ours)", **_POS),
    start_min_distance=Param(0.3, "m", "no two nodes may start closer than this (ours; the paper's Fig. 6 "
                             "starts near 0.3)",
                             low=0.0),
    lattice_spacing=Param(1.75, "m", "start_layout = lattice: the lattice's spacing (ours: about the paper's "
                          "density; with R = 8.4 no lattice distance falls near R)", **_POS),
    lattice_jitter=Param(0.1, "m", "start_layout = lattice: each node moves by U[-jitter, jitter]^2 from its "
                         "site (ours)", low=0.0),
    **faults.PARAMS,
), __name__)


def check_params(cfg, values: dict) -> list[tuple[str, str]]:
    def get(name):
        return kit.param_value(Params, cfg, values, name)

    bad = []
    if np.any(get("n_sensing") > cfg.n_agents):
        bad.append(("n_sensing", f"an integer in [1, n_agents = {cfg.n_agents}]"))
    if np.any(get("epsilon") >= get("R")):
        bad.append(("epsilon", "in (0, R): new links form below R - epsilon"))
    if np.any(get("start_margin") >= get("R")):
        bad.append(("start_margin", "in [0, R)"))
    if cfg.start_layout == "lattice":
        args = (get("R"), get("start_margin"), get("start_min_distance"))
        if not np.all(_lattice_valid(cfg.n_agents, get("lattice_spacing"), 0.0, *args)):
            bad.append(("lattice_spacing", "such that every pair of lattice sites is either below R - start_margin "
                        "or at R or beyond, neighbours below R - start_margin and at least start_min_distance apart "
                        "(start_layout = lattice)"))
        elif not np.all(_lattice_valid(cfg.n_agents, get("lattice_spacing"), get("lattice_jitter"), *args)):
            bad.append(("lattice_jitter", "small enough that no jittered lattice pair can start in [R - start_margin, "
                        "R), neighbours stay below R - start_margin and at least start_min_distance apart "
                        "(start_layout = lattice)"))
    return bad + faults.check(cfg, values, Params)


def lattice_sites(n: int) -> np.ndarray:
    """The sites of ``start_layout = "lattice"`` in units of the spacing, (n, 2): row by row
    on a grid of ``ceil(sqrt(n))`` columns, cell centres from (0.5, 0.5). Filled row by row,
    every site but the first has a neighbour one unit away to its left or below it, so the
    sites' unit links form a connected graph."""
    cols = math.isqrt(max(n - 1, 0)) + 1
    i = np.arange(n)
    return np.stack([i % cols + 0.5, i // cols + 0.5], axis=1)


def _lattice_valid(n, spacing, jitter, R, margin, min_distance):
    """Whether every draw of the jittered lattice meets the start rule (module docstring), by
    bounds: each node moves at most ``sqrt(2)·jitter`` from its site, so a pair's distance
    lies within ``2·sqrt(2)·jitter`` of ``spacing`` times its sites' distance. Sufficient:
    the unit links stay below ``R - margin`` (the graph is connected, :func:`lattice_sites`),
    no pair's range meets ``[R - margin, R)``, and the shortest is ≥ ``min_distance``.
    Array arguments broadcast (sweep points); returns a boolean array."""
    if n < 2:
        return np.ones(np.broadcast(spacing, jitter, R, margin, min_distance).shape, bool)
    sites = lattice_sites(n)
    d0 = np.unique(np.round(np.sqrt(np.sum((sites[:, None] - sites[None]) ** 2, -1)), 12))
    d0 = d0[d0 > 0]
    s, spread, R, margin, dmin = (np.asarray(a, np.float64)[..., None] for a in
                                  (spacing, 2.0 * math.sqrt(2.0) * np.asarray(jitter), R, margin, min_distance))
    lo, hi = s * d0 - spread, s * d0 + spread
    outside = np.all((hi < R - margin) | (lo >= R), axis=-1)
    return outside & (s[..., 0] + spread[..., 0] < R[..., 0] - margin[..., 0]) & (lo[..., 0] >= dmin[..., 0])


class State(NamedTuple):
    t: jax.Array
    flock: fl.FlockState
    adj: jax.Array          # (N, N) hysteresis graph
    filters: tuple          # one Gaussian per filter, node axis first
    start_failed: jax.Array
    attempts: jax.Array
    faults: faults.State | None  # lost links and nodes (mcjax.scenarios.faults; None: off)
    mailbox: faults.Mailbox | None  # the KCF's consensus messages in flight (None: message_delay = 0)


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
    """One draw of the initial flock (module docstring) and whether it meets the start rule."""
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
    """The first valid draw of the initial flock (module docstring), every filter at the true
    target state with covariance ``diag(p0_diag)``, the adaptive gains at 0; no fault yet."""
    dtype = jnp.dtype(cfg.dtype)
    p = kit.cast(params, dtype)
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
    box = faults.mailbox(cfg, x0) if "kcf" in cfg.filters else None
    box = None if box is None else faults.Mailbox(*kit.per_run(p.dt, *box))
    return State(jnp.asarray(0, jnp.int32), flock, adj[pick], filters, ~found, pick + 1,
                 faults.init(cfg, key, p), box)


def _position(x, sensor):
    del sensor
    return jnp.stack([x[0], x[2]])


def step(cfg, params, state: State, key, smoothing: Smoothing | None = None) -> tuple[State, Record]:
    """One sampling step (module docstring): measure, filter (Lou et al. 2013 Alg. 1), fly
    (eqs. 1, 10–13), update the hysteresis graph (Section 1.1, rules 2–3).

    ``smoothing`` (the smoothing switch, :class:`~.smoothing.Smoothing`; None: the exact
    simulation) makes the graph's links weights in [0, 1] with a soft hysteresis
    (:func:`~.smoothing.soft_hysteresis`) and fades each link's potential out at R
    (:func:`.dynamics.faded_potential`); the filters, the controllers (eqs. 10–13), the
    integrator and the random draws are the same. The record's graph statistics and link
    counts are then those of the weights (``last_change_time`` is not meaningful).

    Faults (``Config.faults = "on"``, module docstring "Faults"): a dropped-out or lost node
    measures nothing; a lost link drops the step's KCF exchange on it, not the link of the
    flocking control (eqs. 11–12: sensed, not sent); a lost node leaves the flock at once — no
    link of the graph, frozen where it is, its filter states held, out of every statistic."""
    dtype = jnp.dtype(cfg.dtype)
    p = kit.cast(params, dtype)
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
    z = faults.measurements(jnp.where(h[:, None] > 0.5, _position(target, None)[None, :] + noise, jnp.nan), fault)
    runs_filter = h if cfg.filter_nodes == "sensing" else jnp.ones(n, dtype)
    adj_f = graph_now * runs_filter[:, None] * runs_filter[None, :]
    carried = faults.messages(adj_f, fault)
    R_inv = jnp.broadcast_to(jnp.eye(2, dtype=dtype) / p.sigma_meas**2, (n, 2, 2))
    meas = Measurements(z, state.flock.q, carried, R_inv)
    F, _ = cv_matrices(p.dt, dtype)
    F, Q = first_step_model(state.t == 0, F, cv_process_noise(p.dt, p.sigma_accel, dtype))
    opts = FilterOptions(kcf_gain=cfg.kcf_gain)
    shielded, no_angle, mailbox = faults.shield(fault, state.filters), jnp.array([False, False]), state.mailbox
    if mailbox is None:
        filters = filter_step(cfg.filters, opts, _position, no_angle, shielded, meas, F, Q, p.kcf_epsilon)
    else:  # the KCF's consensus messages arrive message_delay steps late
        late = meas._replace(late=faults.late(mailbox, F))
        filters = tuple(filter_step((k,), opts, _position, no_angle, (f,), late if k == "kcf" else meas, F, Q,
                                    p.kcf_epsilon)[0] for k, f in zip(cfg.filters, shielded))
        mailbox = faults.post(mailbox, shielded[cfg.filters.index("kcf")].x, carried)
    filters = faults.hold(fault, filters, state.filters)
    errors = jnp.stack([metrics.position_error(f.x, target) * h for f in filters])

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
    barrier = None if smoothing is None else jnp.asarray(smoothing.barrier, dtype)
    if cfg.integrator == "dopri5":
        flock, margin, dmin, n_sub, capped = fl.dopri5_adaptive(state.flock, graph_now, h, reference, gains, p.dt,
                                                                cfg.max_substeps, cfg.tolerance, moving, barrier)
    else:
        flock, margin, dmin, n_sub, capped = fl.rk4_adaptive(state.flock, graph_now, h, reference, gains, p.dt,
                                                             cfg.max_substeps, p.substep_safety, moving, barrier)
    if fault is not None:  # a lost node has stopped
        flock = flock._replace(p=jnp.where(moving[:, None], flock.p, 0.0))

    # 3. the hysteresis graph at the step's end (a lost node forms no link)
    if smoothing is None:
        adj = graph.hysteresis_adjacency(graph_now, flock.q, p.R, p.epsilon)
    else:
        adj = soft_hysteresis(graph_now, flock.q, p.R, p.epsilon, jnp.asarray(smoothing.links, dtype))
    if fault is not None:
        adj = adj * a[:, None] * a[None, :]
    if smoothing is None:
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
        faults=record)
    return State(state.t + 1, flock, adj, filters, state.start_failed, state.attempts, fault_state, mailbox), rec


def training_errors(cfg, params, record: Record):
    """What the training loss of ``mcjax tune`` reads from a step's record: the position errors
    (F, N) of every filter's estimate at every node (the error output ``rmse``'s)."""
    return record.error


def training_weights(cfg, params):
    """Each node's weight (N,) in the training loss: 1 for the type-I nodes (those that sense
    and whose errors the ``rmse`` output averages), 0 for the others."""
    dtype = jnp.dtype(cfg.dtype)
    return sensing_mask(cfg, kit.cast(params, dtype), dtype)


def summary(cfg, records: Record | None, params) -> dict:
    """One run's records (stacked over time) reduced to its outputs, each declared next to its
    value (:func:`mcjax.contract.declare`; ``records`` None: the declarations alone)."""
    r = records
    dtype = cache(lambda: r.error.dtype)
    h = cache(lambda: sensing_mask(cfg, kit.cast(params, dtype()), dtype()))
    alive = cache(lambda: faults.weights(h(), r.faults))
    e = cache(lambda: r.energy)
    return declare(
        **kit.error_items(lambda: r.error, alive, cfg, "m", "position error of the type-I nodes' estimates"),
        **kit.graph_items(lambda: r.lambda2),
        edges_added=(Output("", "links formed over the run", False), lambda: jnp.sum(r.added)),
        edges_removed=(Output("", "links broken over the run (Theorem 2: none)", False), lambda: jnp.sum(r.removed)),
        last_change_time=(Output("s", "time of the last topology change (0 if none)", False),
                          lambda: jnp.max(jnp.where((r.added + r.removed) > 0,
                                                    (jnp.arange(r.edges.shape[0]) + 1).astype(dtype())
                                                    * jnp.asarray(params.dt, dtype()), 0.0))),
        final_edges=(Output("", "links at the end", False), lambda: r.edges[-1]),
        min_distance=(Output("m", "smallest distance between two nodes over the run (sub-steps included)", False),
                      lambda: metrics.nan_min(r.min_distance)),
        final_min_distance=(Output("m", "smallest distance between two nodes at the end", False),
                            lambda: r.min_distance[-1]),
        min_link_margin=(Output("m", "smallest R - r over links over the run (sub-steps included)", False),
                         lambda: metrics.nan_min(r.min_link_margin)),
        link_reached_R=(Output("", "some link reached the radius R inside a step, or the flock went non-finite "
                               "(a broken run)", False), lambda: jnp.any(~(r.min_link_margin > 0))),
        energy_start=(Output("", "flocking energy (eq. 15) after the first step", False), lambda: e()[0]),
        energy_end=(Output("", "flocking energy at the end", False), lambda: e()[-1]),
        energy_max_rise=(Output("", "largest rise of the energy between two steps (0 if monotone)", False),
                         lambda: jnp.maximum(metrics.nan_max(e()[1:] - e()[:-1]), 0.0)),
        final_speed_mismatch=(Output("m^2/s^2", "sum over nodes of |p_i - p_target|^2 at the end", False),
                              lambda: r.speed_mismatch[-1]),
        substeps_mean=(Output("", "mean sub-steps per step (dopri5: attempts, rejected ones included)", False),
                       lambda: jnp.mean(r.substeps.astype(dtype()))),
        substeps_capped=(Output("steps", "steps that needed more than max_substeps sub-steps", False),
                         lambda: jnp.sum(r.capped)),
        start_failed=(Output("", "no valid initial draw within start_attempts", False), lambda: r.start_failed[0]),
        start_attempts_used=(Output("", "initial draws until a valid one", False), lambda: r.attempts[0]),
        **faults.summary_items(cfg, r and r.faults, lambda: jnp.ones(cfg.n_agents, dtype())),
    )


def series(cfg, records: Record | None, params) -> dict:
    """Per-step series of one run, each declared next to its value."""
    r = records
    h = cache(lambda: sensing_mask(cfg, kit.cast(params, r.error.dtype), r.error.dtype))
    alive = cache(lambda: faults.weights(h(), r.faults))
    return declare(
        **kit.error_series_items(lambda: r.error, alive, "m", "position error of the type-I nodes' estimates"),
        energy=(Output("", "flocking energy (eq. 15)", False), lambda: r.energy),
        lambda2=(Output("", "algebraic connectivity of the graph", False), lambda: r.lambda2),
        min_distance=(Output("m", "smallest distance between two nodes", False), lambda: r.min_distance),
        edges=(Output("", "links", False), lambda: r.edges),
        **faults.series_items(cfg, r and r.faults, lambda: jnp.ones(cfg.n_agents, r.error.dtype)),
    )


SCENARIO = Scenario(
    name=NAME, title="Lou, Cui & Li 2013: a flocking sensor network tracks a target with the Kalman-consensus "
    "filter", Config=Config, Params=Params, init=init, step=step, summary=summary, series=series,
    check_params=check_params, smooth=Smooth(Smoothing, training_errors, training_weights, ROUGH),
    compiler_options=FAST_COMPILE,
    # two of its programs running at once on two CPU devices wait for each other for good (XLA's CPU
    # runtime, its sub-steps in a data-dependent while loop): a sweep of four 100-run batches hung
    one_device=True,
    filter_words={
        "kcf": "Kalman-consensus filter of Lou, Cui & Li 2013 (Alg. 1): a local update with the neighbours' "
               "measurements plus a step towards their estimates",
        "local": "each node's own Kalman filter on its own measurements, nothing shared"})
default_params = SCENARIO.default_params
#: The record's derived functions (from :func:`summary` and :func:`series`), by their usual names.
reduce, outputs = SCENARIO.reduce, SCENARIO.outputs
timeseries, timeseries_outputs = SCENARIO.timeseries, SCENARIO.timeseries_outputs
