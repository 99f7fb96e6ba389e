"""Six UUVs tracking a manoeuvring (CV ↔ CT) target by consensus IMM-UKF — Ren & Lv 2017 (seed 001).

Six stationary UUVs with range–bearing sonars track a target that switches between
constant velocity (CV) and a coordinated turn (CT) at turn rate ω, either on a fixed
schedule (CV, then CT over ``[ct_start, ct_stop)``, then CV — as in the paper's figures) or
as a Markov chain drawn per run (``Config.schedule = "markov"``). Each UUV runs, per filter:

* ``"imm"`` — the consensus IMM-UKF of seed 001 (CV and CT modes,
  :func:`mcjax.filters.consensus_imm.consensus_imm_ukf_step`);
* ``"cv"`` / ``"ct"`` — the single-model baselines: consensus UKF with the CV model only, or
  the CT model only (the same step with one mode, whose IMM cycle reduces to a UKF).

Consensus runs over the comm graph of ``Params.comm_radius`` (UUVs are stationary, so the
graph is fixed within a run; the default radius gives a ring). Each step records every
UUV's position error per filter (the paper's error E, read as the Euclidean position
error), the true mode and the IMM's CT probability.

Units are SI (m, s, rad). The paper's values and our choices for what it leaves open are
listed in ``configs/ren2017.toml``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mcjax import graph, metrics
from mcjax.filters.consensus_imm import LIKELIHOODS, consensus_imm_ukf_step
from mcjax.filters.gaussian import Unscented
from mcjax.filters.imm import IMMState
from mcjax.models.motion import ct_matrix, cv_matrices, cv_process_noise
from mcjax.models.sensors import measure_range_bearing, range_bearing
from mcjax.numerics import matvec, spd_inverse
from mcjax.scenarios.common import DTYPES, agents, cast, check_config, choices, make_params

NAME = "uuv_imm"
PAPER = "Ren, Lv 2017 (seed 001)"

#: Filters: name → the target modes it models (0 = CV, 1 = CT).
FILTER_MODES = {"imm": (0, 1), "cv": (0,), "ct": (1,)}
FILTER_KINDS = tuple(FILTER_MODES)
SCHEDULES = ("fixed", "markov")
WEIGHT_KINDS = ("metropolis", "max_degree")
CV, CT = 0, 1


@dataclass(frozen=True)
class Config:
    """Everything that fixes shapes or the compiled program (changing it recompiles)."""

    n_agents: int = 6
    n_steps: int = 100
    filters: tuple[str, ...] = FILTER_KINDS
    consensus_steps: int = 3             # L, consensus iterations per step and mode (ours)
    consensus_weights: str = "metropolis"  # paper: Metropolis; "max_degree" offered
    likelihood: str = "fused"            # "fused" (ours) | "local" (Li & Jia): see consensus_imm
    schedule: str = "fixed"              # "fixed": CV, CT on [ct_start, ct_stop), CV | "markov"
    divergence_threshold: float = 100.0  # m — our choice
    warmup_steps: int = 5
    dtype: str = "float64"
    ut_alpha: float = 1.0                # unscented transform (α, β, κ) — ours
    ut_beta: float = 2.0
    ut_kappa: float = 0.0

    def __post_init__(self):
        check_config(self, FILTER_KINDS, min_steps=2)
        if not isinstance(self.consensus_steps, int) or self.consensus_steps < 0:
            raise ValueError(f"consensus_steps must be an integer >= 0; got {self.consensus_steps!r}")
        for name, value, allowed in (("consensus_weights", self.consensus_weights, WEIGHT_KINDS),
                                     ("likelihood", self.likelihood, LIKELIHOODS),
                                     ("schedule", self.schedule, SCHEDULES)):
            if value not in allowed:
                raise ValueError(f"{name} must be {choices(allowed)}; got {value!r}")
        if not self.ut_alpha > 0 or not self.ut_beta >= 0 or not self.ut_kappa > -4:
            raise ValueError("ut_alpha must be > 0, ut_beta >= 0 and ut_kappa > -4 (the state has 4 components); "
                             f"got ({self.ut_alpha}, {self.ut_beta}, {self.ut_kappa})")

    def unscented(self) -> Unscented:
        return Unscented(self.ut_alpha, self.ut_beta, self.ut_kappa)



#: Allowed values of each Config field, as shown by ``mcjax list``.
CONFIG_ALLOWED = {
    "n_agents": "integer >= 1", "n_steps": "integer >= 2",
    "filters": "non-empty subset of " + ", ".join(FILTER_KINDS),
    "consensus_steps": "integer >= 0", "consensus_weights": choices(WEIGHT_KINDS),
    "likelihood": choices(LIKELIHOODS), "schedule": choices(SCHEDULES),
    "divergence_threshold": "> 0 (m)", "warmup_steps": "integer in [0, n_steps)",
    "dtype": choices(DTYPES), "ut_alpha": "> 0", "ut_beta": ">= 0",
    "ut_kappa": "> -4",
}


class Params(NamedTuple):
    """Per-run values a sweep may vary without recompiling. Per-agent fields accept a scalar
    (same for every UUV) or one value per UUV."""

    dt: jax.Array                  # s, sampling = consensus interval (ours: 1 s)
    comm_radius: jax.Array         # m, scalar or (n,) (ours: 450 m → a ring)
    sensing_radius: jax.Array      # m, scalar or (n,) (ours: 10 km — every UUV always measures)
    sigma_range: jax.Array         # m (paper: R = diag[5, 0.5]; ours: 5 = σ_r² in m²)
    sigma_bearing: jax.Array       # rad (ours: 0.5 = σ_θ² in deg²)
    turn_rate: jax.Array           # rad/s, ω of the CT mode (ours: 3°/s)
    model_turn_rate_error: jax.Array  # rad/s, the filters' CT model uses ω + this (0: known ω)
    sigma_accel: jax.Array         # m/s², the filters' process noise (both modes)
    target_sigma_accel: jax.Array  # m/s², the true target's acceleration noise
    ct_start: jax.Array            # step the CT manoeuvre starts (schedule "fixed")
    ct_stop: jax.Array             # step it ends (exclusive)
    target_transition: jax.Array   # (2, 2) true mode chain P(j | l) (schedule "markov")
    imm_transition: jax.Array      # (2, 2) the IMM's mode transition matrix
    mu0: jax.Array                 # (2,) IMM's initial mode probabilities [CV, CT]
    uuv_positions: jax.Array       # (n, 2) m, the stationary UUVs
    target_x0: jax.Array           # (4,) [x, ẋ, y, ẏ] (paper: [0 m, 5 m/s, 0 m, 5 m/s])
    p0_diag: jax.Array             # (4,) prior variances at the first measurement (ours)
    alive: jax.Array               # (n,) 1 = alive, 0 = dropped out (masked, never removed)


PER_AGENT_FIELDS = ("comm_radius", "sensing_radius", "alive")

PARAM_UNITS = {
    "dt": "s", "comm_radius": "m", "sensing_radius": "m", "sigma_range": "m", "sigma_bearing": "rad",
    "turn_rate": "rad/s", "model_turn_rate_error": "rad/s", "sigma_accel": "m/s^2",
    "target_sigma_accel": "m/s^2", "ct_start": "steps", "ct_stop": "steps", "target_transition": "-",
    "imm_transition": "-", "mu0": "-", "uuv_positions": "m", "target_x0": "m, m/s",
    "p0_diag": "m^2, (m/s)^2", "alive": "0/1",
}

_POS = (1e-300, np.inf, "> 0")
_NONNEG = (0.0, np.inf, ">= 0")
_PROB = (0.0, 1.0, "in [0, 1]")
#: Allowed values of each Params field: (low, high, text), checked by sweep specs.
PARAM_RANGES = {
    "dt": _POS, "comm_radius": _NONNEG, "sensing_radius": _NONNEG, "sigma_range": _POS,
    "sigma_bearing": _POS, "turn_rate": (-1.0, 1.0, "in [-1, 1] rad/s"),
    "model_turn_rate_error": (-1.0, 1.0, "in [-1, 1] rad/s"), "sigma_accel": _POS,
    "target_sigma_accel": _NONNEG, "ct_start": _NONNEG, "ct_stop": _NONNEG,
    "target_transition": _PROB, "imm_transition": _PROB, "mu0": _PROB, "p0_diag": _POS,
    "alive": (0.0, 1.0, "0 or 1"),
}


def check_params(cfg: Config, values: dict) -> list[tuple[str, str]]:
    """Checks across fields: ``[(field, what is allowed), …]`` for the bad ones."""
    bad = []
    d = default_params(cfg)
    for name in ("target_transition", "imm_transition"):
        m = np.asarray(values.get(name, getattr(d, name)), np.float64)
        if m.shape[-2:] != (2, 2) or np.any(np.abs(m.sum(-1) - 1.0) > 1e-9):
            bad.append((name, "a 2x2 matrix [[P(CV|CV), P(CT|CV)], [P(CV|CT), P(CT|CT)]] whose rows sum to 1"))
    mu0 = np.asarray(values.get("mu0", d.mu0), np.float64)
    if mu0.shape[-1:] != (2,) or np.any(np.abs(mu0.sum(-1) - 1.0) > 1e-9):
        bad.append(("mu0", "two probabilities [CV, CT] that sum to 1"))
    start = np.asarray(values.get("ct_start", d.ct_start), np.float64)
    stop = np.asarray(values.get("ct_stop", d.ct_stop), np.float64)
    if np.any(stop < start):
        bad.append(("ct_stop", "a step >= ct_start"))
    pos = np.asarray(values.get("uuv_positions", d.uuv_positions), np.float64)
    if pos.shape[-2:] != (cfg.n_agents, 2):
        bad.append(("uuv_positions", f"an (n_agents = {cfg.n_agents}) x 2 list of [x, y] in m"))
    return bad


def default_positions(n: int) -> np.ndarray:
    """Our UUV layout (the paper gives none): ``n`` UUVs on a circle of radius 400 m about
    (100 m, 200 m), the middle of the default target path, so neighbours on the circle are
    400 m apart for n = 6 and the default 450 m comm radius links each UUV to its two ring
    neighbours only (a ring: consensus needs several hops to spread information)."""
    angles = 2 * np.pi * np.arange(n) / max(n, 1)
    return np.stack([100.0 + 400.0 * np.cos(angles), 200.0 + 400.0 * np.sin(angles)], -1)


def default_params(cfg: Config = Config(), **overrides) -> Params:
    """The paper's set-up (seed 001 §4) with our choices for what it leaves open, as numpy arrays."""
    n = cfg.n_agents
    values = dict(
        dt=1.0,
        comm_radius=450.0,
        sensing_radius=10e3,
        sigma_range=float(np.sqrt(5.0)),
        sigma_bearing=float(np.deg2rad(np.sqrt(0.5))),
        turn_rate=float(np.deg2rad(3.0)),
        model_turn_rate_error=0.0,
        sigma_accel=0.05,
        target_sigma_accel=0.01,
        ct_start=float(cfg.n_steps // 3),
        ct_stop=float(2 * cfg.n_steps // 3),
        target_transition=np.array([[0.95, 0.05], [0.05, 0.95]]),
        imm_transition=np.array([[0.95, 0.05], [0.05, 0.95]]),
        mu0=np.array([0.5, 0.5]),
        uuv_positions=default_positions(n),
        target_x0=np.array([0.0, 5.0, 0.0, 5.0]),
        p0_diag=np.array([10.0**2, 1.0, 10.0**2, 1.0]),
        alive=np.ones(n),
    )
    return make_params(Params, values, overrides)


class State(NamedTuple):
    t: jax.Array
    target: jax.Array   # (4,)
    mode: jax.Array     # () int, the target's current mode (0 = CV, 1 = CT)
    filters: tuple      # one IMMState per filter, node axis first: μ (n, M), x (n, M, 4), P (n, M, 4, 4)


class Record(NamedTuple):
    error: jax.Array    # (F, n) position error per filter and UUV, m
    nees: jax.Array     # (F, n) full-state NEES of the combined estimate
    mode: jax.Array     # () true mode during the step's transition (0 = CV, 1 = CT)
    mu_ct: jax.Array    # (n,) the IMM's CT probability per UUV (NaN without "imm")
    lambda2: jax.Array  # ()
    n_seeing: jax.Array  # () UUVs with a measurement
    target: jax.Array   # (4,)
    measurements: jax.Array  # (n, 2) range–bearing, NaN where none



def init(cfg: Config, params: Params, key) -> State:
    """State before step 0: the target at ``target_x0`` in CV, and every UUV's filters at the
    prior (the true initial state, covariance ``diag(p0_diag)``; IMM mode probabilities ``mu0``)."""
    del key
    n, dtype = cfg.n_agents, jnp.dtype(cfg.dtype)
    params = cast(params, dtype)
    x0 = params.target_x0
    P0 = jnp.diag(params.p0_diag)
    states = []
    for f in cfg.filters:
        m = len(FILTER_MODES[f])
        mu = params.mu0 if m == 2 else jnp.ones(1, dtype)
        states.append(IMMState(jnp.broadcast_to(mu, (n, m)), jnp.broadcast_to(x0, (n, m, 4)),
                               jnp.broadcast_to(P0, (n, m, 4, 4))))
    return State(jnp.asarray(0, jnp.int32), x0, jnp.asarray(CV, jnp.int32), tuple(states))


def _true_mode(cfg: Config, params: Params, state: State, key):
    """The mode of the target's transition into step t: the fixed schedule (CT on
    ``[ct_start, ct_stop)``) or one draw of the Markov chain ``target_transition`` (seed 001)."""
    if cfg.schedule == "fixed":
        t = state.t.astype(params.ct_start.dtype)
        return ((t >= params.ct_start) & (t < params.ct_stop)).astype(jnp.int32)
    logp = jnp.log(params.target_transition[state.mode])
    return jax.random.categorical(key, logp).astype(jnp.int32)


def step(cfg: Config, params: Params, state: State, key) -> tuple[State, Record]:
    """One step: move the target (CV or CT, algorithms.md §4), measure range and bearing at
    every UUV, build the comm graph, run every filter's consensus IMM-UKF step (seed 001,
    algorithms.md §3), record errors.

    Step 0 is the first measurement time: nothing moves and the filters update their prior
    without predicting or mixing (algorithms.md §2)."""
    n, dtype = cfg.n_agents, jnp.dtype(cfg.dtype)
    params = cast(params, dtype)
    first = state.t == 0
    k_mode, k_target, k_meas = jax.random.split(key, 3)
    dt = params.dt

    F_cv, G = cv_matrices(dt, dtype)
    mode = jnp.where(first, state.mode, _true_mode(cfg, params, state, k_mode))
    F_true = jnp.where(mode == CT, ct_matrix(dt, params.turn_rate, dtype), F_cv)
    w = params.target_sigma_accel * jax.random.normal(k_target, (2,), dtype)
    target = jnp.where(first, state.target, matvec(F_true, state.target) + matvec(G, w))

    sensors = jnp.asarray(params.uuv_positions, dtype)
    alive = agents(params.alive, n, dtype) > 0.5
    z = jax.vmap(measure_range_bearing, in_axes=(0, None, 0, None, None, 0, 0))(
        jax.random.split(k_meas, n), target, sensors, params.sigma_range, params.sigma_bearing,
        agents(params.sensing_radius, n, dtype), alive)
    adj = graph.adjacency(sensors, agents(params.comm_radius, n, dtype), alive)

    Q = cv_process_noise(dt, params.sigma_accel, dtype)
    F_model = jnp.stack([F_cv, ct_matrix(dt, params.turn_rate + params.model_turn_rate_error, dtype)])
    F_model = jnp.where(first, jnp.eye(4, dtype=dtype), F_model)
    Q_model = jnp.where(first, 0.0, jnp.stack([Q, Q]))
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
            fstate, transition, F_model[modes], Q_model[modes], z, sensors, range_bearing, R, adj,
            steps=cfg.consensus_steps, weights=cfg.consensus_weights, likelihood=cfg.likelihood,
            ut=cfg.unscented(), angle_mask=angle_mask)
        new_filters.append(fnew)
        err.append(metrics.position_error(x, target))
        ne.append(metrics.nees(x, spd_inverse(P), target))
        if name == "imm":
            mu_ct = fnew.mu[:, CT]
    rec = Record(
        error=jnp.stack(err),
        nees=jnp.stack(ne),
        mode=mode,
        mu_ct=mu_ct,
        lambda2=graph.algebraic_connectivity(adj),
        n_seeing=jnp.sum(jnp.all(jnp.isfinite(z), axis=-1)),
        target=target,
        measurements=z,
    )
    return State(state.t + 1, target, mode, tuple(new_filters)), rec


#: Per-run summary fields: (name, per_filter, description). Besides these, per UUV i
#: (numbered from 1, as in the paper's Table 1): ``uuv{i}_max_error``, ``uuv{i}_min_error``,
#: ``uuv{i}_mean_error`` per filter — the max / min / mean over the steps after warm-up of
#: that UUV's position error.
SUMMARY_FIELDS = (
    ("rmse", True, "position RMSE over UUVs and steps after warm-up, m"),
    ("mean_error", True, "mean position error over UUVs and steps after warm-up, m"),
    ("max_error", True, "largest position error of any UUV after warm-up, m"),
    ("final_error", True, "mean position error over UUVs at the last step, m"),
    ("error_cv", True, "mean position error over UUVs and steps (after warm-up) while the target is in CV, m"),
    ("error_ct", True, "the same while the target turns (CT), m (NaN if it never does)"),
    ("anees", True, "mean full-state NEES over UUVs and steps after warm-up (4 dof)"),
    ("diverged", True, "error above divergence_threshold after warm-up, or non-finite"),
    ("nonfinite", True, "some estimate went NaN/inf"),
    *metrics.GRAPH_SUMMARY_FIELDS,
    ("ct_steps", False, "steps the target spent turning (CT)"),
    ("mode_accuracy", False, "fraction of (UUV, step) after warm-up where the IMM's likelier mode is the true one"),
    ("mu_ct_during_ct", False, "the IMM's mean CT probability while the target turns"),
)


def _masked_mean(values, mask):
    mask = jnp.broadcast_to(mask, values.shape).astype(values.dtype)
    return jnp.sum(mask * values) / jnp.sum(mask)


def summarize(cfg: Config, records: Record, params: Params | None = None) -> dict:
    """Reduce one run's records (stacked over time) to scalars (algorithms.md §8; seed 001 Table 1)."""
    w = cfg.warmup_steps
    T, n = records.error.shape[0], cfg.n_agents
    dtype = records.error.dtype
    alive = metrics.alive_weights(None if params is None else params.alive, n, dtype)
    after = jnp.arange(T) >= w
    in_ct = records.mode == CT
    out = {name: [] for name, per_filter, _ in SUMMARY_FIELDS if per_filter}
    per_uuv = {f"uuv{i + 1}_{s}_error": [] for i in range(n) for s in ("max", "min", "mean")}
    for f in range(len(cfg.filters)):
        e = records.error[:, f, :]
        out["rmse"].append(metrics.rmse(e, w, alive))
        out["mean_error"].append(metrics.mean_over(e, w, alive))
        out["max_error"].append(jnp.max(jnp.where(after[:, None] & (alive > 0), e, -jnp.inf)))
        out["final_error"].append(metrics.mean_over(e[-1:], 0, alive))
        out["error_cv"].append(_masked_mean(e, (after & ~in_ct)[:, None] * alive))
        out["error_ct"].append(_masked_mean(e, (after & in_ct)[:, None] * alive))
        out["anees"].append(metrics.mean_over(records.nees[:, f, :], w, alive))
        out["diverged"].append(metrics.diverged(e, cfg.divergence_threshold, w, alive))
        out["nonfinite"].append(metrics.nonfinite(e))
        for i in range(n):
            ei = e[:, i]
            per_uuv[f"uuv{i + 1}_max_error"].append(jnp.max(jnp.where(after, ei, -jnp.inf)))
            per_uuv[f"uuv{i + 1}_min_error"].append(jnp.min(jnp.where(after, ei, jnp.inf)))
            per_uuv[f"uuv{i + 1}_mean_error"].append(jnp.sum(jnp.where(after, ei, 0.0)) / jnp.sum(after))
    summary = {k: jnp.stack(v) for k, v in {**out, **per_uuv}.items()}
    lam = records.lambda2
    likelier_ct = records.mu_ct > 0.5
    summary.update(
        **metrics.graph_summary(lam),
        ct_steps=jnp.sum(in_ct),
        mode_accuracy=jnp.where(jnp.any(jnp.isnan(records.mu_ct)), jnp.nan,
                                _masked_mean((likelier_ct == in_ct[:, None]).astype(dtype), after[:, None] * alive)),
        mu_ct_during_ct=_masked_mean(records.mu_ct, (after & in_ct)[:, None] * alive),
    )
    return summary


#: Per-step series written to ``OUT/timeseries/`` when a sweep spec sets ``timeseries = true``.
TIMESERIES_FIELDS = (
    ("error_mean", True, "mean position error over alive UUVs, m"),
    ("error_max", True, "largest position error of any alive UUV, m"),
    ("mode", False, "the target's true mode (0 = CV, 1 = CT)"),
    ("mu_ct", False, "the IMM's CT probability, mean over alive UUVs (NaN without 'imm')"),
    ("lambda2", False, "algebraic connectivity of the comm graph"),
)


def timeseries(cfg: Config, records: Record, params: Params | None = None) -> dict:
    """A few per-step series of one run: (T, F) per filter, (T,) otherwise."""
    e = records.error
    alive = metrics.alive_weights(None if params is None else params.alive, cfg.n_agents, e.dtype)
    return dict(
        **metrics.error_series(e, alive),
        mode=records.mode,
        mu_ct=jnp.sum(records.mu_ct * alive, -1) / jnp.maximum(jnp.sum(alive), 1.0),
        lambda2=records.lambda2,
    )
