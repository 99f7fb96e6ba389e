"""Faults of a team's network, for every scenario with a comm graph — first piece: lost links.

A link's message is lost in a step with probability ``link_loss``, independently per link and
step (``link_burst = 0``), or in bursts: each link is a two-state Gilbert–Elliott channel
(Gilbert 1960, Elliott 1963) — *good* (delivered) or *bad* (lost) — a Markov chain whose
stationary loss rate is ``link_loss`` and whose mean burst of losses lasts ``link_burst`` steps
(:func:`channel_rates`). A link is symmetric: i's message to j is lost exactly when j's to i is.

The draws come from their own key stream, ``fold_in(step_key, FAULT_STREAM)``
(:func:`fault_key`), so switching faults on changes no other random number of a run, and a loss
rate of 0 leaves the adjacency bit for bit as it was (:func:`delivered` multiplies by 1).

Not yet wired into the scenarios (their Params, outputs and documented behaviour under faults
come next); :data:`LINK_PARAMS` holds the declarations they will share.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mcjax.contract import Param

#: The constant folded into a step's key for the fault draws (``"FAUT"`` in ASCII).
FAULT_STREAM = 0x46415554

#: The Params of lost links, as a scenario declares them (``params_type``'s table).
LINK_PARAMS = {
    "link_loss": Param(0.0, "", "probability that a link's message is lost in a step (the stationary rate with "
                                "link_burst)", low=0.0, high=1.0),
    "link_burst": Param(0.0, "steps", "mean length of a burst of losses on a link (a Gilbert–Elliott channel); "
                                      "0: losses independent per step", low=0.0),
}


def fault_key(step_key: jax.Array) -> jax.Array:
    """The key of a step's fault draws: ``fold_in(step_key, FAULT_STREAM)``."""
    return jax.random.fold_in(step_key, FAULT_STREAM)


def channel_rates(loss, burst):
    """``(p_gb, p_bb)``: the probabilities that a link is lost in the next step given it is
    delivered (good) or lost (bad) now. A Gilbert–Elliott chain with stationary loss rate
    ``π = loss`` and mean burst length ``L = burst`` leaves the bad state with ``p_bg = 1/L``
    (bursts are geometric), and balance ``π p_bg = (1 − π) p_gb`` gives ``p_gb = π / (L (1 − π))``;
    ``burst = 0`` is independent loss, ``p_gb = p_bb = π``. Valid for ``L ≥ max(1, π / (1 − π))``
    (:func:`burst_problem`)."""
    loss, burst = jnp.asarray(loss), jnp.asarray(burst)
    bursty = burst > 0
    safe_burst = jnp.where(bursty, burst, 1.0)
    p_gb = jnp.where(bursty, loss / (safe_burst * jnp.maximum(1.0 - loss, jnp.finfo(loss.dtype).tiny)), loss)
    p_bb = jnp.where(bursty, 1.0 - 1.0 / safe_burst, loss)
    return jnp.minimum(p_gb, 1.0), p_bb


def burst_problem(loss: float, burst: float) -> str | None:
    """None if ``(link_loss, link_burst)`` make a Gilbert–Elliott chain, else what is allowed."""
    if burst == 0:
        return None
    least = max(1.0, loss / (1.0 - loss)) if loss < 1 else float("inf")
    if burst < least * (1 - 1e-12):  # (0.8 / 0.2 is 4.000000000000001 in floating point)
        return f"0 or >= {least:g} steps for link_loss = {loss:g} (a burst lasts at least one step, and " \
               f"bursts must fit the loss rate)"
    return None


def _symmetric_uniform(key, n: int, dtype) -> jax.Array:
    """(n, n) uniform numbers with ``u[i, j] = u[j, i]`` (the upper triangle mirrored; the
    diagonal is that of the draw and unused)."""
    u = jax.random.uniform(key, (n, n), dtype)
    upper = jnp.triu(u, 1)
    return upper + upper.T + jnp.diag(jnp.diag(u))


def channel_init(key, n: int, loss, dtype=jnp.float64) -> jax.Array:
    """The links' states before step 0, drawn from the chain's stationary distribution (loss
    rate ``loss`` whatever the bursts): (n, n), 1.0 where the link is lost, symmetric."""
    return (_symmetric_uniform(key, n, dtype) < loss).astype(dtype)


def channel_step(key, lost: jax.Array, loss, burst) -> jax.Array:
    """The links' states one step on: each link lost with probability ``p_bb`` if it is lost
    now, ``p_gb`` if not (:func:`channel_rates`); symmetric like ``lost``."""
    p_gb, p_bb = channel_rates(loss, burst)
    u = _symmetric_uniform(key, lost.shape[-1], lost.dtype)
    return (u < jnp.where(lost > 0, p_bb, p_gb)).astype(lost.dtype)


def delivered(adjacency: jax.Array, lost: jax.Array) -> jax.Array:
    """The links whose messages arrive this step: ``adjacency · (1 − lost)`` (bit for bit the
    adjacency where nothing is lost)."""
    return adjacency * (1.0 - lost)
