"""The posterior Cramér–Rao bound of a team's target, one step at a time (:mod:`mcjax.tracking.filters.bounds`,
Tichavský, Muravchik & Nehorai 1998): what a scenario with ``bound = "on"`` carries in its state and
records. The information of every measurement taken is added at the true target, so the bound is
conditioned on the run's trajectory (and, in closed loop, on the agents' paths; Zuo, Niu & Varshney
2011). It is carried as a covariance (:func:`mcjax.tracking.filters.bounds.pcrb_covariance_step`), so it may
start from a state the filters are given exactly (``initial`` with a zero covariance): a filter that
starts at the true state has no initial error, and a bound that assumed one would not be its floor."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from mcjax.contract import Output, Setting
from mcjax.scenarios.kit.consistency import run_average, step_average
from mcjax.tracking.filters.bounds import measurement_information, pcrb_covariance_step

#: The Config switch (off: the program without the bound, bit for bit).
SETTING = Setting("off", "the posterior Cramér–Rao bound along the run (Tichavský et al. 1998): on adds "
                  "pcrb_rmse, the floor of any filter of every agent's measurements, and its per-step series; "
                  "off is the program without it", choices=("off", "on"))


class Bound(NamedTuple):
    """The bound of the ``team`` (every agent's measurements: the floor of every filter, centralised
    ones included) and each agent's ``local`` one (its own measurements: the floor of a local filter),
    as covariances (d, d) and (n, d, d), or as their position variances () and (n,)."""

    team: jax.Array
    local: jax.Array


def initial(cfg, C0):
    """The bound before step 0: ``C0`` the covariance of the initial state given what the filters
    start from — zeros when they start at the true state, their prior ``P0`` when their prior is the
    initial state's distribution — for the team and each agent (None when ``cfg.bound`` is off)."""
    if cfg.bound != "on":
        return None
    return Bound(C0, jnp.broadcast_to(C0, (cfg.n_agents,) + C0.shape))


def update(C, F, Q, h, target, sensors, z, R_inv):
    """The bound after this step (eq. 21 for the truth's dynamics ``F``, ``Q``; at the first
    measurement time the caller passes ``(I, 0)``, no prediction): ``h(x, sensor)`` the measurement
    function, ``Hᵀ R⁻¹ H`` at the true ``target`` added for every agent whose measurement ``z`` (n, m)
    was taken (finite: in range, the agent alive, no dropout). None stays None (off)."""
    if C is None:
        return None
    taken = jnp.all(jnp.isfinite(z), axis=-1)
    info = jax.vmap(lambda sensor, Ri, ok: measurement_information(lambda x: h(x, sensor), target, Ri, ok))(
        sensors, jnp.broadcast_to(R_inv, z.shape[:1] + R_inv.shape[-2:]), taken)   # (n, d, d)
    return update_with(C, F, Q, info)


def update_with(C, F, Q, info):
    """:func:`update` with each agent's measurement information ``info`` (n, d, d) given (0 for an
    agent without a measurement): for a scenario whose measurement model is not one ``h`` with one
    ``R`` (e.g. a mode-dependent one). None stays None (off)."""
    if C is None:
        return None
    return Bound(pcrb_covariance_step(C.team, F, Q, jnp.sum(info, axis=0)),
                 jax.vmap(pcrb_covariance_step, in_axes=(0, None, None, 0))(C.local, F, Q, info))


def position_variance(C, index=(0, 2)):
    """The bounds' variances of the tracked quantity, ``Σ_i C_ii`` over ``index`` of the covariance
    ``C`` (the default: ``C_xx + C_yy`` of a ``[x, ẋ, y, ẏ]`` state; None stays None)."""
    if C is None:
        return None
    team, local = C.team, C.local
    i = jnp.asarray(index)
    return Bound(jnp.sum(team[i, i]), jnp.sum(local[:, i, i], axis=-1))


def _local_mean(local, weights, warmup: int = 0):
    """The local bounds' variances (T, n) averaged over the steps from ``warmup`` and the agents
    with a non-zero weight (``weights`` (n,) or (T, n); None: every agent alike)."""
    if weights is None:
        return jnp.mean(local[warmup:])
    return run_average(local[:, None, :], weights, warmup)[0]


def summary_items(cfg, records_bound, warmup: int, unit: str = "m", what: str = "position", weights=None):
    """The bound's summary outputs (``pcrb_rmse``, role ``"floor"``; ``pcrb_local_rmse``), when on:
    the RMS of the ``what`` error (in ``unit``) the bound allows after warm-up. ``weights``: a
    function of no arguments giving the agents the local floor is averaged over, (n,) or (T, n)
    (e.g. only those that measure); None: every agent."""
    if cfg.bound != "on":
        return {}
    return {"pcrb_rmse": (Output(unit, f"the posterior Cramér–Rao bound's {what} RMSE after warm-up along the run: "
                                       "the floor of any filter of every agent's measurements (Tichavský et al. 1998; "
                                       "compare the mean of rmse² over runs)", False, "floor"),
                          lambda: jnp.sqrt(jnp.mean(records_bound().team[warmup:]))),
            "pcrb_local_rmse": (Output(unit, "the same bound of each agent's own measurements (the floor of a local "
                                             "filter), over the agents and the steps after warm-up", False),
                                lambda: jnp.sqrt(_local_mean(records_bound().local, weights and weights(), warmup)))}


def series_items(cfg, records_bound, unit: str = "m", what: str = "position", weights=None):
    """The bound's per-step series (``pcrb_error``, role ``"floor"``; ``pcrb_local_error``), when on;
    ``weights`` as for :func:`summary_items`."""
    if cfg.bound != "on":
        return {}
    return {"pcrb_error": (Output(unit, f"the posterior Cramér–Rao bound's {what} error (the square root of its "
                                        "variance)", False, "floor"), lambda: jnp.sqrt(records_bound().team)),
            "pcrb_local_error": (Output(unit, "the local bound's error, mean variance over the agents", False),
                                 lambda: jnp.sqrt(jnp.mean(records_bound().local, axis=-1) if weights is None else
                                                  step_average(records_bound().local[:, None, :], weights())[:, 0]))}
