"""Leader–follower UAV team tracking a CV target — Sun et al. 2011 (seed 000).

One leader (agent 0) and four followers with range–bearing radars (sensing radius 120 km)
and a 100 km comm range track a constant-velocity target. Each step records, for every
filter, each agent's position error and NEES, plus λ2, degrees, connectivity robustness R_I
and how many agents see the target.

``Config.planner = "none"`` is the open loop: every UAV holds ``Params.heading_cmd``.
Otherwise the loop is closed as in seed 000 §4: every τ_r steps (``Params.replan_every``)
the leader plans the headings of all UAVs over the horizon t_r (``Params.horizon``) from
its own modified-ICF estimate and the UAV states it knows, minimising eq. 16 with eqs.
18–19 as penalties (:mod:`mcjax.planning`), and the UAVs fly the first τ_r commands.

Units are SI (m, s, rad). Defaults are the paper's numbers; the values the paper leaves
open are our choices, marked in ``configs/sun2011.toml``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mcjax import graph, metrics
from mcjax.numerics import symmetrize
from mcjax.filters.consensus import (
    CONTRIBUTION_KINDS,
    FILTER_KINDS,
    ICF_VARIANTS,
    KCF_GAINS,
    WEIGHT_KINDS,
    FilterOptions,
    Measurements,
    filter_step,
    init_states,
    per_agent,
)
from mcjax.models.motion import cv_matrices, cv_process_noise, cv_step
from mcjax.models.platforms import UnicycleLimits, unicycle_step
from mcjax.models.sensors import measure_range_bearing, range_bearing
from mcjax.planning import CostParams, Dynamics, PlannerOptions, Problem, rollout, shift_plan, solve
from mcjax.planning.objectives import ROBUSTNESS_PENALTIES
from mcjax.planning.solvers import PLANNER_KINDS
from mcjax.scenarios.common import DTYPES, agents, cast, check_config, choices, make_params

NAME = "leader_follower"
PAPER = "Sun, Zhou, Zou, Ding 2011 (seed 000)"


@dataclass(frozen=True)
class Config:
    """Everything that fixes shapes or the compiled program (changing it recompiles)."""

    n_agents: int = 5
    n_steps: int = 200
    filters: tuple[str, ...] = FILTER_KINDS
    consensus_steps: int = 1
    consensus_weights: str = "eq11"
    contribution: str = "component"
    icf_variant: str = "contributions"
    kcf_gain: str = "gamma_M"
    divergence_threshold: float = 1000.0  # m — our choice (the paper gives no rule)
    warmup_steps: int = 10
    dtype: str = "float64"
    planner: str = "none"            # "none" (open loop) | "gradient" | "random" | "cem"
    max_horizon: int = 8             # steps the rollout runs; Params.horizon (t_r) <= this
    plan_iterations: int = 10        # gradient: Adam steps; cem: rounds
    plan_samples: int = 256          # random / cem: plans scored per re-plan
    plan_learning_rate: float = 0.3  # Adam step on θ, u = tanh θ
    plan_elite_fraction: float = 0.1 # cem
    robustness_penalty: str = "barrier"  # "barrier" (ours, algorithms.md §5) | "inverse" (paper's 1/|R|)

    def __post_init__(self):
        check_config(self, FILTER_KINDS)
        self.filter_options()  # validates the filter choices
        if self.planner not in ("none",) + PLANNER_KINDS:
            raise ValueError(f"planner must be one of none, {', '.join(PLANNER_KINDS)}; got {self.planner!r}")
        if not isinstance(self.max_horizon, int) or self.max_horizon < 1:
            raise ValueError(f"max_horizon must be an integer >= 1; got {self.max_horizon!r}")
        if self.planner != "none":
            if "modified_icf" not in self.filters:
                raise ValueError("filters must include 'modified_icf' when a planner is on: "
                                 "the leader plans from its modified-ICF estimate (seed 000 §4)")
            self.planner_options()  # validates the planner choices

    def filter_options(self) -> FilterOptions:
        return FilterOptions(self.consensus_steps, self.consensus_weights, self.contribution,
                             self.icf_variant, self.kcf_gain)

    def planner_options(self) -> PlannerOptions:
        return PlannerOptions(self.planner, self.plan_iterations, self.plan_samples,
                              self.plan_learning_rate, self.plan_elite_fraction, self.robustness_penalty)



#: Allowed values of each Config field, as shown by ``mcjax list``.
CONFIG_ALLOWED = {
    "n_agents": "integer >= 1", "n_steps": "integer >= 1",
    "filters": "non-empty subset of " + ", ".join(FILTER_KINDS),
    "consensus_steps": "integer >= 0", "consensus_weights": choices(WEIGHT_KINDS),
    "contribution": choices(CONTRIBUTION_KINDS), "icf_variant": choices(ICF_VARIANTS),
    "kcf_gain": choices(KCF_GAINS), "divergence_threshold": "> 0 (m)",
    "warmup_steps": "integer in [0, n_steps)", "dtype": choices(DTYPES),
    "planner": choices(("none",) + PLANNER_KINDS), "max_horizon": "integer >= 1",
    "plan_iterations": "integer >= 1", "plan_samples": "integer >= 2 (cem: >= 2 per round)",
    "plan_learning_rate": "> 0", "plan_elite_fraction": "in (0, 1]",
    "robustness_penalty": choices(ROBUSTNESS_PENALTIES),
}


class Params(NamedTuple):
    """Per-run values a sweep may vary without recompiling. Per-agent fields accept a scalar
    (same for every agent) or one value per agent."""

    dt: jax.Array                 # s, radar sampling = comm interval (paper: 1 s)
    comm_radius: jax.Array        # m (paper: 100 km), scalar or (n,)
    sensing_radius: jax.Array     # m (paper: 120 km), scalar or (n,)
    sigma_range: jax.Array        # m (paper: 10 m)
    sigma_bearing: jax.Array      # rad (paper: 0.017 rad)
    sigma_accel: jax.Array        # m/s² the filters' process-noise model (paper: 50)
    target_sigma_accel: jax.Array # m/s² the true target's acceleration noise (ours: 5, see configs/sun2011.toml)
    uav_speed: jax.Array          # m/s (paper: 800 m/s), scalar or (n,)
    alpha_phi: jax.Array          # 1/s autopilot heading gain (ours)
    turn_rate_max: jax.Array      # rad/s eq. 4 limit (ours)
    heading_cmd: jax.Array        # rad, held heading command (open loop), scalar or (n,)
    initial_positions: jax.Array  # (n, 2) m
    initial_headings: jax.Array   # rad, scalar or (n,)
    target_x0: jax.Array          # (4,) [x, ẋ, y, ẏ]
    p0_diag: jax.Array            # (4,) prior variances at the first measurement (ours)
    kcf_epsilon: jax.Array        # KCF consensus gain ε (ours)
    alive: jax.Array              # (n,) 1 = alive, 0 = dropped out (masked, never removed)
    # closed loop (seed 000 §4; used when Config.planner != "none")
    alpha_I: jax.Array            # weight of the connectivity-robustness penalty (case 1 of Table 1: 0)
    alpha_C: jax.Array            # 1/rad, weight of the control effort (eq. 17)
    alpha_L: jax.Array            # 1/m, weight of the distance to the target
    alpha_S: jax.Array            # weight of the D_safe / D_LT penalties (eqs. 18–19)
    d_safe: jax.Array             # m, eq. 18
    d_lt: jax.Array               # m, eq. 19
    robustness_scale: jax.Array   # m, s of the barrier softplus(−R_I/s)
    plan_temperature: jax.Array   # m, temperature of the smooth cost (gradient planner)
    horizon: jax.Array            # t_r, steps (integer, 1 … Config.max_horizon)
    replan_every: jax.Array       # τ_r, steps (integer, 1 … t_r)


PER_AGENT_FIELDS = ("comm_radius", "sensing_radius", "uav_speed", "heading_cmd",
                    "initial_headings", "alive")

PARAM_UNITS = {
    "dt": "s", "comm_radius": "m", "sensing_radius": "m", "sigma_range": "m",
    "sigma_bearing": "rad", "sigma_accel": "m/s^2", "target_sigma_accel": "m/s^2", "uav_speed": "m/s", "alpha_phi": "1/s",
    "turn_rate_max": "rad/s", "heading_cmd": "rad", "initial_positions": "m",
    "initial_headings": "rad", "target_x0": "m, m/s", "p0_diag": "m^2, (m/s)^2",
    "kcf_epsilon": "-", "alive": "0/1", "alpha_I": "-", "alpha_C": "1/rad", "alpha_L": "1/m",
    "alpha_S": "-", "d_safe": "m", "d_lt": "m", "robustness_scale": "m", "plan_temperature": "m",
    "horizon": "steps", "replan_every": "steps",
}


_POS = (1e-300, np.inf, "> 0")
_NONNEG = (0.0, np.inf, ">= 0")
#: Allowed values of each Params field: (low, high, text), checked by sweep specs.
PARAM_RANGES = {
    "dt": _POS, "comm_radius": _NONNEG, "sensing_radius": _NONNEG, "sigma_range": _POS,
    "sigma_bearing": _POS, "sigma_accel": _NONNEG, "target_sigma_accel": _NONNEG, "uav_speed": _NONNEG, "alpha_phi": _POS,
    "turn_rate_max": _NONNEG, "heading_cmd": (-10.0, 10.0, "in [-10, 10] rad"),
    "initial_headings": (-10.0, 10.0, "in [-10, 10] rad"), "p0_diag": _POS,
    "kcf_epsilon": _NONNEG, "alive": (0.0, 1.0, "0 or 1"), "alpha_I": _NONNEG, "alpha_C": _NONNEG,
    "alpha_L": _NONNEG, "alpha_S": _NONNEG, "d_safe": _POS, "d_lt": _POS, "robustness_scale": _POS,
    "plan_temperature": _POS, "horizon": (1.0, np.inf, "an integer >= 1"),
    "replan_every": (1.0, np.inf, "an integer >= 1"),
}


def check_params(cfg: Config, values: dict) -> list[tuple[str, str]]:
    """Checks that depend on the Config: ``[(field, what is allowed), …]`` for the bad ones.

    t_r (``horizon``) must be an integer in [1, max_horizon]; τ_r (``replan_every``) an
    integer in [1, t_r] (seed 000 §4.2: 1 ≤ τ_r ≤ t_r)."""
    bad = []
    tr = np.asarray(values.get("horizon", DEFAULT_HORIZON), np.float64)
    tau = np.asarray(values.get("replan_every", DEFAULT_REPLAN), np.float64)
    if np.any(tr != np.round(tr)) or np.any(tr < 1) or np.any(tr > cfg.max_horizon):
        bad.append(("horizon", f"an integer in [1, max_horizon = {cfg.max_horizon}]"))
    if np.any(tau != np.round(tau)) or np.any(tau < 1) or np.any(tau > tr):
        bad.append(("replan_every", "an integer in [1, horizon]"))
    return bad


DEFAULT_HORIZON = 5   # t_r (paper: 5)
DEFAULT_REPLAN = 3    # τ_r (paper: 3)
#: Closed-loop defaults: t_r and τ_r are the paper's, the weights and distances are ours
#: (the paper gives none; configs/sun2011.toml says how they were chosen).
PLANNING_DEFAULTS = dict(
    alpha_I=1000.0, alpha_C=1.0, alpha_L=1e-4, alpha_S=1e4, d_safe=1e3, d_lt=20e3,
    robustness_scale=5e3, plan_temperature=1e3, horizon=DEFAULT_HORIZON, replan_every=DEFAULT_REPLAN,
)


def default_params(cfg: Config = Config(), **overrides) -> Params:
    """The paper's set-up (seed 000 §5) as numpy arrays; ``overrides`` replace fields."""
    n = cfg.n_agents
    paper_positions = np.array([[20e3, 150e3], [80e3, 150e3], [130e3, 200e3],
                                [130e3, 100e3], [180e3, 150e3]])
    if n <= 5:
        positions = paper_positions[:n]
    else:  # extra followers spread behind the leader on a line (our choice)
        extra = np.stack([np.full(n - 5, 20e3), 150e3 + 20e3 * np.arange(1, n - 4)], -1)
        positions = np.concatenate([paper_positions, extra])
    values = dict(
        dt=1.0,
        comm_radius=100e3,
        sensing_radius=120e3,
        sigma_range=10.0,
        sigma_bearing=0.017,
        sigma_accel=50.0,
        target_sigma_accel=5.0,
        uav_speed=800.0,
        alpha_phi=1.0,
        turn_rate_max=np.deg2rad(10.0),
        heading_cmd=float(np.arctan2(-1000.0, 200.0)),
        initial_positions=positions,
        initial_headings=0.0,
        target_x0=np.array([200e3, 200.0, 180e3, -1000.0]),
        p0_diag=np.array([100.0**2, 10.0**2, 100.0**2, 10.0**2]),
        kcf_epsilon=0.1,
        alive=np.ones(n),
        **PLANNING_DEFAULTS,
    )
    return make_params(Params, values, overrides)


class State(NamedTuple):
    t: jax.Array
    target: jax.Array          # (4,)
    uavs: jax.Array            # (n, 4) [x, y, v, φ]
    filters: tuple             # one Gaussian per filter in cfg.filters
    plan_u: jax.Array          # (H, n) the plan in force, u in [−1, 1] (closed loop)
    plan_cmd: jax.Array        # (H, n) its heading commands, rad
    plan_age: jax.Array        # commands of the plan applied so far
    plan_cost: jax.Array       # exact eq. 16 cost of the plan in force


class Record(NamedTuple):
    error: jax.Array           # (F, n) position error per filter and agent, m
    nees: jax.Array            # (F, n) full-state NEES
    lambda2: jax.Array         # ()
    degrees: jax.Array         # (n,)
    robustness: jax.Array      # (n,) R_I, m
    n_seeing: jax.Array        # () agents with a measurement
    positions: jax.Array       # (n, 2)
    target: jax.Array          # (4,)
    measurements: jax.Array    # (n, 2) range–bearing, NaN where none
    adjacency: jax.Array       # (n, n) comm graph
    plan_cost: jax.Array       # () exact eq. 16 cost of the plan in force (0 in open loop)



def init(cfg: Config, params: Params, key) -> State:
    """State before step 0: true target, UAVs at their initial poses, filters at the prior
    (the true initial state with covariance ``diag(p0_diag)``, seed 000 §5)."""
    del key
    n, dtype = cfg.n_agents, jnp.dtype(cfg.dtype)
    params = cast(params, dtype)
    uavs = jnp.concatenate([
        jnp.asarray(params.initial_positions, dtype),
        agents(params.uav_speed, n, dtype)[:, None],
        agents(params.initial_headings, n, dtype)[:, None],
    ], axis=-1)
    x0 = jnp.asarray(params.target_x0, dtype)
    P0 = jnp.diag(jnp.asarray(params.p0_diag, dtype))
    plan = jnp.zeros((cfg.max_horizon, n), dtype)
    return State(jnp.asarray(0, jnp.int32), x0, uavs, init_states(cfg.filters, x0, P0, n),
                 plan, plan, jnp.asarray(0, jnp.int32), jnp.zeros((), dtype))


def _plan(cfg: Config, params: Params, state: State, uavs, filters, age, key):
    """Re-plan if due (every τ_r steps, and at step 0): seed 000 §4.2 steps ① – ③.

    The leader (agent 0) plans from its own modified-ICF estimate and the UAV states it
    knows; the plan is computed every step (one program for every τ_r in a batch) and kept
    only when due."""
    n, dtype = cfg.n_agents, uavs.dtype
    leader = per_agent("modified_icf", filters[cfg.filters.index("modified_icf")], n)
    problem = Problem(uavs, leader.x[0], symmetrize(leader.Y[0]))
    horizon = jnp.asarray(params.horizon, dtype)
    dyn = Dynamics(params.dt, params.alpha_phi, params.turn_rate_max, horizon, params.sigma_accel)
    cost = CostParams(
        params.alpha_I, params.alpha_C, params.alpha_L, params.alpha_S, params.d_safe, params.d_lt,
        params.robustness_scale, params.plan_temperature, agents(params.sensing_radius, n, dtype),
        agents(params.comm_radius, n, dtype), params.sigma_range, params.sigma_bearing,
        agents(params.alive, n, dtype))
    warm = shift_plan(state.plan_u, age, horizon)
    plan = solve(problem, warm, key, dyn, cost, cfg.planner_options())
    _, _, commands, _ = rollout(problem, plan.u, dyn)
    ok = jnp.all(jnp.isfinite(commands))
    commands = jnp.where(ok, commands, uavs[:, 3])  # a non-finite plan holds the headings
    due = (state.t == 0) | (age >= params.replan_every)
    return (jnp.where(due, plan.u, state.plan_u), jnp.where(due, commands, state.plan_cmd),
            jnp.where(due, 0, age), jnp.where(due, plan.cost, state.plan_cost))


def step(cfg: Config, params: Params, state: State, key) -> tuple[State, Record]:
    """One 1-s step: move target (eq. 1) and UAVs (eqs. 3–4, exact heading), measure (range-gated),
    build the comm graph (eq. 13), run every filter, record errors and graph metrics.

    Step 0 is the first measurement time: nothing moves and the filters update their prior
    without predicting (algorithms.md §2).
    """
    n, dtype = cfg.n_agents, jnp.dtype(cfg.dtype)
    params = cast(params, dtype)
    first = state.t == 0
    k_target, k_meas = jax.random.split(key)
    dt = jnp.asarray(params.dt, dtype)
    dt_move = jnp.where(first, 0.0, dt)

    target = jnp.where(first, state.target, cv_step(state.target, k_target, dt, params.target_sigma_accel))
    speed = agents(params.uav_speed, n, dtype)
    limits = UnicycleLimits(speed, speed, jnp.zeros((), dtype), jnp.zeros((), dtype),
                            jnp.asarray(params.turn_rate_max, dtype))
    if cfg.planner == "none":
        command, age = agents(params.heading_cmd, n, dtype), state.plan_age
    else:  # the next command of the plan in force (step 0 does not move)
        command = state.plan_cmd[jnp.minimum(state.plan_age, cfg.max_horizon - 1)]
        age = jnp.where(first, state.plan_age, state.plan_age + 1)
    uavs = unicycle_step(state.uavs, command, 0.0, params.alpha_phi, limits, dt_move)
    sensors = uavs[:, :2]
    alive = agents(params.alive, n, dtype) > 0.5

    sensing = agents(params.sensing_radius, n, dtype)
    keys = jax.random.split(k_meas, n)
    z = jax.vmap(measure_range_bearing, in_axes=(0, None, 0, None, None, 0, 0))(
        keys, target, sensors, params.sigma_range, params.sigma_bearing, sensing, alive)
    comm = agents(params.comm_radius, n, dtype)
    adj = graph.adjacency(sensors, comm, alive)

    F, _ = cv_matrices(dt, dtype)
    Q = cv_process_noise(dt, params.sigma_accel, dtype)
    F = jnp.where(first, jnp.eye(4, dtype=dtype), F)
    Q = jnp.where(first, 0.0, Q)
    # R = diag(σ_r², σ_θ²) is diagonal: its inverse needs no LAPACK call on the hot path
    R_inv = jnp.diag(jnp.stack([1.0 / params.sigma_range**2, 1.0 / params.sigma_bearing**2]))
    R_inv = jnp.broadcast_to(R_inv, (n, 2, 2))
    meas = Measurements(z, sensors, adj, R_inv)
    angle_mask = jnp.array([False, True])
    filters = filter_step(cfg.filters, cfg.filter_options(), range_bearing, angle_mask,
                          state.filters, meas, F, Q, jnp.asarray(params.kcf_epsilon, dtype))

    plan = (state.plan_u, state.plan_cmd, age, state.plan_cost)
    if cfg.planner != "none":
        plan = _plan(cfg, params, state, uavs, filters, age, jax.random.fold_in(key, 0x9A11))

    post = [per_agent(k, f, n) for k, f in zip(cfg.filters, filters)]
    err = jnp.stack([metrics.position_error(g.x, target) for g in post])
    ne = jnp.stack([metrics.nees(g.x, g.Y, target) for g in post])
    rec = Record(
        error=err,
        nees=ne,
        lambda2=graph.algebraic_connectivity(adj),
        degrees=graph.degree(adj),
        robustness=graph.connectivity_robustness(sensors, comm),
        n_seeing=jnp.sum(jnp.all(jnp.isfinite(z), axis=-1)),
        positions=sensors,
        target=target,
        measurements=z,
        adjacency=adj,
        plan_cost=plan[3],
    )
    return State(state.t + 1, target, uavs, filters, *plan), rec


#: Per-run summary fields: (name, per_filter, description).
SUMMARY_FIELDS = (
    ("rmse", True, "position RMSE over agents and steps after warm-up, m"),
    ("mean_error", True, "mean position error over agents and steps after warm-up, m"),
    ("final_error", True, "mean position error over agents at the last step, m"),
    ("max_error", True, "largest position error of any agent after warm-up, m"),
    ("leader_rmse", True, "the leader's (agent 0) position RMSE after warm-up, m"),
    ("anees", True, "mean full-state NEES over agents and steps after warm-up (4 dof)"),
    ("diverged", True, "error above divergence_threshold after warm-up, or non-finite"),
    ("nonfinite", True, "some estimate went NaN/inf"),
    *metrics.GRAPH_SUMMARY_FIELDS,
    ("robustness_min", False, "smallest R_I of any agent over the run, m"),
    ("seeing_mean", False, "mean number of agents that see the target"),
    ("seeing_min", False, "fewest agents that see the target at any step"),
    ("plan_cost_mean", False, "mean exact eq. 16 cost of the plans in force (0 in open loop)"),
)


def summarize(cfg: Config, records: Record, params: Params | None = None) -> dict:
    """Reduce one run's records (stacked over time) to scalars (algorithms.md §8)."""
    w = cfg.warmup_steps
    alive = metrics.alive_weights(None if params is None else params.alive, cfg.n_agents, records.error.dtype)
    out = {name: [] for name, per_filter, _ in SUMMARY_FIELDS if per_filter}
    for f in range(len(cfg.filters)):
        e = records.error[:, f, :]
        ne = records.nees[:, f, :]
        out["rmse"].append(metrics.rmse(e, w, alive))
        out["mean_error"].append(metrics.mean_over(e, w, alive))
        out["final_error"].append(metrics.mean_over(e[-1:], 0, alive))
        out["max_error"].append(jnp.max(jnp.where(jnp.arange(e.shape[0])[:, None] >= w, e, 0.0)))
        out["leader_rmse"].append(metrics.rmse(e[:, :1], w))
        out["anees"].append(metrics.mean_over(ne, w, alive))
        out["diverged"].append(metrics.diverged(e, cfg.divergence_threshold, w, alive))
        out["nonfinite"].append(metrics.nonfinite(e))
    summary = {k: jnp.stack(v) for k, v in out.items()}
    lam = records.lambda2
    summary.update(
        **metrics.graph_summary(lam),
        robustness_min=jnp.min(records.robustness),
        seeing_mean=jnp.mean(records.n_seeing.astype(lam.dtype)),
        seeing_min=jnp.min(records.n_seeing),
        plan_cost_mean=jnp.mean(records.plan_cost),
    )
    return summary


#: Per-step series written to ``OUT/timeseries/`` when a sweep spec sets ``timeseries = true``:
#: (name, per_filter, description).
TIMESERIES_FIELDS = (
    ("error_mean", True, "mean position error over alive agents, m"),
    ("error_max", True, "largest position error of any alive agent, m"),
    ("leader_error", True, "the leader's (agent 0) position error, m"),
    ("lambda2", False, "algebraic connectivity of the comm graph"),
    ("robustness_min", False, "smallest connectivity robustness R_I, m"),
    ("n_seeing", False, "agents that see the target"),
    ("plan_cost", False, "exact eq. 16 cost of the plan in force (0 in open loop)"),
)


def timeseries(cfg: Config, records: Record, params: Params | None = None) -> dict:
    """A few per-step series of one run: (T, F) per filter, (T,) otherwise."""
    e = records.error  # (T, F, n)
    alive = metrics.alive_weights(None if params is None else params.alive, cfg.n_agents, e.dtype)
    return dict(
        **metrics.error_series(e, alive),
        leader_error=e[..., 0],
        lambda2=records.lambda2,
        robustness_min=jnp.min(records.robustness, -1),
        n_seeing=records.n_seeing,
        plan_cost=records.plan_cost,
    )
