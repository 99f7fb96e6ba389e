"""Sun et al. 2011's leader–follower scenario, one step: the target and the UAVs move, the UAVs
measure and link, every filter runs, the leader re-plans when due; the state, the record and the
relaxation switch."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcjax.scenarios import kit
from mcjax.scenarios.kit import bound as pcrb
from mcjax.scenarios.kit import consistency
from mcjax.scenarios.kit import faults
from mcjax.scenarios.sun2011.objectives import resolve_paths
from mcjax.scenarios.sun2011.params import filter_options
from mcjax.scenarios.sun2011.planner import plan_if_due
from mcjax.tracking import connectivity, graph, metrics
from mcjax.tracking.filters.consensus import Measurements
from mcjax.tracking.filters.gaussian import first_step_model
from mcjax.tracking.filters.steps import init_states, per_agent
from mcjax.tracking.models.motion import cv_matrices, cv_process_noise, cv_step
from mcjax.tracking.models.platforms import UnicycleLimits, unicycle_step
from mcjax.tracking.models.sensors import range_bearing


class State(NamedTuple):
    t: jax.Array
    target: jax.Array          # (4,)
    uavs: jax.Array            # (n, 4) [x, y, v, φ]
    filters: tuple             # one Gaussian per filter in cfg.filters
    plan_u: jax.Array          # (H, n) the plan in force, u in [−1, 1] (closed loop)
    plan_cmd: jax.Array        # (H, n) its heading commands, rad
    plan_age: jax.Array        # commands of the plan applied so far
    plan_cost: jax.Array       # exact eq. 16 cost of the plan in force
    faults: faults.State | None  # lost links and agents (mcjax.scenarios.kit.faults; None: off)
    mailbox: faults.Mailbox | None  # the kcf's consensus messages in flight (None: message_delay = 0)
    bound: pcrb.Bound | None = None  # the PCRB's covariance of the target, team and per agent (None: off)


class Record(NamedTuple):
    error: jax.Array           # (F, n) position error per filter and agent, m
    nees: jax.Array            # (F, n) full-state NEES
    lambda2: jax.Array         # ()
    degrees: jax.Array         # (n,)
    robustness: jax.Array      # (n,) R_I, m
    n_seeing: jax.Array        # () kit.agents with a measurement
    positions: jax.Array       # (n, 2)
    target: jax.Array          # (4,)
    measurements: jax.Array    # (n, 2) range–bearing, NaN where none
    adjacency: jax.Array       # (n, n) comm graph
    plan_cost: jax.Array       # () exact eq. 16 cost of the plan in force (0 in open loop)
    faults: faults.Record | None  # the step's faults (None: off)
    bound: pcrb.Bound | None = None  # the PCRB's position variances, team () and per agent (n,), m² (None: off)
    nis: jax.Array | None = None  # (F, n) each agent's NIS, NaN without a measurement (None: consistency off)


def init(cfg, params, key) -> State:
    """State before step 0: true target, UAVs at their initial poses, filters at the prior
    (the true initial state with covariance ``diag(p0_diag)``, Sun et al. 2011 §5); no fault yet."""
    n, dtype = cfg.n_agents, jnp.dtype(cfg.dtype)
    params = kit.cast(params, dtype)
    uavs = jnp.concatenate([
        jnp.asarray(params.initial_positions, dtype),
        kit.agents(params.uav_speed, n, dtype)[:, None],
        kit.agents(params.initial_headings, n, dtype)[:, None],
    ], axis=-1)
    x0 = jnp.asarray(params.target_x0, dtype)
    P0 = jnp.diag(jnp.asarray(params.p0_diag, dtype))
    # the plan entries become per-run at the first re-plan: per-run from the start (kit.per_run)
    plan, cost = kit.per_run(params.dt, jnp.zeros((cfg.max_horizon, n), dtype), jnp.zeros((), dtype))
    return State(jnp.asarray(0, jnp.int32), x0, uavs, init_states(cfg.filters, x0, P0, n),
                 plan, plan, jnp.asarray(0, jnp.int32), cost, faults.init(cfg, key, params),
                 kit.kcf_mailbox(cfg, params, x0), pcrb.initial(cfg, jnp.zeros_like(P0)))  # the filters start at the true state


class Temperatures(NamedTuple):
    """Temperatures (m) of the relaxation switch (:func:`step` with ``temperatures``): the sensing
    gate ``sigmoid((R_s − r)/T)`` and the comm links ``sigmoid((min(R_i, R_j) − l_ij)/T)``
    (:func:`mcjax.scenarios.kit.soft_team_measurements`, :func:`mcjax.tracking.graph.soft_adjacency`,
    :func:`mcjax.tracking.connectivity.soft_component_sizes`); ours."""

    sensing: float = 1e3
    comm: float = 1e3


#: Params with no smooth path (:class:`mcjax.contract.relaxation.Relaxation`): the fault rates (the horizon and
#: the re-plan interval are integers, refused as such).
ROUGH = faults.ROUGH


class _Step(NamedTuple):
    """What one step computed, for :func:`step`'s record."""

    target: jax.Array
    sensors: jax.Array
    z: jax.Array
    comm_graph: jax.Array      # (n, n) links in range between the agents switched on
    carried: jax.Array         # (n, n) the links that carried a message (faults removed)
    faults: faults.Step | None
    filters: tuple
    bound: jax.Array | None
    nis: jax.Array | None


def _advance(cfg, params, state: State, key, temperatures):
    """The physics and filters of one step (:func:`step`): ``(new State, _Step)``. ``temperatures``
    None is the exact simulation; a :class:`Temperatures` swaps the sensing gate and the comm graph
    for their smooth versions.

    Faults (:mod:`mcjax.scenarios.kit.faults`): a lost UAV stops where it is, senses and sends
    nothing, and its filter states stay as they were; if the leader is lost, the
    lowest-numbered UAV not lost takes over the planning (from its own modified-ICF estimate,
    at the next re-plan); a lost link drops the step's consensus message, not the link in R_I."""
    n, dtype = cfg.n_agents, jnp.dtype(cfg.dtype)
    first = state.t == 0
    k_target, k_meas = jax.random.split(key)
    dt = jnp.asarray(params.dt, dtype)
    dt_move = jnp.where(first, 0.0, dt)
    switched_on = kit.agents(params.alive, n, dtype) > 0.5
    fault_state, fault = faults.advance(key, state.faults, params, switched_on)

    target = jnp.where(first, state.target, cv_step(state.target, k_target, dt, params.target_sigma_accel))
    speed = kit.agents(params.uav_speed, n, dtype)
    limits = UnicycleLimits(speed, speed, jnp.zeros((), dtype), jnp.zeros((), dtype),
                            jnp.asarray(params.turn_rate_max, dtype))
    if cfg.planner == "none":
        command, age = kit.agents(params.heading_cmd, n, dtype), state.plan_age
    else:  # the next command of the plan in force (step 0 does not move)
        command = state.plan_cmd[jnp.minimum(state.plan_age, cfg.max_horizon - 1)]
        age = jnp.where(first, state.plan_age, state.plan_age + 1)
    uavs = unicycle_step(state.uavs, command, 0.0, params.alpha_phi, limits, dt_move)
    if fault is not None:
        uavs = jnp.where(fault.alive[:, None], uavs, state.uavs)
    sensors = uavs[:, :2]
    # R = diag(σ_r², σ_θ²) is diagonal: its inverse needs no LAPACK call on the hot path
    R_inv = jnp.diag(jnp.stack([1.0 / params.sigma_range**2, 1.0 / params.sigma_bearing**2]))
    R_inv = jnp.broadcast_to(R_inv, (n, 2, 2))
    comm = kit.agents(params.comm_radius, n, dtype)
    sensing = kit.agents(params.sensing_radius, n, dtype)
    s = kit.sense_and_link(k_meas, target, sensors, params, sensing, comm, switched_on, fault, temperatures)
    z, adj, carried = s.z, s.comm_graph, s.carried
    meas = (Measurements(z, sensors, carried, R_inv) if temperatures is None else
            Measurements(z, sensors, carried, R_inv * s.gates[:, None, None], s.sizes))

    F, Q = first_step_model(first, cv_matrices(dt, dtype)[0], cv_process_noise(dt, params.sigma_accel, dtype))
    angle_mask = jnp.array([False, True])
    nis = None if cfg.consistency != "on" else jnp.stack([  # each agent's own measurement against its prediction
        consistency.predicted_nis(per_agent(k, f, n), F, Q, range_bearing, sensors, z, R_inv, angle_mask)
        for k, f in zip(cfg.filters, state.filters)])
    filters, mailbox = kit.filter_update(cfg.filters, filter_options(cfg, temperatures is not None), range_bearing,
                                         angle_mask, state.filters, meas, F, Q, jnp.asarray(params.kcf_epsilon, dtype),
                                         fault, state.mailbox)

    # the bound (bound = "on"): the truth's motion model (target_sigma_accel, not the filters' sigma_accel)
    bound = pcrb.update(state.bound, *first_step_model(first, cv_matrices(dt, dtype)[0],
                                                        cv_process_noise(dt, params.target_sigma_accel, dtype)),
                        range_bearing, target, sensors, z, R_inv)
    plan = (state.plan_u, state.plan_cmd, age, state.plan_cost)
    if cfg.planner != "none":
        team, leader = kit.agents(params.alive, n, dtype), 0
        if fault is not None:
            team, leader = team * fault.alive.astype(dtype), jnp.argmax(fault.alive)
        plan = plan_if_due(cfg, params, state, uavs, filters, age, jax.random.fold_in(key, 0x9A11),
                           team, leader)
    return (State(state.t + 1, target, uavs, filters, *plan, fault_state, mailbox, bound),
            _Step(target, sensors, z, adj, carried, fault, filters, bound, nis))


def step(cfg, params, state: State, key, temperatures: Temperatures | None = None) -> tuple[State, Record]:
    """One 1-s step: move target (eq. 1) and UAVs (eqs. 3–4, exact heading), measure (range-gated),
    build the comm graph (eq. 13), run every filter, record errors and graph metrics.

    Step 0 is the first measurement time: nothing moves and the filters update their prior
    without predicting (docs/equations.md). The graph statistics are those of the links
    that carried a message (the comm graph less the links lost to faults).

    ``temperatures`` (the relaxation switch, :class:`Temperatures`; None: the exact simulation) swaps
    the sensing gate and the comm graph for their smooth versions (:func:`kit.soft_team_measurements`,
    :func:`graph.soft_adjacency`, :func:`connectivity.soft_component_sizes`) for training by gradient and for
    sensitivities; dynamics (eqs. 1, 3–4), filters (eqs. 8–12) and the planner (eq. 16, whose
    gradient planner descends its own smooth cost) are the same, with the same random draws.
    The graph statistics are then those of the soft links' weights.
    """
    n, dtype = cfg.n_agents, jnp.dtype(cfg.dtype)
    params = kit.cast(params, dtype)
    new, s = _advance(cfg, params, state, key, temperatures)
    comm = kit.agents(params.comm_radius, n, dtype)
    post = [per_agent(k, f, n) for k, f in zip(cfg.filters, s.filters)]
    err = jnp.stack([metrics.position_error(g.x, s.target) for g in post])
    ne = jnp.stack([metrics.nees(g.x, g.Y, s.target) for g in post])
    rec = Record(
        error=err,
        nees=ne,
        lambda2=graph.algebraic_connectivity(s.carried),
        degrees=graph.degree(s.carried),
        robustness=(connectivity.tree_connectivity_robustness(s.sensors, comm)  # the same numbers in O(n^2)
                    if resolve_paths(cfg.robustness_paths, n) == "spanning_tree"
                    else connectivity.connectivity_robustness(s.sensors, comm)),
        n_seeing=jnp.sum(jnp.all(jnp.isfinite(s.z), axis=-1)),
        positions=s.sensors,
        target=s.target,
        measurements=s.z,
        adjacency=s.carried,
        plan_cost=new.plan_cost,
        faults=faults.record(s.comm_graph, s.carried, s.faults, kit.agents(params.alive, n, dtype) > 0.5),
        bound=pcrb.position_variance(s.bound),
        nis=s.nis,
    )
    return new, rec

