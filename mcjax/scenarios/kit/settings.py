"""The Config fields every tracking scenario has and Params as arrays: common settings, their
check, a Params value as a check sees it, the cast to the Config's dtype, per-agent values, and
:func:`per_run` (an ``init`` constant made per-run)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from mcjax.contract import Setting
from mcjax.tracking.filters.registry import ENTRY_POINT_GROUP, FILTER_KINDS, get, same_names, shown_name

DTYPES = ("float64", "float32")


def common_settings(*, filter_kinds: tuple[str, ...], filters: tuple[str, ...] | None = None, n_agents: int,
                    n_steps: int, min_steps: int = 1, warmup_steps: int, divergence_threshold: float,
                    error_unit: str = "m", plugin_filters: bool | str = False) -> dict[str, Setting]:
    """The Config fields every scenario shares, with this scenario's defaults: ``n_agents``,
    ``n_steps`` (≥ ``min_steps``), ``filters`` (from ``filter_kinds``; default all of them),
    ``divergence_threshold`` (in ``error_unit``), ``warmup_steps`` and ``dtype``. Check
    ``warmup_steps < n_steps`` with :func:`check_common`. ``plugin_filters``: the scenario runs any
    filter of the filter contract (:mod:`mcjax.contract.filter`), so ``filters`` may also name an installed
    plugin (entry-point group ``mcjax.filters``) or a reference ``"file.py:ATTRIBUTE"``; a string says in a
    few words why the scenario takes none (a plugin named is refused with it, in one line)."""
    return dict(
        n_agents=Setting(n_agents, "number of agents", low=1, integer=True),
        n_steps=Setting(n_steps, "simulated steps", "steps", low=min_steps, integer=True),
        filters=Setting(tuple(filters or filter_kinds), "filters run side by side, in display order",
                        choices=tuple(filter_kinds), many=True,
                        plugins=ENTRY_POINT_GROUP if plugin_filters is True else None,
                        refuses=(ENTRY_POINT_GROUP, plugin_filters) if isinstance(plugin_filters, str) else None),
        divergence_threshold=Setting(divergence_threshold, "a run diverged if an alive agent's error "
                                     "exceeds this after warm-up (or went non-finite)", error_unit,
                                     low=0, low_open=True),
        warmup_steps=Setting(warmup_steps, "first steps left out of the error statistics", "steps",
                             low=0, integer=True),
        dtype=Setting("float64", "float type of the simulation (float32: for speed studies only; it changes "
                      "divergence statistics, see docs/benchmarks.md)", choices=DTYPES),
    )


def check_common(cfg) -> None:
    """The checks across the common fields: ``warmup_steps < n_steps``; every filter that is not a built-in
    one resolves to a filter record (:func:`mcjax.tracking.filters.registry.get`: an unknown plugin, one that
    fails to import or is not a Filter, a name that clashes with a built-in: one line); no two filters are shown
    by one name (:func:`mcjax.tracking.filters.registry.same_names`)."""
    if cfg.warmup_steps >= cfg.n_steps:
        raise ValueError(f"warmup_steps must be an integer in [0, n_steps = {cfg.n_steps}); got {cfg.warmup_steps}")
    setting = getattr(type(cfg), "SETTINGS", {}).get("filters", Setting(None, ""))
    if setting.plugins:
        for name in cfg.filters:
            if name not in FILTER_KINDS:
                try:
                    get(name)
                except ValueError as exc:
                    raise ValueError(f"filters: {exc}") from None
        twice = same_names(cfg.filters, tuple(setting.choices or ()))
        if twice:
            raise ValueError(twice)


def shown_filter_names(filters, own=FILTER_KINDS) -> str:
    """``filters`` as a refusal names them: by the names the datasets show (a filter of one's own by its
    record's name; ``own``: the scenario's own filter kinds, shown as written)."""
    return ", ".join(shown_name(f, own) for f in filters)


def param_value(Params, cfg, values: dict, name: str) -> np.ndarray:
    """A Params field as a check_params sees it: the spec's value if given, else the declared
    default (for this Config), as a float64 numpy array."""
    return np.asarray(values.get(name, Params.TABLE[name].default_value(cfg)), np.float64)


def cast(params, dtype):
    """Every Params field as a JAX array of ``dtype`` (the Config's float type)."""
    return jax.tree.map(lambda a: jnp.asarray(a, dtype), params)


def typed(cfg, params):
    """``(dtype, params)``: the Config's float type and every Params field as a JAX array of it
    (:func:`cast`)."""
    dtype = jnp.dtype(cfg.dtype)
    return dtype, cast(params, dtype)


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
