"""Three UAVs estimate a constant wind by consensus Kalman filtering and hold a formation on a
sine path — Chen & Lu 2013.

``n`` UAVs (the paper: 3) fly through a constant wind (40 m/s at 45°). Each step of ``dt``:

1. every UAV measures the wind, z_i = w + v_i (eq. 2; the noise v_i uniform on
   ±``noise_scale`` or Gaussian, ``Config.wind_noise``);
2. the filters (``Config.filters``) update their wind estimates over the comm graph (links
   within ``comm_radius``): ``kcf`` — the consensus Kalman filter of eqs. 6–12 (consensus on
   the priors with the weights of eq. 7, then the update, plus the formation term of eq. 12,
   :func:`mcjax.tracking.filters.consensus.prior_consensus_kcf_step`); ``local`` — each UAV's own
   Kalman filter; ``cif`` — one Kalman filter on all the measurements; opt-in, the robust
   consensus filters ``ci`` and ``hcmci`` (:mod:`mcjax.tracking.filters.robust_consensus`, one consensus
   step per step, Metropolis weights of the links that carried a message). The wind model of
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

Faults (:mod:`mcjax.scenarios.kit.faults`, ``Config.faults = "on"``; ours, the paper has none).
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

The bound (``Config.bound = "on"``, ours; :mod:`.step`): the posterior Cramér–Rao bound of the
wind's error, ``pcrb_rmse`` (every UAV's measurements: the floor of any filter, the ``cif``
included) and ``pcrb_local_rmse`` (each UAV's own: the floor of its ``local`` filter), in m/s.
The truth is a constant wind (F = I, Q = 0), the prior the filters' (``sigma_wind_prior``² I),
and each measurement taken adds I/``noise_scale``²: J_k = J_0 + (measurements so far)·I/σ². It
needs ``wind_noise = "gaussian"`` (a uniform noise has no Fisher information: the density's
support moves with the wind, and the mid-range beats any 1/N-type bound), and the Config check
refuses ``bound = "on"`` with ``"uniform"``. Consistency (``Config.consistency = "on"``, ours):
``anees`` and ``anis`` (2 dof) and their per-step series; under a uniform noise they are still
computed but only approximately χ².
"""

from __future__ import annotations

from functools import cache

import jax.numpy as jnp
import numpy as np

from mcjax.contract import FAST_COMPILE, Output, Scenario, declare
from mcjax.contract.relaxation import Relaxation
from mcjax.scenarios import kit
from mcjax.scenarios.chen2013.params import Config, NAME, Params, check_params
from mcjax.scenarios.chen2013.relaxation import ROUGH, Temperatures, training_errors, training_weights
from mcjax.scenarios.chen2013.step import Record, init, pairs, reference_distances, step
from mcjax.scenarios.kit import bound as pcrb
from mcjax.scenarios.kit import consistency
from mcjax.scenarios.kit import faults
from mcjax.tracking import metrics


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
    else:  # the relaxation switch's weights: the steps before the first join, Σ_t Π_{s≤t} (1 − on_path_s)
        joined = jnp.sum(jnp.cumprod(1.0 - records.on_path))
    after_join = (steps >= jnp.nan_to_num(joined, nan=T)) & jnp.isfinite(joined)
    return dict(dev=dev, holds=holds, settle=_first(holds, dtype), joined=joined, after_join=after_join)


def summary(cfg, records: Record | None, params) -> dict:
    """One run's records (stacked over time) reduced to its outputs, each declared next to its
    value (:func:`mcjax.contract.declare`; ``records`` None: the declarations alone)."""
    r = records
    axes = cache(lambda: _axis_errors(cfg, r))
    fm = cache(lambda: _formation(cfg, r, params))
    switched_on, alive = kit.team_weights(cfg, params, r, cache(lambda: jnp.ones(cfg.n_agents, r.error.dtype)))

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
        **pcrb.summary_items(cfg, lambda: r.bound, cfg.warmup_steps, "m/s", "wind"),
        **consistency.summary_items(cfg, lambda: r.nees, lambda: r.nis, alive, cfg.warmup_steps, 2, 2, anees=True),
    )


def series(cfg, records: Record | None, params) -> dict:
    """Per-step series of one run, each declared next to its value: errors, per-axis errors,
    the centroid's path error, λ2, every pairwise distance and every UAV's position."""
    r = records
    switched_on, alive = kit.team_weights(cfg, params, r, cache(lambda: jnp.ones(cfg.n_agents, r.error.dtype)))
    items = dict(
        **kit.error_series_items(lambda: r.error, alive, "m/s", "wind estimate error"),
        wind_error_x=(Output("m/s", "|estimate - wind| along x, report_agent"), lambda: r.axis_error[:, :, 0]),
        wind_error_y=(Output("m/s", "|estimate - wind| along y, report_agent"), lambda: r.axis_error[:, :, 1]),
        raw_error_x=(Output("m/s", "|measurement - wind| along x, report_agent", False), lambda: r.raw_error[:, 0]),
        raw_error_y=(Output("m/s", "|measurement - wind| along y, report_agent", False), lambda: r.raw_error[:, 1]),
        path_error=(Output("m", "|Y - psi(X)| of the centroid", False), lambda: r.path_error),
        lambda2=(Output("", "algebraic connectivity of the comm graph", False), lambda: r.lambda2),
        **faults.series_items(cfg, r and r.faults, switched_on),
        **pcrb.series_items(cfg, lambda: r.bound, "m/s", "wind"),
        **consistency.series_items(cfg, lambda: r.nees, lambda: r.nis, alive, 2, 2),
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
    series=series, check_params=check_params, relaxation=Relaxation(Temperatures, training_errors, training_weights, ROUGH),
    compiler_options=FAST_COMPILE,
    filter_names={"kcf": "consensus KF", "local": "local KF", "cif": "centralised KF", "ci": "CI", "hcmci": "HCMCI"},
    filter_words={
        "kcf": "Chen & Lu 2013's consensus Kalman filter: each UAV fuses its neighbours' wind measurements and "
               "moves towards their estimates",
        "local": "each UAV's own Kalman filter on its own wind measurements, nothing shared",
        "cif": "one Kalman filter on every UAV's measurements (the centralised reference)",
        "ci": "consensus on information (Battistelli & Chisci 2014): each UAV updates with its own measurement, "
              "then averages its information with its neighbours' once per step — covariance intersection, "
              "never over-confident, at the price of diluting the new measurements",
        "hcmci": "hybrid consensus on measurements and information (Battistelli et al. 2015): each UAV averages "
                 "its neighbours' predictions and, separately, their new measurements, then adds N times the "
                 "averaged measurements — the centralised filter once the averages converge"})
default_params, reduce, outputs, timeseries, timeseries_outputs = kit.aliases(SCENARIO)
