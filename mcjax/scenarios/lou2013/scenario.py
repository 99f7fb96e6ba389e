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
filter: the paper's Fig. 2–3 baseline); opt-in, the robust consensus filters ``ci`` and
``hcmci`` (:mod:`mcjax.tracking.filters.robust_consensus`), with ``filter_nodes = "all"`` only: HCMCI's
ω = N counts every node as one that filters. Errors are the position errors of the type-I
nodes' estimates. Units: the paper's (m, s). Our choices where it is silent are marked in
``configs/lou2013.toml``.

Faults (:mod:`mcjax.scenarios.kit.faults`, ``Config.faults = "on"``; ours, the paper has none).
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
steps late (:func:`mcjax.tracking.filters.consensus.kcf_step`: the disagreement of k steps ago; the
neighbours' old measurement information is not fused); the control, sensed, is not delayed.

The bound (``Config.bound = "on"``, ours; :mod:`.step`). The target's path is deterministic, so
no Bayesian floor above zero exists for it (an estimator that knows the path has zero error).
``pcrb_rmse`` is the floor for a target that moves as the filters' own model says (CV with
their ``sigma_accel``, prior ``diag(p0_diag)``) and is seen by the type-I measurements actually
taken: for this linear-Gaussian model, exactly the centralised Kalman filter's covariance.
``pcrb_local_rmse`` is each type-I node's own (the floor of its ``local`` filter), averaged over
the alive type-I nodes at each step and then over the steps. On the sine path, smoother than the
model, a filter's error may fall below it: it is the model's floor, not a floor of the sine
path. Consistency (``Config.consistency = "on"``, ours): ``anees`` (4 dof) and ``anis`` (2 dof)
over the type-I nodes, and their per-step series.
"""

from __future__ import annotations

from functools import cache

import jax.numpy as jnp

from mcjax.contract import FAST_COMPILE, Output, Scenario, declare
from mcjax.scenarios import kit
from mcjax.scenarios.kit import bound as pcrb
from mcjax.scenarios.kit import consistency
from mcjax.scenarios.kit import faults
from mcjax.scenarios.lou2013.params import Config, NAME, Params, check_params
from mcjax.scenarios.lou2013.relaxation import ROUGH, Temperatures
from mcjax.tracking import metrics
from mcjax.scenarios.lou2013.step import Record, init, sensing_mask, step  # sensing_mask: read here by benchmarks
from mcjax.contract.relaxation import Relaxation


def training_weights(cfg, params):
    """Each node's weight (N,) in the training loss: 1 for the type-I nodes (those that sense
    and whose errors the ``rmse`` output averages), 0 for the others."""
    return sensing_mask(cfg, params, jnp.dtype(cfg.dtype))


def summary(cfg, records: Record | None, params) -> dict:
    """One run's records (stacked over time) reduced to its outputs, each declared next to its
    value (:func:`mcjax.contract.declare`; ``records`` None: the declarations alone)."""
    r = records
    dtype = cache(lambda: r.error.dtype)
    h, alive = kit.team_weights(cfg, params, r, cache(lambda: sensing_mask(cfg, params, dtype())))
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
        **pcrb.summary_items(cfg, lambda: r.bound, cfg.warmup_steps, weights=alive),  # type-I nodes only
        **consistency.summary_items(cfg, lambda: r.nees, lambda: r.nis, alive, cfg.warmup_steps, 4, 2, anees=True),
    )


def series(cfg, records: Record | None, params) -> dict:
    """Per-step series of one run, each declared next to its value."""
    r = records
    h, alive = kit.team_weights(cfg, params, r, cache(lambda: sensing_mask(cfg, params, r.error.dtype)))
    return declare(
        **kit.error_series_items(lambda: r.error, alive, "m", "position error of the type-I nodes' estimates"),
        energy=(Output("", "flocking energy (eq. 15)", False), lambda: r.energy),
        lambda2=(Output("", "algebraic connectivity of the graph", False), lambda: r.lambda2),
        min_distance=(Output("m", "smallest distance between two nodes", False), lambda: r.min_distance),
        edges=(Output("", "links", False), lambda: r.edges),
        **faults.series_items(cfg, r and r.faults, lambda: jnp.ones(cfg.n_agents, r.error.dtype)),
        **pcrb.series_items(cfg, lambda: r.bound, weights=alive),
        **consistency.series_items(cfg, lambda: r.nees, lambda: r.nis, alive, 4, 2),
    )


SCENARIO = Scenario(
    name=NAME, title="Lou, Cui & Li 2013: a flocking sensor network tracks a target with the Kalman-consensus "
    "filter", Config=Config, Params=Params, init=init, step=step, summary=summary, series=series,
    check_params=check_params, relaxation=Relaxation(Temperatures, kit.training_errors, training_weights, ROUGH),
    compiler_options=FAST_COMPILE,
    filter_names={"kcf": "KCF", "local": "local KF", "ci": "CI", "hcmci": "HCMCI"},
    filter_words={
        "kcf": "Kalman-consensus filter of Lou, Cui & Li 2013 (Alg. 1): a local update with the neighbours' "
               "measurements plus a step towards their estimates",
        "local": "each node's own Kalman filter on its own measurements, nothing shared",
        "ci": "consensus on information (Battistelli & Chisci 2014): each node updates with its own measurement, "
              "then averages its information with its neighbours' once per step — covariance intersection, "
              "never over-confident, at the price of diluting the new measurements",
        "hcmci": "hybrid consensus on measurements and information (Battistelli et al. 2015): each node averages "
                 "its neighbours' predictions and, separately, their new measurements, then adds N times the "
                 "averaged measurements — the centralised filter once the averages converge"})
default_params, reduce, outputs, timeseries, timeseries_outputs = kit.aliases(SCENARIO)
