"""Pieces every scenario module shares: the common Config checks and small array helpers."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

DTYPES = ("float64", "float32")


def choices(values) -> str:
    """``"one of a, b, c"`` — the allowed-values text of ``CONFIG_ALLOWED``."""
    return "one of " + ", ".join(values)


def check_config(cfg, filter_kinds, *, min_steps: int = 1) -> None:
    """The Config checks common to every scenario (ValueError naming the field): ``n_agents``,
    ``n_steps`` (≥ ``min_steps``), ``filters`` (non-empty, known, no repeats), ``dtype``,
    ``warmup_steps`` and ``divergence_threshold``."""
    if not isinstance(cfg.n_agents, int) or cfg.n_agents < 1:
        raise ValueError(f"n_agents must be an integer >= 1; got {cfg.n_agents!r}")
    if not isinstance(cfg.n_steps, int) or cfg.n_steps < min_steps:
        raise ValueError(f"n_steps must be an integer >= {min_steps}; got {cfg.n_steps!r}")
    if not cfg.filters:
        raise ValueError("filters must name at least one filter")
    for f in cfg.filters:
        if f not in filter_kinds:
            raise ValueError(f"filters: unknown filter {f!r}; allowed: {', '.join(filter_kinds)}")
    if len(set(cfg.filters)) != len(cfg.filters):
        raise ValueError(f"filters must not repeat a filter; got {cfg.filters}")
    if cfg.dtype not in DTYPES:
        raise ValueError(f"dtype must be {choices(DTYPES)}; got {cfg.dtype!r}")
    if not 0 <= cfg.warmup_steps < cfg.n_steps:
        raise ValueError(f"warmup_steps must be in [0, n_steps); got {cfg.warmup_steps}")
    if not cfg.divergence_threshold > 0:
        raise ValueError(f"divergence_threshold must be > 0 m; got {cfg.divergence_threshold}")


def cast(params, dtype):
    """Every Params field as a JAX array of ``dtype`` (the Config's float type)."""
    return jax.tree.map(lambda a: jnp.asarray(a, dtype), params)


def agents(p, n: int, dtype):
    """A scalar-or-per-agent Params value as an (n,) array."""
    return jnp.broadcast_to(jnp.asarray(p, dtype), (n,))


def make_params(params_type, values: dict, overrides: dict):
    """``params_type`` (a Params NamedTuple) from the defaults ``values`` with ``overrides``
    applied, every field a float64 numpy array; an unknown override is a ValueError
    listing the allowed fields."""
    unknown = set(overrides) - set(params_type._fields)
    if unknown:
        raise ValueError(f"unknown Params field(s) {sorted(unknown)}; allowed: {', '.join(params_type._fields)}")
    return params_type(**{k: np.asarray(v, dtype=np.float64) for k, v in {**values, **overrides}.items()})
