"""Chen & Lu 2013's wind and formation scenario, one step: the UAVs measure the wind, the filters
update over the links that carried a message, the centre's path correction (eqs. 13–16), the flight
through the wind; the state, the record and what both the step and the outputs use.

The bound (``Config.bound = "on"``; :mod:`mcjax.scenarios.kit.bound`, Tichavský, Muravchik &
Nehorai 1998). The tracked quantity is the wind, and the truth is a constant wind: its dynamics
are ``F = I``, ``Q = 0`` (the recursion's ``(Q + F J⁻¹ Fᵀ)⁻¹`` form allows a zero Q; the filters'
random walk, ``sigma_wind_process``, is their model, not the truth's). ``J0`` is the inverse of
the filters' prior covariance, ``sigma_wind_prior² I``: the filters' prior read as the wind's
distribution. Each step adds ``I / σ²`` (σ = ``noise_scale``) per UAV whose measurement was taken
(alive, no dropout), so ``J_k = J0 + (measurements taken up to step k) · I / σ²``: the team bound
(every UAV's measurements, the floor of any filter, ``cif`` included) and each UAV's own one (the
floor of its ``local`` filter). The bound's variance is the trace of ``J⁻¹`` over the wind's two
components, in (m/s)², the square of the recorded error ``|ŵ − w|``. The bound needs
``wind_noise = "gaussian"``: a uniform noise has no Fisher information (its density's support
moves with the wind, so the Cramér–Rao regularity conditions fail, and an estimator such as the
mid-range beats any 1/N-type bound); the Config check refuses ``bound = "on"`` with it.

Consistency (``Config.consistency = "on"``; :mod:`mcjax.scenarios.kit.consistency`): each filter's
and UAV's NEES of its 2-D wind estimate against the true wind, and the NIS of each UAV's own
measurement against its own prediction (the filter's state before this step's update, predicted
by the filters' random walk; the ``cif``'s one state repeated for every UAV). Both are χ² with 2
degrees of freedom for a consistent filter under Gaussian noise; with ``wind_noise = "uniform"``
they are still defined (the filters take the noise's variance ``noise_scale²/3`` as R) but only
approximately χ²."""

from __future__ import annotations

from itertools import combinations
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mcjax.scenarios import kit
from mcjax.scenarios.chen2013 import guidance
from mcjax.scenarios.chen2013.params import CAP_TOL
from mcjax.scenarios.chen2013.relaxation import Temperatures, smooth_cap, smooth_next_centre, soft_capped
from mcjax.scenarios.kit import bound as pcrb
from mcjax.scenarios.kit import consistency
from mcjax.scenarios.kit import faults
from mcjax.tracking import graph, metrics
from mcjax.tracking.filters.consensus import FilterOptions, Measurements, cif_step
from mcjax.tracking.filters.gaussian import Gaussian, first_step_model
from mcjax.tracking.filters.steps import centralised, filter_step, per_agent
from mcjax.tracking.numerics import spd_inverse, symmetrize


class State(NamedTuple):
    t: jax.Array
    positions: jax.Array    # (n, 2) ground positions
    filters: tuple          # one Gaussian per filter (cif: single, else a UAV axis first)
    centre: Gaussian        # the centre Kalman filter's wind estimate
    faults: faults.State | None  # lost links and UAVs (mcjax.scenarios.kit.faults; None: off)
    bound: pcrb.Bound | None = None  # the PCRB's covariance of the wind, team and per UAV (None: off)


class Record(NamedTuple):
    error: jax.Array         # (F, n) |wind estimate - wind| per filter and UAV
    axis_error: jax.Array    # (F, 2) |estimate - wind| per axis, report agent
    raw_error: jax.Array     # (2,) |measurement - wind| per axis, report agent (NaN: no measurement, faults)
    distances: jax.Array     # (pairs,) pairwise distances after the step
    path_error: jax.Array    # () |Y - psi(X)| of the centroid after the step
    on_path: jax.Array       # () eq. 13 had a forward root (temperatures: a weight in [0, 1])
    capped: jax.Array        # () some UAV's air step was capped at l (temperatures: a weight in [0, 1])
    air_max: jax.Array       # () longest air step
    lambda2: jax.Array       # () algebraic connectivity of the links that carried a message
    positions: jax.Array     # (n, 2) after the step
    faults: faults.Record | None  # the step's faults (None: off)
    bound: pcrb.Bound | None = None  # the PCRB's wind variances, team () and per UAV (n,), (m/s)² (None: off)
    nees: jax.Array | None = None  # (F, n) NEES of each wind estimate (None: consistency off)
    nis: jax.Array | None = None   # (F, n) NIS of each UAV's own measurement, NaN without one (None: off)


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
    dtype, p = kit.typed(cfg, params)
    n = cfg.n_agents
    P0 = jnp.eye(2, dtype=dtype) * p.sigma_wind_prior ** 2
    g = Gaussian(kit.per_run(p.dt, jnp.zeros(2, dtype)), P0, symmetrize(spd_inverse(P0)))  # per-run: kit.per_run
    every = jax.tree.map(lambda a: jnp.broadcast_to(a, (n,) + a.shape), g)
    filters = tuple(g if centralised(k) else every for k in cfg.filters)
    return State(jnp.asarray(0, jnp.int32), p.start, filters, g, faults.init(cfg, key, p), pcrb.initial(cfg, P0))


def _identity(x, sensor):
    del sensor
    return x


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


def step(cfg, params, state: State, key, temperatures: Temperatures | None = None) -> tuple[State, Record]:
    """One step of ``dt`` (module docstring): measure (eq. 2), filter (eqs. 6–12), correct the
    path (eqs. 13–16), fly through the true wind. ``temperatures`` (:class:`Temperatures`; None: the
    exact simulation) makes the comm links, eq. 13's path point and eq. 15's cap smooth with the
    same draws (:mod:`.relaxation`); ``on_path`` and ``capped`` are then weights in [0, 1].

    Faults (``Config.faults = "on"``, module docstring "Faults"): a dropped-out or lost UAV's
    measurement is missing (every filter and the centre filter go without it); a lost link
    drops the kcf's exchange on it (the neighbour's prior, measurement information and eq. 12's
    formation term); a lost UAV stops where it is, its filter states hold, and the others
    place the formation's centre from their own slots (:func:`formation_centre`)."""
    dtype, p = kit.typed(cfg, params)
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
    adj, carried = kit.link(state.positions, p.comm_radius, fault, temperatures)
    R_inv = jnp.broadcast_to(jnp.eye(2, dtype=dtype) / noise_variance(cfg, p), (n, 2, 2))
    meas = Measurements(z, state.positions, carried, R_inv)
    F, Q = first_step_model(state.t == 0, jnp.eye(2, dtype=dtype), jnp.eye(2, dtype=dtype) * p.sigma_wind_process ** 2)
    no_angle = jnp.array([False, False])
    nis = None if cfg.consistency != "on" else jnp.stack([  # each UAV's own measurement against its prediction
        consistency.predicted_nis(per_agent(k, f, n), F, Q, _identity, state.positions, z, R_inv, no_angle)
        for k, f in zip(cfg.filters, state.filters)])
    opts = FilterOptions(weights=cfg.weights, kcf_gain="prior_consensus")
    filters = filter_step(cfg.filters, opts, _identity, no_angle, kit.shield_filters(fault, cfg.filters, state.filters),
                          meas, F, Q, None, formation_term(cfg, p, state.positions, offsets))
    filters = kit.hold_filters(fault, cfg.filters, filters, state.filters)
    centre = cif_step(_identity, no_angle, state.centre, meas, F, Q)
    post = [per_agent(k, f, n) for k, f in zip(cfg.filters, filters)]
    estimates = [g.x for g in post]
    # the bound (bound = "on"; module docstring): a constant wind, F = I, Q = 0, I/σ² per measurement taken
    eye = jnp.eye(2, dtype=dtype)
    bound = pcrb.update(state.bound, eye, jnp.zeros_like(eye), _identity, w, state.positions, z, R_inv)

    # 3.–4. path correction and flight
    psi = guidance.sine_path(p.path_amplitude, p.path_scale)
    if fault is None:
        here = jnp.mean(state.positions, axis=0)
    else:
        here = formation_centre(state.positions, offsets, fault.alive)
    predicted = here + centre.x * p.dt
    if temperatures is None:
        nxt = guidance.next_centre(psi, predicted, p.step_length, cfg.root_grid)
    else:
        nxt = smooth_next_centre(psi, predicted, p.step_length, cfg.root_grid, temperatures.path)
    steer = estimates[cfg.filters.index("kcf") if "kcf" in cfg.filters else 0]
    wanted = guidance.wanted_steps(nxt.point, offsets, state.positions, steer, p.dt)
    if temperatures is None:
        air = guidance.cap_step(wanted, p.step_length)                               # eq. 15
    else:
        air = smooth_cap(wanted, p.step_length, temperatures.cap)
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
        capped=(jnp.any(jnp.linalg.norm(wanted, axis=-1) > p.step_length * (1.0 + CAP_TOL)) if temperatures is None
                else soft_capped(wanted, p.step_length, temperatures.cap, CAP_TOL)),
        air_max=jnp.max(jnp.linalg.norm(air, axis=-1)),
        lambda2=graph.algebraic_connectivity(carried),
        positions=positions,
        faults=faults.record(adj, carried, fault, switched_on),
        bound=pcrb.position_variance(bound, (0, 1)),
        nees=None if cfg.consistency != "on" else jnp.stack([metrics.nees(g.x, g.Y, w) for g in post]),
        nis=nis)
    return State(state.t + 1, positions, filters, centre, fault_state, bound), rec

