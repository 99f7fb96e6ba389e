"""Sparse consensus exchanges: each agent's links as a neighbour list of a fixed length K.

The dense path of :mod:`mcjax.tracking.filters.consensus` sums over every agent, ``Σ_j W_ij v_j`` with an
(n, n) matrix: its cost grows with n². Here agent i keeps the first K agents it is linked to
(ascending index) as a list, and an exchange is a gather of those K neighbours' values and a
sum over the K slots: n·K terms, so the cost grows with the links, not with n². The weights
are the dense path's (the same equations, written per link); only the order of the sums
differs, so the results agree to round-off (~1e-15 relative), not bit for bit.

An agent with more than K links cannot be represented: its list's weights are NaN, so every
value it fuses is NaN — surfaced in the run's outputs (``nonfinite``), never a link silently
dropped. With ``K ≥ n − 1`` no agent can overflow.

Functions here take one run's arrays (agents on the leading axis); the engine vmaps over runs.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

EXCHANGES = ("dense", "sparse")


class NeighbourLists(NamedTuple):
    """One run's comm graph as neighbour lists (:func:`neighbour_lists`)."""

    index: jax.Array     # (n, K) int32: the agent in slot k of agent i's list (0 where unused)
    valid: jax.Array     # (n, K) bool: slot k holds a link
    weight: jax.Array    # (n, K) a_ij of that link (0 where unused; NaN on every slot of an overflowing agent)
    degree: jax.Array    # (n,) d_i = Σ_j a_ij over all of i's links
    overflow: jax.Array  # (n,) bool: agent i has more than K links


class SparseWeights(NamedTuple):
    """A consensus matrix ``W`` kept as its diagonal and its entries on the listed links."""

    lists: NeighbourLists
    own: jax.Array       # (n,) W_ii
    link: jax.Array      # (n, K) W_ij for j = lists.index[i, k] (0 where unused)


def neighbour_lists(adjacency: jax.Array, max_degree: int) -> NeighbourLists:
    """The links of ``adjacency`` (n, n; a_ij ≠ 0 is a link, the diagonal ignored) as lists of
    ``K = min(max_degree, n − 1)`` slots: slot k of agent i holds its (k+1)-th linked agent in
    ascending index. ``d_i = Σ_j a_ij`` is the degree of Sun et al. 2011 eq. 11. Every list
    entry is picked by a sum with a single non-zero term, so indices and weights are exact."""
    n = adjacency.shape[-1]
    k = max(1, min(int(max_degree), n - 1))
    a = jnp.where(jnp.eye(n, dtype=bool), jnp.zeros((), adjacency.dtype), adjacency)
    linked = a != 0
    slot = jnp.cumsum(linked, axis=-1) - 1                          # (n, n): slot of link i–j in i's list
    hit = linked[:, :, None] & (slot[:, :, None] == jnp.arange(k))  # (n, n, K)
    index = jnp.sum(jnp.where(hit, jnp.arange(n, dtype=jnp.int32)[None, :, None], 0), axis=1).astype(jnp.int32)
    weight = jnp.sum(jnp.where(hit, a[:, :, None], jnp.zeros((), a.dtype)), axis=1)
    count = jnp.sum(linked, axis=-1)
    overflow = count > k
    weight = jnp.where(overflow[:, None], jnp.nan, weight)
    return NeighbourLists(index, jnp.arange(k) < count[:, None], weight, jnp.sum(a, axis=-1), overflow)


def neighbour_sum(lists: NeighbourLists, link: jax.Array, values: jax.Array) -> jax.Array:
    """``out_i = Σ_k link_ik values_{index_ik}`` over the K slots (unrolled over k), ``values``
    (n, ...): the sum ``Σ_{j ∈ N_i} w_ij v_j`` over agent i's neighbours."""
    extra = (1,) * (values.ndim - 1)
    out = None
    for k in range(lists.index.shape[-1]):
        term = link[:, k].reshape((-1,) + extra) * jnp.take(values, lists.index[:, k], axis=0)
        out = term if out is None else out + term
    return out


def mix(w: SparseWeights, values: jax.Array) -> jax.Array:
    """One consensus iteration ``v_i ← W_ii v_i + Σ_{j ∈ N_i} W_ij v_j`` (the sparse form of
    :func:`mcjax.tracking.numerics.weighted_agent_sum`; with eq. 11 weights, Sun et al. 2011 eq. 11)."""
    extra = (1,) * (values.ndim - 1)
    return w.own.reshape((-1,) + extra) * values + neighbour_sum(w.lists, w.link, values)


def inclusive_sum(lists: NeighbourLists, values: jax.Array) -> jax.Array:
    """``Σ_{j ∈ J_i} a_ij v_j`` with ``J_i = N_i ∪ {i}`` (a_ii = 1): the neighbourhood sums
    ``S_i = Σ_{J_i} U_j``, ``y_i = Σ_{J_i} u_j`` of the KCF (Olfati-Saber 2009; Chen & Lu 2013 eq. 8)."""
    return values + neighbour_sum(lists, lists.weight, values)


def sparse_weights(lists: NeighbourLists, kind: str, n_agents: int) -> SparseWeights:
    """The consensus matrix of ``kind`` on the listed links, the equations of
    :func:`mcjax.tracking.graph.consensus_weights` per link:

    * ``"eq11"`` (Sun et al. 2011 eq. 11): ``W_ij = a_ij/(1+d_i)``, ``W_ii = 1/(1+d_i)``;
    * ``"metropolis"``: ``W_ij = a_ij/(1+max(d_i,d_j))``, ``W_ii = 1 − Σ_{j≠i} W_ij``;
    * ``"max_degree"`` (Chen & Lu 2013 eq. 7): ``W_ij = a_ij/n``, ``W_ii = 1 − d_i/n``.
    """
    d, a = lists.degree, lists.weight
    if kind == "eq11":
        inv = 1.0 / (1.0 + d)
        return SparseWeights(lists, inv, a * inv[:, None])
    if kind == "metropolis":
        d_j = jnp.take(d, lists.index, axis=0)
        link = jnp.where(lists.valid, a / (1.0 + jnp.maximum(d[:, None], d_j)), 0.0)
        link = jnp.where(lists.overflow[:, None], jnp.nan, link)
        own = 1.0 - _slot_sum(link)
        return SparseWeights(lists, own, link)
    if kind == "max_degree":
        return SparseWeights(lists, 1.0 - d / n_agents, a / n_agents)
    raise ValueError(f"sparse_weights: kind must be one of 'eq11', 'metropolis', 'max_degree'; got {kind!r}")


def _slot_sum(x: jax.Array) -> jax.Array:
    out = x[:, 0]
    for k in range(1, x.shape[1]):
        out = out + x[:, k]
    return out


def component_sizes(lists: NeighbourLists) -> jax.Array:
    """Size of each agent's connected component, itself included (the weights ``n_i`` of
    ``contribution="component"``, docs/equations.md), by min-label propagation on the lists:
    every agent starts with its own index as label and takes, until no label changes, the
    smallest label among itself and its neighbours, then the label of its label (pointer
    jumping). Labels only decrease and stay inside the component, so the loop ends (at most
    n rounds; about the graph's diameter) with each component labelled by its smallest
    agent; ``n_i`` counts the agents sharing i's label. Exact integers, as
    :func:`mcjax.tracking.graph.component_sizes`, in O(n·K) per round instead of O(n³ log n)."""
    n = lists.index.shape[0]

    def body(carry):
        label, _ = carry
        seen = jnp.where(lists.valid, jnp.take(label, lists.index, axis=0), n)
        new = jnp.minimum(label, jnp.min(seen, axis=-1))
        new = jnp.take(new, new, axis=0)
        return new, jnp.any(new != label)

    label, _ = jax.lax.while_loop(lambda c: c[1], body, (jnp.arange(n, dtype=jnp.int32), jnp.asarray(True)))
    return jnp.sum(label[:, None] == label[None, :], axis=-1).astype(lists.weight.dtype)
