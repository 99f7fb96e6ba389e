"""Any filter's step, start and agent axis, by its record (:mod:`.registry`): what the scenarios call, so that
none of them names a filter to learn how it runs. Each is resolved by name at trace time."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from mcjax.contract.filter import FilterError, Model
from mcjax.tracking.filters.consensus import FilterOptions, Measurements
from mcjax.tracking.filters.gaussian import Gaussian
from mcjax.tracking.filters.registry import get, shown_name
from mcjax.tracking.numerics import spd_inverse, symmetrize


def filter_step(kinds, opts: FilterOptions, h, angle_mask, states, meas: Measurements, F, Q, kcf_epsilon,
                formation=None):
    """Advance every filter in ``kinds`` (names, :func:`mcjax.tracking.filters.registry.get`) by one step: each
    record's ``step(Model(h, angle_mask, F, Q, opts, kcf_epsilon, formation), state, meas)``. Returns the new
    states (same structure as ``states``). ``formation``: eq. 12's formation term of Chen & Lu 2013's
    consensus Kalman filter, if any."""
    model = Model(h, angle_mask, F, Q, opts, kcf_epsilon, formation)
    return tuple(checked(kind, get(kind).step(model, post, meas), post) for kind, post in zip(kinds, states))


def checked(kind, new, post):
    """``new``, a filter's step's result, when it has the structure, shapes and dtypes of the posterior it was
    given; else a one-line :class:`FilterError` naming the filter and the field (at the first trace, before
    anything runs)."""
    if not isinstance(new, Gaussian):
        raise FilterError(f"filter {kind!r}: its step returned {_what(new)}, not a Gaussian(x, P, Y) like "
                         f"the posterior it was given")
    for field, a, b in zip(Gaussian._fields, new, post):
        if jnp.shape(a) != jnp.shape(b) or jnp.result_type(a) != jnp.result_type(b):
            raise FilterError(f"filter {kind!r}: its step returned {field} of shape {tuple(jnp.shape(a))} and dtype "
                             f"{jnp.result_type(a)}; the posterior's {field} is {tuple(jnp.shape(b))} "
                             f"{jnp.result_type(b)}")
    return new


def _what(value) -> str:
    """What a step returned, in its author's words: an array with its shape (not JAX's tracer), a tuple of so
    many values, None, else its type."""
    if value is None:
        return "None"
    if isinstance(value, tuple):
        inner = ", ".join(_what(v) for v in value[:4]) + (", …" if len(value) > 4 else "")
        kind = "tuple" if type(value) is tuple else type(value).__name__
        return f"a {kind} of {len(value)} ({inner})"
    if isinstance(value, (jax.Array, np.ndarray)) or hasattr(value, "shape") and hasattr(value, "dtype"):
        return f"an array (shape {tuple(jnp.shape(value))})"
    return f"a {type(value).__name__}"


def _with_agents(state: Gaussian, n_agents: int) -> Gaussian:
    return jax.tree.map(lambda a: jnp.broadcast_to(a, (n_agents,) + a.shape), state)


def init_states(kinds, x0, P0, n_agents):
    """Every filter's state at the first measurement time: the prior ``(x0, P0)`` — one Gaussian for a
    centralised filter (its traits), one per agent for the others."""
    Y0 = symmetrize(spd_inverse(P0))
    single = Gaussian(x0, P0, Y0)
    per_agent_state = _with_agents(single, n_agents)
    return tuple(single if get(k).traits.centralised else per_agent_state for k in kinds)


def per_agent(kind, state: Gaussian, n_agents) -> Gaussian:
    """A filter state with an agent axis (a centralised filter's one estimate repeated for every agent)."""
    return _with_agents(state, n_agents) if get(kind).traits.centralised else state


def centralised(kind) -> bool:
    """Whether the filter ``kind`` keeps one estimate for all agents (no link carries it)."""
    return get(kind).traits.centralised


def late_messages(kind) -> bool:
    """Whether the filter ``kind`` takes consensus messages that arrive late, or sends none."""
    return get(kind).traits.late_messages


def delayed_sender(kinds) -> int | None:
    """The index in ``kinds`` of the one filter whose consensus messages a delay carries (it sends messages
    and takes them late: the KCF among the built-ins), or None; two such filters is a ValueError (one
    mailbox per run)."""
    found = [i for i, k in enumerate(kinds) if get(k).traits.messages and get(k).traits.late_messages]
    if len(found) > 1:
        raise ValueError(f"filters: at most one filter that sends consensus messages and takes them late "
                         f"(traits.messages and traits.late_messages) may run with message_delay > 0 (one mailbox "
                         f"per run); got {', '.join(shown_name(kinds[i]) for i in found)}")
    return found[0] if found else None
