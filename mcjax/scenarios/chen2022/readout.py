"""Chen & Hao 2022's scenario (:mod:`.scenario`): what a run reports — its outputs (summary,
series) and what the training loss of ``mcjax tune`` reads. With ``bound = "on"`` the posterior
Cramér–Rao bound of the emitter's horizontal position (pcrb_rmse, m; :mod:`.step` says what it is
conditioned on), with ``consistency = "on"`` each filter's ANEES (2 dof: [x, y]) and ANIS (1 dof:
the azimuth; the IMM's from its predicted measurement mixture's moments,
:func:`.mode_filters.mixture_nis`) and their per-step series."""

from __future__ import annotations

from functools import cache

import jax.numpy as jnp

from mcjax.contract import Output, declare
from mcjax.scenarios import kit
from mcjax.scenarios.chen2022.params import NLOS_MINUS, NLOS_PLUS
from mcjax.scenarios.chen2022.step import Record
from mcjax.scenarios.kit import bound as pcrb
from mcjax.scenarios.kit import consistency


def training_weights(cfg, params):
    """What the training loss of ``mcjax tune`` reads: one UAV, weight 1 (the errors of
    :class:`Record` are (F, 1))."""
    return jnp.ones(1, jnp.dtype(cfg.dtype))


def _nlos_mean(nlos, value):
    """The mean of ``value`` over the NLOS steps: ``nlos`` a 0/1 indicator (the exact record) or
    a weight in [0, 1] (the smooth one)."""
    if nlos.dtype == jnp.bool_:
        return jnp.sum(jnp.where(nlos, value, 0.0)) / jnp.sum(nlos)
    return jnp.sum(nlos * value) / jnp.sum(nlos)


def summary(cfg, records: Record | None, params) -> dict:
    """One run's records (stacked over time) reduced to its outputs, each declared next to its
    value (:func:`mcjax.contract.declare`; ``records`` None: the declarations alone)."""
    r = records
    nlos_mu = cache(lambda: r.mu[:, NLOS_PLUS] + r.mu[:, NLOS_MINUS])
    return declare(
        **kit.error_items(lambda: r.error, lambda: jnp.ones(1, r.error.dtype), cfg, "m",
                          "distance of the estimate from the emitter"),
        shadow_steps=(Output("steps", "steps with no line of sight (no measurement)", False),
                      lambda: jnp.sum(r.shadow)),
        nlos_steps=(Output("steps", "steps whose measurement carried a reflection (biased)", False),
                    lambda: jnp.sum(r.nlos)),
        held_steps=(Output("steps", "steps flying the previous command after a step in the shadow", False),
                    lambda: jnp.sum(r.held)),
        building_steps=(Output("steps", "steps with the UAV inside a building (must be 0)", False),
                        lambda: jnp.sum(r.in_building)),
        limit_violations=(Output("steps", "steps whose command or altitude broke a limit of eq. 4 (must be 0)",
                                 False), lambda: jnp.sum(r.violation)),
        min_altitude=(Output("m", "lowest altitude flown", False), lambda: jnp.min(r.uav[:, 2])),
        mu_nlos_when_nlos=(Output("", "the IMM's mean NLOS probability on steps with a reflected measurement "
                                  "(NaN if there were none)", False),
                           lambda: _nlos_mean(r.nlos, nlos_mu())),
        **pcrb.summary_items(cfg, lambda: r.bound, cfg.warmup_steps, "m", "horizontal position"),
        **consistency.summary_items(cfg, lambda: r.nees, lambda: r.nis, lambda: jnp.ones(1, r.error.dtype),
                                    cfg.warmup_steps, 2, 1),
    )


def series(cfg, records: Record | None, params) -> dict:
    """Per-step series of one run, each declared next to its value."""
    r = records
    return declare(
        **kit.error_series_items(lambda: r.error, lambda: jnp.ones(1, r.error.dtype), "m",
                                 "distance of the estimate from the emitter"),
        x=(Output("m", "UAV x", False), lambda: r.uav[:, 0]),
        y=(Output("m", "UAV y", False), lambda: r.uav[:, 1]),
        z=(Output("m", "UAV altitude", False), lambda: r.uav[:, 2]),
        shadow=(Output("", "1 = no line of sight (no measurement)", False), lambda: r.shadow.astype(r.error.dtype)),
        nlos=(Output("", "1 = the measurement carried a reflection", False), lambda: r.nlos.astype(r.error.dtype)),
        **pcrb.series_items(cfg, lambda: r.bound, "m", "horizontal position"),
        **consistency.series_items(cfg, lambda: r.nees, lambda: r.nis, lambda: jnp.ones(1, r.error.dtype), 2, 1),
    )
