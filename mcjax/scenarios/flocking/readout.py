"""Lou, Cui & Li 2013's flock (:mod:`.scenario`): what a run's records reduce to — the summary
and the per-step series — and the weights of ``mcjax tune``'s training loss (its errors: the kit's)."""

from __future__ import annotations

from functools import cache

import jax.numpy as jnp

from mcjax import metrics
from mcjax.contract import Output, declare
from mcjax.scenarios import faults, kit
from mcjax.scenarios.flocking.step import Record, sensing_mask


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
