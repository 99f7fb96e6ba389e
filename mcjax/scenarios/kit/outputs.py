"""What a run reports, declared next to its value: the per-filter error summary, the comm graph's
statistics, the per-step error series, and the weights they are taken over (agents switched on,
less those lost to faults).

**Dropped-out agents** (``alive = 0``) count in no team statistic: RMSE, mean, final and
largest error and the divergence rule run over the alive agents only (a run with no alive
agent gets NaN); an agent lost to faults during a run (:mod:`mcjax.scenarios.kit.faults`) leaves
them from its loss step on. Per-agent columns (a named agent's own error) report that agent
regardless.
"""

from __future__ import annotations

from functools import cache

import jax.numpy as jnp

from mcjax.contract import Output, declare
from mcjax.scenarios.kit import faults
from mcjax.tracking import metrics


def declarations(items) -> dict[str, Output]:
    """The :class:`~mcjax.contract.Output` s of ``declare``-d items, in order."""
    return {k: o for k, (o, _) in items.items()}


def error_items(errors, alive, cfg, unit: str = "m", what: str = "position error"):
    """The per-filter error summary of one run (:func:`error_summary` after ``cfg``'s warm-up,
    with its divergence threshold), each field declared next to its value: ``errors`` and
    ``alive`` are functions of no arguments giving (T, F, n) errors (``what`` in ``unit``) and
    the alive weights, (n,) or (T, n); nothing is computed before a value is asked for."""
    stats = cache(lambda: error_summary(errors(), alive(), cfg.warmup_steps, cfg.divergence_threshold))
    return declare(
        rmse=(Output(unit, f"RMS {what} over alive agents and steps after warm-up", True, "error"),
              lambda: stats()["rmse"]),
        mean_error=(Output(unit, f"mean {what} over alive agents and steps after warm-up"),
                    lambda: stats()["mean_error"]),
        final_error=(Output(unit, f"mean {what} over alive agents at the last step"), lambda: stats()["final_error"]),
        max_error=(Output(unit, f"largest {what} of any alive agent after warm-up"), lambda: stats()["max_error"]),
        diverged=(Output("", f"{what} above divergence_threshold after warm-up, or non-finite", True, "divergence"),
                  lambda: stats()["diverged"]),
        nonfinite=(Output("", "some estimate went NaN or infinite", True, "nonfinite"), lambda: stats()["nonfinite"]),
    )


def error_outputs(unit: str = "m", what: str = "position error") -> dict[str, Output]:
    """Declarations of :func:`error_summary`'s fields (those of :func:`error_items`)."""
    return declarations(error_items(None, None, None, unit, what))


def error_summary(errors, alive, warmup: int, threshold) -> dict:
    """Per-filter error statistics of one run: ``errors`` (T, F, n) for F filters and n
    agents, ``alive`` 0/1 weights, (n,) or per step (T, n) (agents lost during the run:
    :func:`mcjax.scenarios.kit.faults.weights`). Returns each field of :func:`error_outputs` as (F,)."""
    T = errors.shape[0]
    errors = faults.masked(errors, alive)
    last = alive[-1] if alive.ndim == 2 else alive
    after = (jnp.arange(T) >= warmup)[:, None] & (alive > 0)
    any_alive = jnp.any(alive > 0)
    out = {k: [] for k in error_outputs()}
    for f in range(errors.shape[1]):
        e = errors[:, f, :]
        out["rmse"].append(metrics.rmse(e, warmup, alive))
        out["mean_error"].append(metrics.mean_over(e, warmup, alive))
        out["final_error"].append(metrics.mean_over(e[-1:], 0, last))
        out["max_error"].append(metrics.nan_max(jnp.where(after, e, -jnp.inf)))
        out["diverged"].append(metrics.diverged(e, threshold, warmup, alive))
        out["nonfinite"].append(metrics.nonfinite(e))
    stats = {k: jnp.stack(v) for k, v in out.items()}
    for k in ("rmse", "mean_error", "final_error", "max_error"):
        stats[k] = jnp.where(any_alive, stats[k], jnp.nan)
    return stats


def graph_items(lambda2):
    """The comm-graph statistics of one run (:func:`mcjax.tracking.metrics.graph_summary` of the λ2
    series that the function of no arguments ``lambda2`` gives), each declared next to its value."""
    stats = cache(lambda: metrics.graph_summary(lambda2()))
    return declare(
        lambda2_min=(Output("", "smallest algebraic connectivity of the comm graph over the run", False,
                            "connectivity_min"), lambda: stats()["lambda2_min"]),
        lambda2_mean=(Output("", "mean algebraic connectivity of the comm graph", False, "connectivity_mean"),
                      lambda: stats()["lambda2_mean"]),
        disconnected_steps=(Output("steps", "steps with lambda2 <= 1e-9 (comm graph disconnected)", False,
                                   "disconnected_steps"), lambda: stats()["disconnected_steps"]),
    )


#: Declarations of :func:`mcjax.tracking.metrics.graph_summary`'s fields (those of :func:`graph_items`).
GRAPH_OUTPUTS = declarations(graph_items(None))


def error_series_items(errors, alive, unit: str = "m", what: str = "position error"):
    """The per-step series of :func:`mcjax.tracking.metrics.error_series` (``errors`` (T, F, n) and the
    ``alive`` weights (n,) or (T, n) given by functions of no arguments), each declared next to its value."""
    series = cache(lambda: _error_series(errors(), alive()))
    return declare(error_mean=(Output(unit, f"mean {what} over alive agents", True, "error"),
                               lambda: series()["error_mean"]),
                   error_max=(Output(unit, f"largest {what} of any alive agent"), lambda: series()["error_max"]))


def _error_series(errors, alive):
    """:func:`mcjax.tracking.metrics.error_series` of (T, F, n) errors with (n,) or (T, n) weights."""
    if alive.ndim == 2:
        return metrics.error_series(faults.masked(errors, alive), alive[:, None, :])
    return metrics.error_series(errors, alive)


def error_series_outputs(unit: str = "m", what: str = "position error") -> dict[str, Output]:
    """Declarations of the per-step series of :func:`mcjax.tracking.metrics.error_series`."""
    return declarations(error_series_items(None, None, unit, what))


def team_weights(cfg, params, r, switched_on=None):
    """``(switched_on, alive)``: functions of no arguments (each computed once) giving the weights
    (n,) of the agents the spec switched on (``params.alive``, unless a ``switched_on`` function
    is given) and, per step (T, n), of those not yet lost to faults
    (:func:`mcjax.scenarios.kit.faults.weights` of the records ``r``)."""
    if switched_on is None:
        switched_on = cache(lambda: metrics.alive_weights(params.alive, cfg.n_agents, r.error.dtype))
    return switched_on, cache(lambda: faults.weights(switched_on(), r.faults))


def training_errors(cfg, params, record):
    """What the training loss of ``mcjax tune`` reads from a step's record: the errors (F, n) of
    every filter and agent (``record.error``)."""
    return record.error


def training_weights(cfg, params):
    """The weight (n,) of each agent's error in the training loss of ``mcjax tune``: 1 if the spec
    switched it on (``params.alive``), else 0."""
    return metrics.alive_weights(params.alive, cfg.n_agents, jnp.dtype(cfg.dtype))
