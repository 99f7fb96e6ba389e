"""Leader–follower UAV team tracking a CV target — Sun et al. 2011.

One leader (agent 0) and four followers with range–bearing radars (sensing radius 120 km)
and a 100 km comm range track a constant-velocity target. Each step records, for every
filter, each agent's position error and NEES, plus λ2, degrees, connectivity robustness R_I
and how many agents see the target.

``Config.planner = "none"`` is the open loop: every UAV holds ``Params.heading_cmd``.
Otherwise the loop is closed as in Sun et al. 2011 §4: every τ_r steps (``Params.replan_every``)
the leader plans the headings of all UAVs over the horizon t_r (``Params.horizon``) from
its own modified-ICF estimate and the UAV states it knows, minimising eq. 16 with eqs.
18–19 as penalties (:mod:`.planner`, :mod:`.horizon`, :mod:`.objectives`), and the UAVs fly
the first τ_r commands.

Units are SI (m, s, rad). Defaults are the paper's numbers; the values the paper leaves
open are our choices, marked in ``configs/sun2011.toml``.
"""

from __future__ import annotations

from functools import cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mcjax import graph, metrics
from mcjax.contract import (
    FAST_COMPILE, Output, Param, Scenario, Setting, config_type, declare, params_type,
)
from mcjax.filters.consensus import (
    CONTRIBUTION_KINDS,
    FILTER_KINDS,
    ICF_VARIANTS,
    KCF_GAINS,
    LATE_KINDS,
    WEIGHT_KINDS,
    FilterOptions,
    Measurements,
    filter_step,
    init_states,
    per_agent,
)
from mcjax.filters.gaussian import first_step_model
from mcjax.models.motion import cv_matrices, cv_process_noise, cv_step
from mcjax.models.platforms import UnicycleLimits, unicycle_step
from mcjax.models.sensors import range_bearing
from mcjax.scenarios import faults, kit
from mcjax.scenarios.leader_follower.objectives import ROBUSTNESS_PATHS, ROBUSTNESS_PENALTIES, resolve_paths
from mcjax.scenarios.leader_follower.planner import plan_if_due, planner_options
from mcjax.smoothing import Smooth

NAME = "leader_follower"

PLANNERS = ("none", "gradient", "random", "cem")


def _check(cfg) -> None:
    kit.check_common(cfg)
    if cfg.planner != "none":
        if "modified_icf" not in cfg.filters:
            raise ValueError("filters must include 'modified_icf' when a planner is on: "
                             "the leader plans from its modified-ICF estimate (Sun et al. 2011, sec. 4)")
        planner_options(cfg)  # validates the planner budget
    if cfg.message_delay > 0:
        other = [f for f in cfg.filters if f not in LATE_KINDS]
        if other:
            raise ValueError(f"filters must be among {', '.join(LATE_KINDS)} when message_delay > 0 (the ICF and "
                             f"modified ICF average this step's information, which a late message cannot join; "
                             f"so the planner, which needs modified_icf, must be 'none'); got {', '.join(other)}")
        if cfg.kcf_gain == "prior_consensus":
            raise ValueError("kcf_gain must be gamma_M or mu_P when message_delay > 0 (prior_consensus averages "
                             "this step's priors); got 'prior_consensus'")


#: Config: everything that fixes shapes or the compiled program (changing it recompiles).
Config = config_type("Config", dict(
    **kit.common_settings(filter_kinds=FILTER_KINDS, n_agents=5, n_steps=200, warmup_steps=10,
                      divergence_threshold=1000.0),
    consensus_steps=Setting(1, "consensus iterations L per step (paper: one message per comm interval)",
                            low=0, integer=True),
    consensus_weights=Setting("eq11", "consensus weights (eq11 = Sun et al. 2011 eq. 11)", choices=WEIGHT_KINDS),
    contribution=Setting("component", "weight of an agent's own measurement information (component = "
                         "by its component's size, ours; one = eq. 9 as printed)", choices=CONTRIBUTION_KINDS),
    icf_variant=Setting("contributions", "reading of the ICF (docs/equations.md)", choices=ICF_VARIANTS),
    kcf_gain=Setting("gamma_M", "KCF consensus gain form", choices=KCF_GAINS),
    planner=Setting("none", "receding-horizon planner; none = open loop (every UAV holds heading_cmd)",
                    choices=PLANNERS),
    max_horizon=Setting(8, "steps the planning rollout runs; the horizon t_r (param horizon) <= this", "steps",
                        low=1, integer=True),
    plan_period=Setting(0, "tau_r fixed in the compiled program: the planner runs only on the steps it "
                        "re-plans (param replan_every must equal it); 0 = tau_r from the Params, free to vary "
                        "in a batch, at the cost of planning every step and keeping the due plans",
                        "steps", low=0, integer=True),
    plan_iterations=Setting(10, "gradient: Adam steps; cem: rounds", low=1, integer=True),
    plan_samples=Setting(256, "random / cem: plans scored per re-plan (cem: >= 2 per round)", low=2,
                         integer=True),
    plan_learning_rate=Setting(0.3, "Adam step on theta, u = tanh(theta)", low=0, low_open=True),
    plan_elite_fraction=Setting(0.1, "cem: fraction of each round refitted", low=0, high=1, low_open=True),
    plan_dtype=Setting("float64", "float type of the planner's problem (float32: solved in coordinates relative "
                       "to the leader's target estimate: the closed loop ran 1.2-1.7x faster; the filters, the "
                       "executed commands and the simulation stay in dtype)", choices=kit.DTYPES),
    robustness_penalty=Setting("barrier", "penalty of the connectivity robustness R_I (barrier = "
                               "softplus(-R_I/s), ours; inverse = the paper's 1/|R_I|)",
                               choices=ROBUSTNESS_PENALTIES),
    robustness_paths=Setting("auto", "how R_I is computed: all_pairs = widest path of every pair, O(n^3), smooth "
                             "by soft Floyd-Warshall; spanning_tree = the same exact R_I in O(n^2), smooth by a "
                             "softmin over a maximum spanning tree's links (a different surrogate, ours); auto = "
                             "all pairs up to 10 UAVs, the tree above", choices=ROBUSTNESS_PATHS),
    **faults.SETTINGS,
    **faults.DELAY_SETTINGS,
), __name__, _check)


def filter_options(cfg) -> FilterOptions:
    return FilterOptions(cfg.consensus_steps, cfg.consensus_weights, cfg.contribution, cfg.icf_variant,
                         cfg.kcf_gain)


def _paper_positions(cfg) -> np.ndarray:
    """The paper's five UAVs (sec. 5); extra followers spread behind the leader on a line (ours)."""
    n = cfg.n_agents
    paper = np.array([[20e3, 150e3], [80e3, 150e3], [130e3, 200e3], [130e3, 100e3], [180e3, 150e3]])
    if n <= 5:
        return paper[:n]
    extra = np.stack([np.full(n - 5, 20e3), 150e3 + 20e3 * np.arange(1, n - 4)], -1)
    return np.concatenate([paper, extra])


_POS = dict(low=0.0, low_open=True)
_NONNEG = dict(low=0.0)
_ANGLE = dict(low=-10.0, high=10.0)
#: Params: per-run values a sweep may vary without recompiling. Defaults are the paper's
#: (sec. 5) where it gives one; the others are ours (configs/sun2011.toml says why).
Params = params_type("Params", dict(
    dt=Param(1.0, "s", "radar sampling interval = comm interval (paper: 1 s)", **_POS),
    comm_radius=Param(100e3, "m", "communication radius (paper: 100 km)", **_NONNEG, per_agent=True, display="km"),
    sensing_radius=Param(120e3, "m", "radar range (paper: 120 km)", **_NONNEG, per_agent=True, display="km"),
    sigma_range=Param(10.0, "m", "range noise std (paper: 10 m)", **_POS),
    sigma_bearing=Param(0.017, "rad", "bearing noise std (paper: 0.017 rad)", **_POS,
                        high=float(np.pi)),
    sigma_accel=Param(50.0, "m/s^2", "the filters' process-noise acceleration std (paper: 50)", **_NONNEG),
    target_sigma_accel=Param(5.0, "m/s^2", "the true target's acceleration noise std (ours)", **_NONNEG),
    uav_speed=Param(800.0, "m/s", "UAV airspeed (paper: 800 m/s)", **_NONNEG, per_agent=True),
    alpha_phi=Param(1.0, "1/s", "autopilot heading gain, eq. 3 (ours)", **_POS),
    turn_rate_max=Param(float(np.deg2rad(10.0)), "rad/s", "turn-rate limit, eq. 4 (ours)", **_NONNEG),
    heading_cmd=Param(float(np.arctan2(-1000.0, 200.0)), "rad", "held heading command (open loop only)",
                      **_ANGLE, per_agent=True),
    initial_positions=Param(_paper_positions, "m", "initial UAV positions (paper, sec. 5)", shape=("n", 2)),
    initial_headings=Param(0.0, "rad", "initial headings (ours)", **_ANGLE, per_agent=True),
    target_x0=Param(np.array([200e3, 200.0, 180e3, -1000.0]), "m, m/s", "initial target state [x, vx, y, vy]",
                    shape=(4,)),
    p0_diag=Param(np.array([100.0**2, 10.0**2, 100.0**2, 10.0**2]), "m^2, (m/s)^2",
                  "prior variances at the first measurement (ours)", **_POS, shape=(4,)),
    kcf_epsilon=Param(0.1, "", "KCF consensus gain epsilon (ours)", **_NONNEG),
    alive=Param(lambda cfg: np.ones(cfg.n_agents), "", "1 = alive, 0 = dropped out (masked, never removed)",
                choices=(0, 1), per_agent=True),
    alpha_I=Param(1000.0, "", "weight of the connectivity-robustness penalty (case 1 of Table 1: 0)", **_NONNEG),
    alpha_C=Param(1.0, "1/rad", "weight of the control effort, eq. 17", **_NONNEG),
    alpha_L=Param(1e-4, "1/m", "weight of the distance to the target", **_NONNEG),
    alpha_S=Param(1e4, "", "weight of the D_safe / D_LT penalties, eqs. 18-19", **_NONNEG),
    d_safe=Param(1e3, "m", "D_safe, eq. 18", **_POS, display="km"),
    d_lt=Param(20e3, "m", "D_LT, eq. 19", **_POS, display="km"),
    robustness_scale=Param(5e3, "m", "s of the barrier softplus(-R_I/s)", **_POS, display="km"),
    plan_temperature=Param(1e3, "m", "temperature of the smooth cost (gradient planner)", **_POS),
    horizon=Param(5, "steps", "t_r, the planning horizon (paper: 5; <= max_horizon)", low=1, integer=True),
    replan_every=Param(3, "steps", "tau_r, steps between re-plans (paper: 3; <= t_r)", low=1, integer=True),
    **faults.PARAMS,
), __name__)


def check_params(cfg, values: dict) -> list[tuple[str, str]]:
    """Checks across fields: ``[(field, what is allowed), …]`` for the bad ones.

    t_r (``horizon``) must be an integer in [1, max_horizon]; τ_r (``replan_every``) an
    integer in [1, t_r] (Sun et al. 2011, sec. 4.2: 1 ≤ τ_r ≤ t_r)."""
    bad = []
    table = Params.TABLE
    tr = np.asarray(values.get("horizon", table["horizon"].default), np.float64)
    tau = np.asarray(values.get("replan_every", table["replan_every"].default), np.float64)
    if np.any(tr != np.round(tr)) or np.any(tr < 1) or np.any(tr > cfg.max_horizon):
        bad.append(("horizon", f"an integer in [1, max_horizon = {cfg.max_horizon}]"))
    if np.any(tau != np.round(tau)) or np.any(tau < 1) or np.any(tau > tr):
        bad.append(("replan_every", "an integer in [1, horizon]"))
    elif cfg.plan_period > 0 and np.any(tau != cfg.plan_period):
        bad.append(("replan_every", f"equal to config.plan_period = {cfg.plan_period} (set plan_period = 0 "
                                    "to vary it)"))
    return bad + faults.check(cfg, values, Params)


class State(NamedTuple):
    t: jax.Array
    target: jax.Array          # (4,)
    uavs: jax.Array            # (n, 4) [x, y, v, φ]
    filters: tuple             # one Gaussian per filter in cfg.filters
    plan_u: jax.Array          # (H, n) the plan in force, u in [−1, 1] (closed loop)
    plan_cmd: jax.Array        # (H, n) its heading commands, rad
    plan_age: jax.Array        # commands of the plan applied so far
    plan_cost: jax.Array       # exact eq. 16 cost of the plan in force
    faults: faults.State | None  # lost links and agents (mcjax.scenarios.faults; None: off)
    mailbox: faults.Mailbox | None  # the kcf's consensus messages in flight (None: message_delay = 0)


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
                 _mailbox(cfg, params, x0))


def _mailbox(cfg, params, x0):
    """The kcf's messages in flight before step 0 (None without delay or without a kcf),
    per-run from the start (:func:`kit.per_run`)."""
    box = faults.mailbox(cfg, x0) if "kcf" in cfg.filters else None
    return None if box is None else faults.Mailbox(*kit.per_run(params.dt, *box))


class Smoothing(NamedTuple):
    """Temperatures (m) of the smoothing switch (:func:`step` with ``smoothing``): the sensing
    gate ``sigmoid((R_s − r)/T)`` and the comm links ``sigmoid((min(R_i, R_j) − l_ij)/T)``
    (:func:`mcjax.scenarios.kit.soft_team_measurements`, :func:`mcjax.graph.soft_adjacency`,
    :func:`mcjax.graph.soft_component_sizes`); ours."""

    sensing: float = 1e3
    comm: float = 1e3


#: Params with no smooth path (:class:`mcjax.smoothing.Smooth`): the fault rates (the horizon and
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


def _advance(cfg, params, state: State, key, smoothing):
    """The physics and filters of one step (:func:`step`): ``(new State, _Step)``. ``smoothing``
    None is the exact simulation; a :class:`Smoothing` swaps the sensing gate and the comm graph
    for their smooth versions.

    Faults (:mod:`mcjax.scenarios.faults`): a lost UAV stops where it is, senses and sends
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
    alive = switched_on

    # R = diag(σ_r², σ_θ²) is diagonal: its inverse needs no LAPACK call on the hot path
    R_inv = jnp.diag(jnp.stack([1.0 / params.sigma_range**2, 1.0 / params.sigma_bearing**2]))
    R_inv = jnp.broadcast_to(R_inv, (n, 2, 2))
    comm = kit.agents(params.comm_radius, n, dtype)
    sensing = kit.agents(params.sensing_radius, n, dtype)
    if smoothing is None:
        z = faults.measurements(kit.team_measurements(k_meas, target, sensors, params.sigma_range,
                                                      params.sigma_bearing, sensing, alive), fault)
        adj = graph.adjacency(sensors, comm, alive)
        carried = faults.messages(adj, fault)
        meas = Measurements(z, sensors, carried, R_inv)
    else:  # (the smooth component sizes see lost agents, not lost links)
        z, gates = kit.soft_team_measurements(k_meas, target, sensors, params.sigma_range, params.sigma_bearing,
                                              sensing, alive, smoothing.sensing)
        z = faults.measurements(z, fault)
        adj = graph.soft_adjacency(sensors, comm, smoothing.comm, alive)
        carried = faults.messages(adj, fault)
        meas = Measurements(z, sensors, carried, R_inv * gates[:, None, None],
                            graph.soft_component_sizes(sensors, comm, smoothing.comm, alive & faults.alive(fault, n)))

    F, Q = first_step_model(first, cv_matrices(dt, dtype)[0], cv_process_noise(dt, params.sigma_accel, dtype))
    angle_mask = jnp.array([False, True])
    shielded = tuple(f if k == "cif" else faults.shield(fault, f) for k, f in zip(cfg.filters, state.filters))
    eps, mailbox = jnp.asarray(params.kcf_epsilon, dtype), state.mailbox
    if mailbox is None:
        filters = filter_step(cfg.filters, filter_options(cfg), range_bearing, angle_mask, shielded, meas, F, Q, eps)
    else:  # the kcf's consensus messages arrive message_delay steps late
        late = meas._replace(late=faults.late(mailbox, F))
        filters = tuple(filter_step((k,), filter_options(cfg), range_bearing, angle_mask, (f,),
                                    late if k == "kcf" else meas, F, Q, eps)[0] for k, f in zip(cfg.filters, shielded))
        mailbox = faults.post(mailbox, shielded[cfg.filters.index("kcf")].x, carried)
    filters = tuple(f if k == "cif" else faults.hold(fault, f, old)
                    for k, f, old in zip(cfg.filters, filters, state.filters))

    plan = (state.plan_u, state.plan_cmd, age, state.plan_cost)
    if cfg.planner != "none":
        team, leader = kit.agents(params.alive, n, dtype), 0
        if fault is not None:
            team, leader = team * fault.alive.astype(dtype), jnp.argmax(fault.alive)
        plan = plan_if_due(cfg, params, state, uavs, filters, age, jax.random.fold_in(key, 0x9A11),
                           team, leader)
    return (State(state.t + 1, target, uavs, filters, *plan, fault_state, mailbox),
            _Step(target, sensors, z, adj, carried, fault, filters))


def step(cfg, params, state: State, key, smoothing: Smoothing | None = None) -> tuple[State, Record]:
    """One 1-s step: move target (eq. 1) and UAVs (eqs. 3–4, exact heading), measure (range-gated),
    build the comm graph (eq. 13), run every filter, record errors and graph metrics.

    Step 0 is the first measurement time: nothing moves and the filters update their prior
    without predicting (docs/equations.md). The graph statistics are those of the links
    that carried a message (the comm graph less the links lost to faults).

    ``smoothing`` (the smoothing switch, :class:`Smoothing`; None: the exact simulation) swaps
    the sensing gate and the comm graph for their smooth versions (:func:`kit.soft_team_measurements`,
    :func:`graph.soft_adjacency`, :func:`graph.soft_component_sizes`) for training by gradient and for
    sensitivities; dynamics (eqs. 1, 3–4), filters (eqs. 8–12) and the planner (eq. 16, whose
    gradient planner descends its own smooth cost) are the same, with the same random draws.
    The graph statistics are then those of the soft links' weights.
    """
    n, dtype = cfg.n_agents, jnp.dtype(cfg.dtype)
    params = kit.cast(params, dtype)
    new, s = _advance(cfg, params, state, key, smoothing)
    comm = kit.agents(params.comm_radius, n, dtype)
    post = [per_agent(k, f, n) for k, f in zip(cfg.filters, s.filters)]
    err = jnp.stack([metrics.position_error(g.x, s.target) for g in post])
    ne = jnp.stack([metrics.nees(g.x, g.Y, s.target) for g in post])
    rec = Record(
        error=err,
        nees=ne,
        lambda2=graph.algebraic_connectivity(s.carried),
        degrees=graph.degree(s.carried),
        robustness=(graph.tree_connectivity_robustness(s.sensors, comm)  # the same numbers in O(n^2)
                    if resolve_paths(cfg.robustness_paths, n) == "spanning_tree"
                    else graph.connectivity_robustness(s.sensors, comm)),
        n_seeing=jnp.sum(jnp.all(jnp.isfinite(s.z), axis=-1)),
        positions=s.sensors,
        target=s.target,
        measurements=s.z,
        adjacency=s.carried,
        plan_cost=new.plan_cost,
        faults=faults.record(s.comm_graph, s.carried, s.faults, kit.agents(params.alive, n, dtype) > 0.5),
    )
    return new, rec


def training_errors(cfg, params, record: Record):
    """What the training loss of ``mcjax tune`` reads from a step's record: the position errors
    (F, n) of every filter and agent."""
    return record.error


def training_weights(cfg, params):
    """What the training loss of ``mcjax tune`` reads: the alive weights (n,) of the errors
    :func:`training_errors` returns."""
    return metrics.alive_weights(params.alive, cfg.n_agents, jnp.dtype(cfg.dtype))


def summary(cfg, records: Record | None, params) -> dict:
    """One run's records (stacked over time) reduced to its outputs, each declared next to its
    value (:func:`mcjax.contract.declare`; ``records`` None: the declarations alone)."""
    r, w, F = records, cfg.warmup_steps, len(cfg.filters)
    switched_on = cache(lambda: metrics.alive_weights(params.alive, cfg.n_agents, r.error.dtype))
    alive = cache(lambda: faults.weights(switched_on(), r.faults))
    return declare(
        **kit.error_items(lambda: r.error, alive, cfg, "m"),
        leader_rmse=(Output("m", "the leader's (agent 0) position RMSE after warm-up"),
                     lambda: jnp.stack([metrics.rmse(r.error[:, f, :1], w) for f in range(F)])),
        anees=(Output("", "mean full-state NEES over alive agents and steps after warm-up (4 dof)"),
               lambda: jnp.stack([metrics.mean_over(faults.masked(r.nees[:, f, :], alive()), w, alive())
                                   for f in range(F)])),
        **kit.graph_items(lambda: r.lambda2),
        robustness_min=(Output("m", "smallest connectivity robustness R_I of any agent over the run", False),
                        lambda: jnp.min(r.robustness)),
        seeing_mean=(Output("", "mean number of agents that see the target", False),
                     lambda: jnp.mean(r.n_seeing.astype(r.lambda2.dtype))),
        seeing_min=(Output("", "fewest agents that see the target at any step", False), lambda: jnp.min(r.n_seeing)),
        plan_cost_mean=(Output("", "mean exact eq. 16 cost of the plans in force (0 in open loop)", False),
                        lambda: jnp.mean(r.plan_cost)),
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
        leader_error=(Output("m", "the leader's (agent 0) position error"), lambda: r.error[..., 0]),
        lambda2=(Output("", "algebraic connectivity of the comm graph", False), lambda: r.lambda2),
        robustness_min=(Output("m", "smallest connectivity robustness R_I", False),
                        lambda: jnp.min(r.robustness, -1)),
        n_seeing=(Output("", "agents that see the target", False), lambda: r.n_seeing),
        plan_cost=(Output("", "exact eq. 16 cost of the plan in force (0 in open loop)", False),
                   lambda: r.plan_cost),
        **faults.series_items(cfg, r and r.faults, switched_on),
    )


SCENARIO = Scenario(
    name=NAME, title="Sun, Zhou, Zou & Ding 2011: leader-follower UAVs, consensus information filters, "
    "receding-horizon planning", Config=Config, Params=Params, init=init, step=step, summary=summary,
    series=series, check_params=check_params,
    smooth=Smooth(Smoothing, training_errors, training_weights, ROUGH),
    compiler_options=FAST_COMPILE,
    filter_words={
        "cif": "centralised information filter: one filter fuses every UAV's measurements (the bound the "
               "distributed filters aim at)",
        "icf": "information consensus filter (Casbeer & Beard 2009): the UAVs average their new measurement "
               "information by consensus with their neighbours, then update",
        "modified_icf": "Sun et al. 2011's modified information consensus filter: each UAV adds its own "
                        "measurement information, then averages the whole information pair with its neighbours",
        "kcf": "Kalman-consensus filter (Olfati-Saber 2009): a local update with the neighbours' measurements "
               "plus a step towards their estimates",
        "local": "each UAV's own extended Kalman filter on its own measurements, nothing shared"})
default_params = SCENARIO.default_params
#: The record's derived functions (from :func:`summary` and :func:`series`), by their usual names.
reduce, outputs = SCENARIO.reduce, SCENARIO.outputs
timeseries, timeseries_outputs = SCENARIO.timeseries, SCENARIO.timeseries_outputs
