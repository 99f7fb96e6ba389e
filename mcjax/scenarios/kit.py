"""The scenario kit: pieces every scenario shares, so a scenario holds only its own system.

* :func:`common_settings` — the Config fields every tracking scenario has (agents, steps,
  filters, warm-up, divergence threshold, dtype) as :class:`~mcjax.contract.Setting` s;
* :func:`error_items` — the per-filter error summary of a run, each output declared next to its
  value (:func:`mcjax.contract.declare`; a scenario's ``summary`` unpacks them);
  :func:`error_outputs` / :func:`error_summary` — its declarations / its values alone;
* :func:`error_series_items` — the per-step series of :func:`mcjax.metrics.error_series`
  (:func:`error_series_outputs`: their declarations);
* :func:`graph_items` — the comm-graph statistics of :func:`mcjax.metrics.graph_summary`
  (:data:`GRAPH_OUTPUTS`: their declarations);
* :func:`team_measurements` — every agent's range–bearing measurement of the target;
* :func:`cast`, :func:`agents` — Params as arrays of the Config's dtype.

**Dropped-out agents** (``alive = 0``) count in no team statistic: RMSE, mean, final and
largest error and the divergence rule run over the alive agents only (a run with no alive
agent gets NaN); an agent lost to faults during a run (:mod:`mcjax.scenarios.faults`) leaves
them from its loss step on. Per-agent columns (a named agent's own error) report that agent
regardless.
"""

from __future__ import annotations

from functools import cache

import jax
import jax.numpy as jnp
import numpy as np

from mcjax import metrics
from mcjax.contract import Output, Setting, declare
from mcjax.models.sensors import measure_range_bearing, range_bearing
from mcjax.scenarios import faults

DTYPES = ("float64", "float32")


def common_settings(*, filter_kinds: tuple[str, ...], filters: tuple[str, ...] | None = None, n_agents: int,
                    n_steps: int, min_steps: int = 1, warmup_steps: int, divergence_threshold: float,
                    error_unit: str = "m") -> dict[str, Setting]:
    """The Config fields every scenario shares, with this scenario's defaults: ``n_agents``,
    ``n_steps`` (≥ ``min_steps``), ``filters`` (from ``filter_kinds``; default all of them),
    ``divergence_threshold`` (in ``error_unit``), ``warmup_steps`` and ``dtype``. Check
    ``warmup_steps < n_steps`` with :func:`check_common`."""
    return dict(
        n_agents=Setting(n_agents, "number of agents", low=1, integer=True),
        n_steps=Setting(n_steps, "simulated steps", "steps", low=min_steps, integer=True),
        filters=Setting(tuple(filters or filter_kinds), "filters run side by side, in display order",
                        choices=tuple(filter_kinds), many=True),
        divergence_threshold=Setting(divergence_threshold, "a run diverged if an alive agent's error "
                                     "exceeds this after warm-up (or went non-finite)", error_unit,
                                     low=0, low_open=True),
        warmup_steps=Setting(warmup_steps, "first steps left out of the error statistics", "steps",
                             low=0, integer=True),
        dtype=Setting("float64", "float type of the simulation (float32: for speed studies only; it changes "
                      "divergence statistics, see docs/benchmarks.md)", choices=DTYPES),
    )


def check_common(cfg) -> None:
    """The check across the common fields: ``warmup_steps < n_steps``."""
    if cfg.warmup_steps >= cfg.n_steps:
        raise ValueError(f"warmup_steps must be an integer in [0, n_steps = {cfg.n_steps}); got {cfg.warmup_steps}")


def param_value(Params, cfg, values: dict, name: str) -> np.ndarray:
    """A Params field as a check_params sees it: the spec's value if given, else the declared
    default (for this Config), as a float64 numpy array."""
    return np.asarray(values.get(name, Params.TABLE[name].default_value(cfg)), np.float64)


def cast(params, dtype):
    """Every Params field as a JAX array of ``dtype`` (the Config's float type)."""
    return jax.tree.map(lambda a: jnp.asarray(a, dtype), params)


def agents(p, n: int, dtype):
    """A scalar-or-per-agent Params value as an (n,) array."""
    return jnp.broadcast_to(jnp.asarray(p, dtype), (n,))


def per_run(like, *values):
    """``values`` unchanged (same bits), but made to depend on ``like`` (any value of the run,
    e.g. a parameter): under the engine's ``vmap`` over runs they become per-run values.

    For an ``init`` state entry that starts as a constant (zeros) but that the first step
    makes per-run: JAX would otherwise batch the time loop's body twice (once with the entry
    shared by all runs, then again with it per run), which cost ~2 s of the closed loop's
    ~5 s of tracing. The engine's program is the same either way."""
    p = jnp.asarray(like)
    same = jnp.any(p == p)  # a per-run boolean (False for NaN: then the second branch, the same value)
    out = tuple(jnp.where(same, v, v) for v in values)
    return out[0] if len(out) == 1 else out


def team_measurements(key, target, sensors, sigma_range, sigma_bearing, sensing_radius, alive):
    """Every agent's noisy range–bearing measurement of ``target`` (n, 2), NaN where the
    target is out of the agent's ``sensing_radius`` (n,) or the agent is not ``alive`` (n,)
    — :func:`mcjax.models.sensors.measure_range_bearing` with one key per agent."""
    keys = jax.random.split(key, sensors.shape[0])
    return jax.vmap(measure_range_bearing, in_axes=(0, None, 0, None, None, 0, 0))(
        keys, target, sensors, sigma_range, sigma_bearing, sensing_radius, alive)


def soft_team_measurements(key, target, sensors, sigma_range, sigma_bearing, sensing_radius, alive, temperature):
    """:func:`team_measurements` (the same noise draws) with the range gate ``r ≤ R_s`` replaced
    by a soft gate ``g_i = sigmoid((R_s − r_i)/T)``, for a scenario's smoothing switch: returns
    ``(z (n, 2), g (n,))``, every alive agent's measurement and its weight (the caller weighs
    agent i's measurement information by ``g_i``). Dead agents: NaN, ``g = 0``."""
    z = team_measurements(key, target, sensors, sigma_range, sigma_bearing,
                          jnp.full(sensors.shape[0], jnp.inf, sensors.dtype), alive)
    r = jax.vmap(range_bearing, in_axes=(None, 0))(target, sensors)[:, 0]
    return z, jnp.where(alive, jax.nn.sigmoid((sensing_radius - r) / temperature), 0.0)


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
    :func:`mcjax.scenarios.faults.weights`). Returns each field of :func:`error_outputs` as (F,)."""
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
    """The comm-graph statistics of one run (:func:`mcjax.metrics.graph_summary` of the λ2
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


#: Declarations of :func:`mcjax.metrics.graph_summary`'s fields (those of :func:`graph_items`).
GRAPH_OUTPUTS = declarations(graph_items(None))


def error_series_items(errors, alive, unit: str = "m", what: str = "position error"):
    """The per-step series of :func:`mcjax.metrics.error_series` (``errors`` (T, F, n) and the
    ``alive`` weights (n,) or (T, n) given by functions of no arguments), each declared next to its value."""
    series = cache(lambda: _error_series(errors(), alive()))
    return declare(error_mean=(Output(unit, f"mean {what} over alive agents"), lambda: series()["error_mean"]),
                   error_max=(Output(unit, f"largest {what} of any alive agent"), lambda: series()["error_max"]))


def _error_series(errors, alive):
    """:func:`mcjax.metrics.error_series` of (T, F, n) errors with (n,) or (T, n) weights."""
    if alive.ndim == 2:
        return metrics.error_series(faults.masked(errors, alive), alive[:, None, :])
    return metrics.error_series(errors, alive)


def error_series_outputs(unit: str = "m", what: str = "position error") -> dict[str, Output]:
    """Declarations of the per-step series of :func:`mcjax.metrics.error_series`."""
    return declarations(error_series_items(None, None, unit, what))
