"""Leader–follower UAV team tracking a CV target — Sun et al. 2011 (seed 000), open loop.

One leader (agent 0) and four followers with range–bearing radars (sensing radius 120 km)
and a 100 km comm range track a constant-velocity target. In this open-loop form every UAV
holds the heading command given in ``Params.heading_cmd`` (the receding-horizon planner is
a later layer). Each step records, for every filter, each agent's position error and NEES,
plus λ2, degrees, connectivity robustness R_I and how many agents see the target.

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
from mcjax.filters.consensus import (
    FILTER_KINDS,
    FilterOptions,
    Measurements,
    filter_step,
    init_states,
    per_agent,
)
from mcjax.models.motion import cv_matrices, cv_process_noise, cv_step
from mcjax.models.platforms import UnicycleLimits, unicycle_step
from mcjax.models.sensors import measure_range_bearing, range_bearing

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

    def __post_init__(self):
        if not isinstance(self.n_agents, int) or self.n_agents < 1:
            raise ValueError(f"n_agents must be an integer >= 1; got {self.n_agents!r}")
        if not isinstance(self.n_steps, int) or self.n_steps < 1:
            raise ValueError(f"n_steps must be an integer >= 1; got {self.n_steps!r}")
        if not self.filters:
            raise ValueError("filters must name at least one filter")
        for f in self.filters:
            if f not in FILTER_KINDS:
                raise ValueError(f"filters: unknown filter {f!r}; allowed: {', '.join(FILTER_KINDS)}")
        if len(set(self.filters)) != len(self.filters):
            raise ValueError(f"filters must not repeat a filter; got {self.filters}")
        if self.dtype not in ("float64", "float32"):
            raise ValueError(f"dtype must be 'float64' or 'float32'; got {self.dtype!r}")
        if not 0 <= self.warmup_steps < self.n_steps:
            raise ValueError(f"warmup_steps must be in [0, n_steps); got {self.warmup_steps}")
        if not self.divergence_threshold > 0:
            raise ValueError(f"divergence_threshold must be > 0 m; got {self.divergence_threshold}")
        self.filter_options()  # validates the filter choices

    def filter_options(self) -> FilterOptions:
        return FilterOptions(self.consensus_steps, self.consensus_weights, self.contribution,
                             self.icf_variant, self.kcf_gain)


class Params(NamedTuple):
    """Per-run values a sweep may vary without recompiling. Per-agent fields accept a scalar
    (same for every agent) or one value per agent."""

    dt: jax.Array                 # s, radar sampling = comm interval (paper: 1 s)
    comm_radius: jax.Array        # m (paper: 100 km), scalar or (n,)
    sensing_radius: jax.Array     # m (paper: 120 km), scalar or (n,)
    sigma_range: jax.Array        # m (paper: 10 m)
    sigma_bearing: jax.Array      # rad (paper: 0.017 rad)
    sigma_accel: jax.Array        # m/s² target acceleration noise (paper: 50)
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


PER_AGENT_FIELDS = ("comm_radius", "sensing_radius", "uav_speed", "heading_cmd",
                    "initial_headings", "alive")

PARAM_UNITS = {
    "dt": "s", "comm_radius": "m", "sensing_radius": "m", "sigma_range": "m",
    "sigma_bearing": "rad", "sigma_accel": "m/s^2", "uav_speed": "m/s", "alpha_phi": "1/s",
    "turn_rate_max": "rad/s", "heading_cmd": "rad", "initial_positions": "m",
    "initial_headings": "rad", "target_x0": "m, m/s", "p0_diag": "m^2, (m/s)^2",
    "kcf_epsilon": "-", "alive": "0/1",
}


_POS = (1e-300, np.inf, "> 0")
_NONNEG = (0.0, np.inf, ">= 0")
#: Allowed values of each Params field: (low, high, text), checked by sweep specs.
PARAM_RANGES = {
    "dt": _POS, "comm_radius": _NONNEG, "sensing_radius": _NONNEG, "sigma_range": _POS,
    "sigma_bearing": _POS, "sigma_accel": _NONNEG, "uav_speed": _NONNEG, "alpha_phi": _POS,
    "turn_rate_max": _NONNEG, "heading_cmd": (-10.0, 10.0, "in [-10, 10] rad"),
    "initial_headings": (-10.0, 10.0, "in [-10, 10] rad"), "p0_diag": _POS,
    "kcf_epsilon": _NONNEG, "alive": (0.0, 1.0, "0 or 1"),
}


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
    )
    unknown = set(overrides) - set(Params._fields)
    if unknown:
        raise ValueError(f"unknown Params field(s) {sorted(unknown)}; allowed: {', '.join(Params._fields)}")
    values.update(overrides)
    return Params(**{k: np.asarray(v, dtype=np.float64) for k, v in values.items()})


class State(NamedTuple):
    t: jax.Array
    target: jax.Array          # (4,)
    uavs: jax.Array            # (n, 4) [x, y, v, φ]
    filters: tuple             # one Gaussian per filter in cfg.filters


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


def _cast(params: Params, dtype) -> Params:
    return jax.tree.map(lambda a: jnp.asarray(a, dtype), params)


def _agents(p, n, dtype):
    return jnp.broadcast_to(jnp.asarray(p, dtype), (n,))


def init(cfg: Config, params: Params, key) -> State:
    """State before step 0: true target, UAVs at their initial poses, filters at the prior
    (the true initial state with covariance ``diag(p0_diag)``, seed 000 §5)."""
    del key
    n, dtype = cfg.n_agents, jnp.dtype(cfg.dtype)
    params = _cast(params, dtype)
    uavs = jnp.concatenate([
        jnp.asarray(params.initial_positions, dtype),
        _agents(params.uav_speed, n, dtype)[:, None],
        _agents(params.initial_headings, n, dtype)[:, None],
    ], axis=-1)
    x0 = jnp.asarray(params.target_x0, dtype)
    P0 = jnp.diag(jnp.asarray(params.p0_diag, dtype))
    return State(jnp.asarray(0, jnp.int32), x0, uavs, init_states(cfg.filters, x0, P0, n))


def step(cfg: Config, params: Params, state: State, key) -> tuple[State, Record]:
    """One 1-s step: move target (eq. 1) and UAVs (eq. 3, RK4), measure (range-gated),
    build the comm graph (eq. 13), run every filter, record errors and graph metrics.

    Step 0 is the first measurement time: nothing moves and the filters update their prior
    without predicting (algorithms.md §2).
    """
    n, dtype = cfg.n_agents, jnp.dtype(cfg.dtype)
    params = _cast(params, dtype)
    first = state.t == 0
    k_target, k_meas = jax.random.split(key)
    dt = jnp.asarray(params.dt, dtype)
    dt_move = jnp.where(first, 0.0, dt)

    target = jnp.where(first, state.target, cv_step(state.target, k_target, dt, params.sigma_accel))
    speed = _agents(params.uav_speed, n, dtype)
    limits = UnicycleLimits(speed, speed, jnp.zeros((), dtype), jnp.zeros((), dtype),
                            jnp.asarray(params.turn_rate_max, dtype))
    uavs = unicycle_step(state.uavs, _agents(params.heading_cmd, n, dtype), 0.0,
                         params.alpha_phi, limits, dt_move)
    sensors = uavs[:, :2]
    alive = _agents(params.alive, n, dtype) > 0.5

    sensing = _agents(params.sensing_radius, n, dtype)
    keys = jax.random.split(k_meas, n)
    z = jax.vmap(measure_range_bearing, in_axes=(0, None, 0, None, None, 0, 0))(
        keys, target, sensors, params.sigma_range, params.sigma_bearing, sensing, alive)
    comm = _agents(params.comm_radius, n, dtype)
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
    )
    return State(state.t + 1, target, uavs, filters), rec


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
    ("lambda2_min", False, "smallest algebraic connectivity over the run"),
    ("lambda2_mean", False, "mean algebraic connectivity"),
    ("disconnected_steps", False, "steps with lambda2 <= 1e-9 (graph disconnected)"),
    ("robustness_min", False, "smallest R_I of any agent over the run, m"),
    ("seeing_mean", False, "mean number of agents that see the target"),
    ("seeing_min", False, "fewest agents that see the target at any step"),
)


def summarize(cfg: Config, records: Record, params: Params | None = None) -> dict:
    """Reduce one run's records (stacked over time) to scalars (algorithms.md §8)."""
    w = cfg.warmup_steps
    alive = None
    if params is not None:
        alive = jnp.broadcast_to(jnp.asarray(params.alive, records.error.dtype) > 0.5,
                                 (cfg.n_agents,)).astype(records.error.dtype)
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
        lambda2_min=jnp.min(lam),
        lambda2_mean=jnp.mean(lam),
        disconnected_steps=jnp.sum(lam <= 1e-9),
        robustness_min=jnp.min(records.robustness),
        seeing_mean=jnp.mean(records.n_seeing.astype(lam.dtype)),
        seeing_min=jnp.min(records.n_seeing),
    )
    return summary
