"""Three UAVs estimate a constant wind by consensus Kalman filtering and hold a formation on a
sine path — Chen & Lu 2013.

``n`` UAVs (the paper: 3) fly through a constant wind (40 m/s at 45°). Each step of ``dt``:

1. every UAV measures the wind, z_i = w + v_i (eq. 2; the noise v_i uniform on
   ±``noise_scale`` or Gaussian, ``Config.wind_noise``);
2. the filters (``Config.filters``) update their wind estimates over the comm graph (links
   within ``comm_radius``): ``kcf`` — the consensus Kalman filter of eqs. 6–12 (consensus on
   the priors with the weights of eq. 7, then the update, plus the formation term of eq. 12,
   :func:`mcjax.filters.consensus.prior_consensus_kcf_step`); ``local`` — each UAV's own
   Kalman filter; ``cif`` — one Kalman filter on all the measurements. The wind model of
   eq. 1 is a random walk, x⁺ = x + w_k with Q = ``sigma_wind_process``² I (the true wind is
   constant);
3. the centre Kalman filter (the paper's "main" filter: one Kalman filter on the mean of the
   measurements — the same as ``cif``) predicts where the wind carries the formation's
   centroid, P̃ = P + ŵ_c·dt; the centre's next point P̂(k+1) is the path point at distance
   ``step_length`` l ahead of P̃ (eq. 13; :mod:`.guidance`, with its approach
   rule while the path is farther than l);
4. each UAV flies the air displacement a_i = cap_l(P̂(k+1) + d_i − p_i − ŵ_i·dt) (eqs. 14–16:
   to its slot, less the drift it expects from its own wind estimate, at most l); the ground
   moves it by a_i + w·dt, so its wind error becomes a formation error. The UAVs compensate
   with their ``kcf`` estimate (the first filter's without a ``kcf``).

The formation: the slots d_i about the centroid come from the pairwise offsets ``offsets``
(rows d_12, d_23, …, then the closing d_1n; the paper's three read as sides 3200 / 2062 /
2062 m). Table 1's metrics are one UAV's (``Config.report_agent``, the paper's UAV2) mean
and largest absolute wind error per axis, before filtering (the measurement) and after.

The formation term of eq. 12 is η Σ_j w_ij (X_j − X_i − d_ij) as printed; with a UAV whose
command compensates its estimate, a larger wind estimate moves it back, so that sign pushes
a lagging UAV further back. ``formation_sign = "corrective"`` (ours, the default) enters it
with the sign that pulls the UAV towards its slot; ``"printed"`` keeps the paper's.
Units: SI (m, s, rad). Our choices where the paper is silent are marked in
``configs/chen2013.toml``.

Faults (:mod:`mcjax.scenarios.faults`, ``Config.faults = "on"``; ours, the paper has none).
A *lost link* drops that step's kcf exchange on it — the neighbour's prior, its measurement
information and eq. 12's formation term (all ride on the message; eq. 7's weights are those of
the links that carried one). A *sensor dropout* leaves the UAV without its wind measurement
that step. A *lost UAV* leaves the formation: it measures, sends and receives nothing, stops
where it is, its kcf and local filters hold, and it drops out of the others' consensus and
formation terms (it has no link) and of the error and formation statistics (pairs with it). The
others keep their slots d_i — the lost UAV's slot stays empty — and place the formation's
centre from their own positions, c = mean over them of (p_i − d_i) (with all alive, the
centroid): the survivors' pairwise offsets d_ij, which eq. 12 and the formation statistics are
about, stay as they were, losing a UAV makes no one manoeuvre, and the path is still flown by
the formation's centre; re-assigning slots would need a rule the paper does not give. The
``cif`` and the centre filter are the centralised references: they fuse every measurement
taken (none from a dropped-out or lost sensor) and see no link loss. The report agent's
per-axis wind errors stay its own after a loss (its held estimate); its measurement errors run
over the steps it had a measurement.
"""

from __future__ import annotations

from functools import cache
from itertools import combinations
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mcjax import graph, metrics
from mcjax.contract import FAST_COMPILE, Output, Param, Scenario, Setting, config_type, declare, params_type
from mcjax.filters.consensus import (
    WEIGHT_KINDS,
    FilterOptions,
    Measurements,
    cif_step,
    local_step,
    prior_consensus_kcf_step,
)
from mcjax.filters.gaussian import Gaussian, first_step_model
from mcjax.numerics import spd_inverse, symmetrize
from mcjax.scenarios import faults, kit
from mcjax.scenarios.wind_formation import guidance
from mcjax.scenarios.wind_formation.smoothing import (
    ROUGH, Smoothing, smooth_cap, smooth_next_centre, soft_capped, training_errors, training_weights,
)
from mcjax.smoothing import Smooth

NAME = "wind_formation"
FILTER_KINDS = ("kcf", "local", "cif")
NOISES = ("uniform", "gaussian")
FORMATION_SIGNS = ("corrective", "printed")
#: Closing tolerance of the offsets (m): the last row must equal the sum of the chain.
CLOSURE_TOL = 1e-6
#: An air step counts as capped (eq. 15) when the wanted one is longer than l by this fraction:
#: on the path the centre's wanted step is l itself, up to rounding.
CAP_TOL = 1e-9


def _check(cfg) -> None:
    kit.check_common(cfg)
    if cfg.n_agents < 2:
        raise ValueError(f"n_agents must be an integer >= 2 (a formation); got {cfg.n_agents}")
    if cfg.report_agent > cfg.n_agents:
        raise ValueError(f"report_agent must be an integer in [1, n_agents = {cfg.n_agents}]; "
                         f"got {cfg.report_agent}")


Config = config_type("Config", dict(
    **kit.common_settings(filter_kinds=FILTER_KINDS, n_agents=3, n_steps=100, min_steps=2, warmup_steps=0,
                          divergence_threshold=20.0, error_unit="m/s"),
    wind_noise=Setting("uniform", "wind measurement noise: uniform on [-noise_scale, noise_scale] or "
                       "gaussian with std noise_scale (ours)", choices=NOISES),
    weights=Setting("max_degree", "consensus weights of the kcf: max_degree = Chen & Lu 2013 eq. 7",
                    choices=WEIGHT_KINDS),
    formation_sign=Setting("corrective", "sign of eq. 12's formation term: corrective (ours: pulls a UAV "
                           "towards its slot) or printed", choices=FORMATION_SIGNS),
    report_agent=Setting(2, "the UAV (1-based) whose per-axis wind errors are reported (paper: UAV2)",
                         low=1, integer=True),
    root_grid=Setting(128, "grid cells that bracket eq. 13's roots before bisection (ours)", low=2,
                      integer=True),
    **faults.SETTINGS,
), __name__, _check)

#: The paper's starting positions of its three UAVs (m).
PAPER_START = np.array([[10000.0, 7000.0], [10000.0, 12000.0], [12000.0, 9000.0]])
#: The paper's reference vectors as the chain d_12, d_23 and the closing d_13 (configs/chen2013.toml).
PAPER_OFFSETS = np.array([[0.0, 3200.0], [1300.0, -1600.0], [1300.0, 1600.0]])


def _default_start(cfg):
    if cfg.n_agents == 3:
        return PAPER_START.copy()
    return np.stack([np.full(cfg.n_agents, 10000.0), 7000.0 + 2500.0 * np.arange(cfg.n_agents)], axis=1)


def _default_offsets(cfg):
    if cfg.n_agents == 3:
        return PAPER_OFFSETS.copy()
    n = cfg.n_agents
    chain = np.tile([[0.0, 1000.0]], (n, 1))
    chain[-1] = [0.0, 1000.0 * (n - 1)]
    return chain


_POS = dict(low=0.0, low_open=True)
Params = params_type("Params", dict(
    dt=Param(10.0, "s", "measurement and guidance interval (paper: 10 s)", **_POS),
    step_length=Param(1000.0, "m", "l: the look-ahead of eq. 13 and the longest air step of eq. 15 "
                      "(paper: V dt = 1000 m)", **_POS),
    wind_speed=Param(40.0, "m/s", "the constant wind's speed (paper)", low=0.0),
    wind_direction=Param(np.pi / 4, "rad", "the wind's direction from the x axis (paper: 45 deg)"),
    noise_scale=Param(10.0, "m/s", "wind measurement noise: the uniform bound or the Gaussian std (ours)", **_POS),
    sigma_wind_process=Param(0.5, "m/s", "the filters' random-walk wind model, std per step (ours)", **_POS),
    sigma_wind_prior=Param(50.0, "m/s", "the filters' prior std about zero wind (ours)", **_POS),
    eta=Param(0.01, "1/s", "formation factor eta of eq. 12 (ours)", low=0.0),
    comm_radius=Param(1.0e5, "m", "UAVs within this distance exchange estimates (ours: complete graph)", **_POS,
                      display="km"),
    path_amplitude=Param(2000.0 / 3.0, "m", "path y = amplitude sin(x / scale) (paper: 2000/3)"),
    path_scale=Param(1200.0, "m", "path y = amplitude sin(x / scale) (paper: 1200)", **_POS),
    formation_tolerance=Param(50.0, "m", "pairwise distances count as in formation within this of the "
                              "reference (ours)", **_POS),
    start=Param(_default_start, "m", "starting positions (paper: (10000, 7000), (10000, 12000), (12000, 9000))",
                shape=("n", 2)),
    offsets=Param(_default_offsets, "m", "pairwise formation offsets d_ij = p_j - p_i: rows d_12, d_23, ..., "
                  "then the closing d_1n (= their sum)", shape=("n", 2)),
    **faults.PARAMS,
), __name__)


def check_params(cfg, values: dict) -> list[tuple[str, str]]:
    offsets = kit.param_value(Params, cfg, values, "offsets")
    bad = []
    if offsets.shape[-2:] == (cfg.n_agents, 2):   # one formation, or one per sweep point
        gaps = np.linalg.norm(np.sum(offsets[..., : cfg.n_agents - 1, :], axis=-2) - offsets[..., -1, :], axis=-1)
        if np.any(gaps > CLOSURE_TOL * (1.0 + np.max(np.abs(offsets)))):
            bad.append(("offsets", f"pairwise offsets that close: the last row d_1n must equal the sum of the "
                        f"rows d_12 ... d_(n-1)n (they are {float(np.max(gaps)):g} m apart)"))
    return bad + faults.check(cfg, values, Params)


class State(NamedTuple):
    t: jax.Array
    positions: jax.Array    # (n, 2) ground positions
    filters: tuple          # one Gaussian per filter (cif: single, else a UAV axis first)
    centre: Gaussian        # the centre Kalman filter's wind estimate
    faults: faults.State | None  # lost links and UAVs (mcjax.scenarios.faults; None: off)


class Record(NamedTuple):
    error: jax.Array         # (F, n) |wind estimate - wind| per filter and UAV
    axis_error: jax.Array    # (F, 2) |estimate - wind| per axis, report agent
    raw_error: jax.Array     # (2,) |measurement - wind| per axis, report agent (NaN: no measurement, faults)
    distances: jax.Array     # (pairs,) pairwise distances after the step
    path_error: jax.Array    # () |Y - psi(X)| of the centroid after the step
    on_path: jax.Array       # () eq. 13 had a forward root (smoothing: a weight in [0, 1])
    capped: jax.Array        # () some UAV's air step was capped at l (smoothing: a weight in [0, 1])
    air_max: jax.Array       # () longest air step
    lambda2: jax.Array       # () algebraic connectivity of the links that carried a message
    positions: jax.Array     # (n, 2) after the step
    faults: faults.Record | None  # the step's faults (None: off)


def pairs(n: int) -> list[tuple[int, int]]:
    """The UAV pairs (i, j), i < j, 0-based, in the order of the distance outputs."""
    return list(combinations(range(n), 2))


def wind(params, dtype):
    """The true wind vector (constant; Chen & Lu 2013 §3)."""
    p = kit.cast(params, dtype)
    return p.wind_speed * jnp.stack([jnp.cos(p.wind_direction), jnp.sin(p.wind_direction)])


def reference_distances(cfg, offsets):
    """The formation's pairwise distances |d_ij| from the ``offsets`` Param, in the order of
    :func:`pairs` (jittable)."""
    d = guidance.centre_offsets(jnp.asarray(offsets))
    ij = np.array(pairs(cfg.n_agents))
    return jnp.linalg.norm(d[ij[:, 1]] - d[ij[:, 0]], axis=-1)


def noise_variance(cfg, p):
    """The variance of one axis of the measurement noise (uniform ±a: a²/3; Gaussian: σ²)."""
    return p.noise_scale ** 2 / 3.0 if cfg.wind_noise == "uniform" else p.noise_scale ** 2


def init(cfg, params, key) -> State:
    """The UAVs at ``start``; every filter at zero wind with covariance ``sigma_wind_prior``² I;
    no fault yet."""
    dtype = jnp.dtype(cfg.dtype)
    p = kit.cast(params, dtype)
    n = cfg.n_agents
    P0 = jnp.eye(2, dtype=dtype) * p.sigma_wind_prior ** 2
    g = Gaussian(kit.per_run(p.dt, jnp.zeros(2, dtype)), P0, symmetrize(spd_inverse(P0)))  # per-run: kit.per_run
    per_agent = jax.tree.map(lambda a: jnp.broadcast_to(a, (n,) + a.shape), g)
    filters = tuple(g if k == "cif" else per_agent for k in cfg.filters)
    return State(jnp.asarray(0, jnp.int32), p.start, filters, g, faults.init(cfg, key, p))


def _identity(x, sensor):
    del sensor
    return x


def _per_agent(kind, g: Gaussian, n):
    return jax.tree.map(lambda a: jnp.broadcast_to(a, (n,) + a.shape), g) if kind == "cif" else g


def formation_term(cfg, p, positions, offsets):
    """Eq. 12's formation term per pair, ``η (X_j − X_i − d_ij)`` at [i, j] (n, n, 2) per axis,
    with d_ij = d_j − d_i; negated when ``formation_sign = "corrective"`` (module docstring)."""
    rel = positions[None, :, :] - positions[:, None, :]
    want = offsets[None, :, :] - offsets[:, None, :]
    sign = -1.0 if cfg.formation_sign == "corrective" else 1.0
    return sign * p.eta * (rel - want)


def formation_centre(positions, offsets, alive):
    """The formation's centre as the UAVs ``alive`` (n,) bool hold it: the mean of p_i − d_i
    over them, where d_i is UAV i's slot about the centre (:func:`guidance.centre_offsets`; with
    every UAV alive it is the centroid of eqs. 13–14, since Σ d_i = 0). A lost UAV's slot stays
    empty: the others keep theirs (module docstring, "Faults")."""
    a = alive.astype(positions.dtype)[:, None]
    return jnp.sum(a * (positions - offsets), axis=0) / jnp.maximum(jnp.sum(a), 1.0)


def step(cfg, params, state: State, key, smoothing: Smoothing | None = None) -> tuple[State, Record]:
    """One step of ``dt`` (module docstring): measure (eq. 2), filter (eqs. 6–12), correct the
    path (eqs. 13–16), fly through the true wind. ``smoothing`` (:class:`Smoothing`; None: the
    exact simulation) makes the comm links, eq. 13's path point and eq. 15's cap smooth with the
    same draws (:mod:`.smoothing`); ``on_path`` and ``capped`` are then weights in [0, 1].

    Faults (``Config.faults = "on"``, module docstring "Faults"): a dropped-out or lost UAV's
    measurement is missing (every filter and the centre filter go without it); a lost link
    drops the kcf's exchange on it (the neighbour's prior, measurement information and eq. 12's
    formation term); a lost UAV stops where it is, its filter states hold, and the others
    place the formation's centre from their own slots (:func:`formation_centre`)."""
    dtype = jnp.dtype(cfg.dtype)
    p = kit.cast(params, dtype)
    n = cfg.n_agents
    w = wind(params, dtype)
    offsets = guidance.centre_offsets(p.offsets)
    switched_on = jnp.ones(n, bool)
    fault_state, fault = faults.advance(key, state.faults, p, switched_on)

    # 1. measurements (NaN where a sensor dropped out or its UAV is lost: faults)
    if cfg.wind_noise == "uniform":
        noise = p.noise_scale * jax.random.uniform(key, (n, 2), dtype, -1.0, 1.0)
    else:
        noise = p.noise_scale * jax.random.normal(key, (n, 2), dtype)
    z = faults.measurements(w[None, :] + noise, fault)

    # 2. the filters over the links that carry a message (step 0 updates the prior without predicting)
    if smoothing is None:
        adj = graph.adjacency(state.positions, p.comm_radius)
    else:
        adj = graph.soft_adjacency(state.positions, p.comm_radius, smoothing.comm)
    carried = faults.messages(adj, fault)
    R_inv = jnp.broadcast_to(jnp.eye(2, dtype=dtype) / noise_variance(cfg, p), (n, 2, 2))
    meas = Measurements(z, state.positions, carried, R_inv)
    F, Q = first_step_model(state.t == 0, jnp.eye(2, dtype=dtype), jnp.eye(2, dtype=dtype) * p.sigma_wind_process ** 2)
    no_angle = jnp.array([False, False])
    opts = FilterOptions(weights=cfg.weights, kcf_gain="prior_consensus")
    filters = []
    for kind, post in zip(cfg.filters, state.filters):
        if kind == "kcf":
            filters.append(prior_consensus_kcf_step(_identity, no_angle, opts, faults.shield(fault, post), meas, F, Q,
                                                    formation_term(cfg, p, state.positions, offsets)))
        elif kind == "local":
            filters.append(local_step(_identity, no_angle, faults.shield(fault, post), meas, F, Q))
        else:
            filters.append(cif_step(_identity, no_angle, post, meas, F, Q))
    filters = tuple(f if k == "cif" else faults.hold(fault, f, old)
                    for k, f, old in zip(cfg.filters, filters, state.filters))
    centre = cif_step(_identity, no_angle, state.centre, meas, F, Q)
    estimates = [_per_agent(k, f, n).x for k, f in zip(cfg.filters, filters)]

    # 3.–4. path correction and flight
    psi = guidance.sine_path(p.path_amplitude, p.path_scale)
    if fault is None:
        here = jnp.mean(state.positions, axis=0)
    else:
        here = formation_centre(state.positions, offsets, fault.alive)
    predicted = here + centre.x * p.dt
    if smoothing is None:
        nxt = guidance.next_centre(psi, predicted, p.step_length, cfg.root_grid)
    else:
        nxt = smooth_next_centre(psi, predicted, p.step_length, cfg.root_grid, smoothing.path)
    steer = estimates[cfg.filters.index("kcf") if "kcf" in cfg.filters else 0]
    wanted = guidance.wanted_steps(nxt.point, offsets, state.positions, steer, p.dt)
    if smoothing is None:
        air = guidance.cap_step(wanted, p.step_length)                               # eq. 15
    else:
        air = smooth_cap(wanted, p.step_length, smoothing.cap)
    positions = state.positions + air + w[None, :] * p.dt
    if fault is None:
        centroid = jnp.mean(positions, axis=0)
    else:  # a lost UAV stops where it is
        flying = fault.alive[:, None]
        wanted, air = jnp.where(flying, wanted, 0.0), jnp.where(flying, air, 0.0)
        positions = jnp.where(flying, positions, state.positions)
        centroid = formation_centre(positions, offsets, fault.alive)

    a = cfg.report_agent - 1
    ij = np.array(pairs(n))
    rec = Record(
        error=jnp.stack([jnp.linalg.norm(e - w, axis=-1) for e in estimates]),
        axis_error=jnp.stack([jnp.abs(e[a] - w) for e in estimates]),
        raw_error=jnp.abs(z[a] - w),
        distances=jnp.linalg.norm(positions[ij[:, 1]] - positions[ij[:, 0]], axis=-1),
        path_error=jnp.abs(centroid[1] - psi(centroid[0])),
        on_path=nxt.on_path,
        capped=(jnp.any(jnp.linalg.norm(wanted, axis=-1) > p.step_length * (1.0 + CAP_TOL)) if smoothing is None
                else soft_capped(wanted, p.step_length, smoothing.cap, CAP_TOL)),
        air_max=jnp.max(jnp.linalg.norm(air, axis=-1)),
        lambda2=graph.algebraic_connectivity(carried),
        positions=positions,
        faults=faults.record(adj, carried, fault, switched_on))
    return State(state.t + 1, positions, filters, centre, fault_state), rec


def _first(mask, dtype):
    """Index of the first True of ``mask`` (T,), as a float; NaN if none."""
    return jnp.where(jnp.any(mask), jnp.argmax(mask).astype(dtype), jnp.nan)


def _axis_errors(cfg, records: Record) -> dict:
    """Table 1's per-axis errors of the report agent after warm-up: the mean and largest
    |estimate − wind| per filter (F,) and |measurement − wind| (a scalar), along x and y. With
    faults on, the measurement's over the steps it had one (NaN if none); the estimate's over
    every step (a named agent's own error: kit's rule; a lost agent's estimate holds)."""
    dtype = records.error.dtype
    after = (jnp.arange(records.error.shape[0]) >= cfg.warmup_steps).astype(dtype)
    count = jnp.sum(after)
    raw, raw_after, raw_count = records.raw_error, after, count
    if faults.on(cfg):
        measured = jnp.all(jnp.isfinite(raw), axis=-1)
        raw, raw_after = jnp.where(measured[:, None], raw, 0.0), after * measured
        raw_count = jnp.where(jnp.sum(raw_after) > 0, jnp.sum(raw_after), jnp.nan)
    out = {}
    for k, ax in enumerate(("x", "y")):
        out[f"wind_mean_{ax}"] = jnp.sum(records.axis_error[:, :, k] * after[:, None], axis=0) / count
        out[f"wind_max_{ax}"] = metrics.nan_max(jnp.where(after[:, None] > 0, records.axis_error[:, :, k], -jnp.inf),
                                                axis=0)
        out[f"raw_mean_{ax}"] = jnp.sum(raw[:, k] * raw_after) / raw_count
        out[f"raw_max_{ax}"] = metrics.nan_max(jnp.where(raw_after > 0, raw[:, k], -jnp.inf))
        if faults.on(cfg):
            out[f"raw_max_{ax}"] = jnp.where(jnp.isnan(raw_count), jnp.nan, out[f"raw_max_{ax}"])
    return out


def _formation(cfg, records: Record, params) -> dict:
    """The formation and path statistics of one run (the values of :func:`summary`'s
    ``settle_step`` … ``path_error_max`` and their intermediates)."""
    dtype = records.error.dtype
    T = records.error.shape[0]
    steps = jnp.arange(T)
    ref = reference_distances(cfg, jnp.asarray(params.offsets, dtype))
    gap = jnp.abs(records.distances - ref[None, :])
    if records.faults is not None:  # pairs with a lost UAV leave the formation statistics
        ij = np.array(pairs(cfg.n_agents))
        gap = jnp.where(records.faults.alive[:, ij[:, 0]] & records.faults.alive[:, ij[:, 1]], gap, 0.0)
    dev = jnp.max(gap, axis=1)                                                       # (T,)
    inside = dev <= jnp.asarray(params.formation_tolerance, dtype)
    holds = jnp.flip(jnp.cumprod(jnp.flip(inside).astype(jnp.int32))) > 0           # inside from here to the end
    if records.on_path.dtype == jnp.bool_:
        joined = _first(records.on_path, dtype)
    else:  # the smoothing switch's weights: the steps before the first join, Σ_t Π_{s≤t} (1 − on_path_s)
        joined = jnp.sum(jnp.cumprod(1.0 - records.on_path))
    after_join = (steps >= jnp.nan_to_num(joined, nan=T)) & jnp.isfinite(joined)
    return dict(dev=dev, holds=holds, settle=_first(holds, dtype), joined=joined, after_join=after_join)


def summary(cfg, records: Record | None, params) -> dict:
    """One run's records (stacked over time) reduced to its outputs, each declared next to its
    value (:func:`mcjax.contract.declare`; ``records`` None: the declarations alone)."""
    r = records
    axes = cache(lambda: _axis_errors(cfg, r))
    fm = cache(lambda: _formation(cfg, r, params))
    switched_on = cache(lambda: jnp.ones(cfg.n_agents, r.error.dtype))
    alive = cache(lambda: faults.weights(switched_on(), r.faults))

    def axis_items(prefix: str, what: str, per_filter: bool) -> dict:
        def pick(name):
            return lambda: axes()[name]
        return {f"{prefix}_{stat}_{ax}": (Output("m/s", f"{'mean' if stat == 'mean' else 'largest'} |{what} - wind| "
                                                 f"along {ax}, report_agent, after warm-up (Table 1)", per_filter),
                                          pick(f"{prefix}_{stat}_{ax}"))
                for ax in ("x", "y") for stat in ("mean", "max")}

    pe = cache(lambda: r.path_error)
    return declare(
        **kit.error_items(lambda: r.error, alive, cfg, "m/s", "wind estimate error"),
        **axis_items("wind", "estimate", True),
        **axis_items("raw", "measurement", False),
        **kit.graph_items(lambda: r.lambda2),
        settle_step=(Output("steps", "steps flown until every pairwise distance stays within formation_tolerance "
                            "of the reference to the end (NaN: never)", False), lambda: fm()["settle"] + 1.0),
        formation_error_max=(Output("m", "largest |distance - reference| over pairs after settling", False),
                             lambda: jnp.where(jnp.any(fm()["holds"]),
                                               metrics.nan_max(jnp.where(fm()["holds"], fm()["dev"], -jnp.inf)),
                                               jnp.nan)),
        formation_error_final=(Output("m", "largest |distance - reference| over pairs at the end", False),
                               lambda: fm()["dev"][-1]),
        join_step=(Output("steps", "steps flown until eq. 13 first had a forward root (the path within l)", False),
                   lambda: fm()["joined"] + 1.0),
        path_error_mean=(Output("m", "mean |Y - psi(X)| of the centroid after join_step", False),
                         lambda: jnp.sum(jnp.where(fm()["after_join"], pe(), 0.0)) / jnp.sum(fm()["after_join"])),
        path_error_max=(Output("m", "largest |Y - psi(X)| of the centroid after join_step", False),
                        lambda: metrics.nan_max(jnp.where(fm()["after_join"], pe(), -jnp.inf))),
        approach_steps=(Output("steps", "steps on the approach rule (eq. 13 had no forward root)", False),
                        lambda: jnp.sum(~r.on_path) if r.on_path.dtype == jnp.bool_ else jnp.sum(1.0 - r.on_path)),
        capped_steps=(Output("steps", "steps where some UAV's air step was capped at l (eq. 15)", False),
                      lambda: jnp.sum(r.capped)),
        max_air_step=(Output("m", "longest air step of any UAV (eq. 15: at most step_length)", False),
                      lambda: metrics.nan_max(r.air_max)),
        **faults.summary_items(cfg, r and r.faults, switched_on),
    )


def series(cfg, records: Record | None, params) -> dict:
    """Per-step series of one run, each declared next to its value: errors, per-axis errors,
    the centroid's path error, λ2, every pairwise distance and every UAV's position."""
    r = records
    switched_on = cache(lambda: jnp.ones(cfg.n_agents, r.error.dtype))
    alive = cache(lambda: faults.weights(switched_on(), r.faults))
    items = dict(
        **kit.error_series_items(lambda: r.error, alive, "m/s", "wind estimate error"),
        wind_error_x=(Output("m/s", "|estimate - wind| along x, report_agent"), lambda: r.axis_error[:, :, 0]),
        wind_error_y=(Output("m/s", "|estimate - wind| along y, report_agent"), lambda: r.axis_error[:, :, 1]),
        raw_error_x=(Output("m/s", "|measurement - wind| along x, report_agent", False), lambda: r.raw_error[:, 0]),
        raw_error_y=(Output("m/s", "|measurement - wind| along y, report_agent", False), lambda: r.raw_error[:, 1]),
        path_error=(Output("m", "|Y - psi(X)| of the centroid", False), lambda: r.path_error),
        lambda2=(Output("", "algebraic connectivity of the comm graph", False), lambda: r.lambda2),
        **faults.series_items(cfg, r and r.faults, switched_on),
    )
    for k, (i, j) in enumerate(pairs(cfg.n_agents)):
        items[f"distance_{i + 1}_{j + 1}"] = (Output("m", f"distance between UAV{i + 1} and UAV{j + 1}", False),
                                              lambda k=k: r.distances[:, k])
    for i in range(cfg.n_agents):
        items[f"x_{i + 1}"] = (Output("m", f"UAV{i + 1}'s x after the step", False), lambda i=i: r.positions[:, i, 0])
        items[f"y_{i + 1}"] = (Output("m", f"UAV{i + 1}'s y after the step", False), lambda i=i: r.positions[:, i, 1])
    return declare(**items)


SCENARIO = Scenario(
    name=NAME, title="Chen & Lu 2013: three UAVs estimate the wind by consensus Kalman filtering and hold a "
    "formation on a sine path", Config=Config, Params=Params, init=init, step=step, summary=summary,
    series=series, check_params=check_params, smooth=Smooth(Smoothing, training_errors, training_weights, ROUGH),
    compiler_options=FAST_COMPILE,
    filter_words={
        "kcf": "Chen & Lu 2013's consensus Kalman filter: each UAV fuses its neighbours' wind measurements and "
               "moves towards their estimates",
        "local": "each UAV's own Kalman filter on its own wind measurements, nothing shared",
        "cif": "one Kalman filter on every UAV's measurements (the centralised reference)"})
default_params = SCENARIO.default_params
#: The record's derived functions (from :func:`summary` and :func:`series`), by their usual names.
reduce, outputs = SCENARIO.reduce, SCENARIO.outputs
timeseries, timeseries_outputs = SCENARIO.timeseries, SCENARIO.timeseries_outputs
