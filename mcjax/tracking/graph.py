"""Communication topology of a team and its metrics (docs/equations.md).

Every function is pure, jit- and vmap-friendly, and accepts any leading batch shape: agent
positions are ``(..., n, d)``, adjacency matrices ``(..., n, n)``. The only Python loops run
over the static number of agents ``n``. Results keep the floating dtype of the input
(float32 or float64); integer positions are promoted to JAX's default float.

Conventions:

* ``radius`` is a scalar (one comm range for everybody) or one range per agent, anything
  broadcastable to ``positions.shape[:-1]`` — so a batch of graphs with one scalar range
  each passes ``radius`` as ``(B, 1)``.
* An adjacency matrix is a float 0/1 matrix, symmetric, with a zero diagonal. Functions
  that take an adjacency ignore its diagonal (self-loops are dropped), so a matrix with
  ones on the diagonal gives the same result as the same matrix without them.
* Distances use :func:`mcjax.tracking.numerics.safe_norm`, so gradients stay finite (zero) when two
  agents coincide.
* Margins are in the units of the positions (metres in mcjax); the ``temperature`` of the
  smooth forms is in the same units.

The connectivity robustness R_I built on the link margins (widest paths) is
:mod:`mcjax.tracking.connectivity`'.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from mcjax.tracking.numerics import eigvalsh, matmul, require_x64, safe_norm

WEIGHT_KINDS = ("eq11", "metropolis", "max_degree")


# --------------------------------------------------------------------------- helpers


def _float_positions(positions) -> jax.Array:
    require_x64("mcjax.tracking.graph")
    positions = jnp.asarray(positions)
    if not jnp.issubdtype(positions.dtype, jnp.floating):
        positions = positions.astype(jnp.result_type(float))
    return positions


def _pair_range(positions: jax.Array, radius) -> jax.Array:
    """``R_ij = min(r_i, r_j)`` (..., n, n) in the dtype of ``positions``."""
    r = jnp.broadcast_to(jnp.asarray(radius, dtype=positions.dtype), positions.shape[:-1])
    return jnp.minimum(r[..., :, None], r[..., None, :])


def _offdiag_mask(n: int) -> jax.Array:
    return ~jnp.eye(n, dtype=bool)


def _clean_adjacency(adj) -> jax.Array:
    """Adjacency as a float array with its diagonal zeroed (self-loops dropped)."""
    require_x64("mcjax.tracking.graph")
    adj = jnp.asarray(adj)
    if not jnp.issubdtype(adj.dtype, jnp.floating):
        adj = adj.astype(jnp.result_type(float))
    return jnp.where(_offdiag_mask(adj.shape[-1]), adj, jnp.zeros((), adj.dtype))


# --------------------------------------------------------------------------- topology


def pairwise_distances(positions) -> jax.Array:
    """Inter-agent distances ``l_ij = ‖q_i − q_j‖`` (Sun et al. 2011 eq. 13).

    ``positions`` (..., n, d) -> (..., n, n), zero diagonal. Uses the double-``where`` safe
    norm, so ``jax.grad`` is finite (zero) where two agents coincide.
    """
    positions = _float_positions(positions)
    diff = positions[..., :, None, :] - positions[..., None, :, :]
    return safe_norm(diff, axis=-1)


def link_margins(positions, radius) -> jax.Array:
    """Signed link margins ``m_ij = min(r_i, r_j) − l_ij`` (Sun et al. 2011 eqs. 13–14).

    ``m_ij ≥ 0`` iff i and j are linked (eq. 13); a non-link has a negative margin. The
    diagonal is ``+inf`` (an agent is always "linked" to itself with infinite margin, the
    neutral element of the (max, min) path algebra used by :func:`pair_robustness`).
    Returns (..., n, n).
    """
    positions = _float_positions(positions)
    n = positions.shape[-2]
    m = _pair_range(positions, radius) - pairwise_distances(positions)
    return jnp.where(_offdiag_mask(n), m, jnp.inf)


def adjacency(positions, radius, alive=None) -> jax.Array:
    """Comm-graph adjacency: link i–j iff ``l_ij ≤ min(r_i, r_j)`` (Sun et al. 2011 eq. 13).

    ``positions`` (..., n, d); ``radius`` scalar or per agent (..., n); ``alive`` optional
    bool (..., n) — a dead agent has no links. Returns a float 0/1 matrix (..., n, n),
    symmetric, with a zero diagonal, in the dtype of ``positions``.
    """
    positions = _float_positions(positions)
    n = positions.shape[-2]
    linked = pairwise_distances(positions) <= _pair_range(positions, radius)
    linked = linked & _offdiag_mask(n)
    if alive is not None:
        alive = jnp.asarray(alive, dtype=bool)
        linked = linked & alive[..., :, None] & alive[..., None, :]
    return linked.astype(positions.dtype)


def hysteresis_adjacency(previous, positions, radius, epsilon) -> jax.Array:
    """Adjacency with hysteresis on new links (Lou et al. 2013 §1.1, edge rules 1–3).

    With ``R = min(r_i, r_j)``: a link that existed (``previous_ij = 1``) survives while
    ``l_ij < R`` and breaks when ``l_ij ≥ R`` (rule 3); a link that did not exist forms only
    when ``l_ij < R − ε`` (rule 2). Zero diagonal; symmetric when ``previous`` is. Note the
    strict inequality: an existing link at exactly ``l_ij = R`` breaks here, whereas
    :func:`adjacency` (Sun et al. 2011 eq. 13) keeps it. The initial graph (rule 1, ``l_ij < R``)
    is obtained by passing ``previous = 1`` everywhere. ``epsilon`` is a scalar or
    broadcastable to (..., n, n). Returns a float 0/1 matrix in the dtype of ``positions``.
    """
    positions = _float_positions(positions)
    n = positions.shape[-2]
    dist = pairwise_distances(positions)
    big_r = _pair_range(positions, radius)
    existed = jnp.asarray(previous) > 0.5
    keep = existed & (dist < big_r)
    form = dist < big_r - jnp.asarray(epsilon, dtype=positions.dtype)
    linked = (keep | form) & _offdiag_mask(n)
    return linked.astype(positions.dtype)


def degree(adj) -> jax.Array:
    """Degrees ``d_i = Σ_j a_ij`` (Sun et al. 2011 eq. 11; docs/equations.md).

    (..., n, n) -> (..., n); the diagonal (self-loops) is ignored.
    """
    return jnp.sum(_clean_adjacency(adj), axis=-1)


def laplacian(adj) -> jax.Array:
    """Graph Laplacian ``L = D − A`` (docs/equations.md; Sun et al. 2011 Figs. 6 and 10).

    (..., n, n) -> (..., n, n); the diagonal of ``adj`` is ignored.
    """
    a = _clean_adjacency(adj)
    n = a.shape[-1]
    eye = jnp.eye(n, dtype=a.dtype)
    return jnp.sum(a, axis=-1)[..., :, None] * eye - a


def algebraic_connectivity(adj) -> jax.Array:
    """Algebraic connectivity λ2, the second-smallest eigenvalue of ``L = D − A``.

    docs/equations.md (Sun et al. 2011 Figs. 6/10, Lou et al. 2013 "λ2 > 0"): λ2 = 0 iff the graph is
    disconnected. (..., n, n) -> (...,), via :func:`mcjax.tracking.numerics.eigvalsh` (LAPACK, on the
    calling thread). Round-off can make the eigenvalue of a disconnected graph a tiny negative
    number (~−1e−16); it is clipped to 0, so the result is always ≥ 0. Needs ``n ≥ 2`` (λ2 does
    not exist for one agent): a ``ValueError`` otherwise.
    """
    n = jnp.shape(adj)[-1]
    if n < 2:
        raise ValueError(f"algebraic_connectivity needs at least 2 agents, got adj with n={n}")
    lam = eigvalsh(laplacian(adj))
    return jnp.maximum(lam[..., 1], 0.0)


#: Teams up to this size get their component sizes by repeated squaring (one fused loop per
#: squaring, the program every built-in configuration was checked with); larger teams by label
#: propagation, O(n²) per round, about the graph's diameter in rounds, instead of O(n³) per squaring
#: (100 agents: 8 squarings of 10⁶ multiply–adds against 10⁴ comparisons per round).
SQUARING_MAX_AGENTS = 24


def component_sizes(adj) -> jax.Array:
    """Size of each agent's connected component, itself included (docs/equations.md).

    Up to :data:`SQUARING_MAX_AGENTS` agents: the boolean transitive closure of ``A ∨ I`` by
    repeated squaring — a static ``ceil(log2 n) + 1`` squarings, enough for paths of any length
    ≤ n − 1. Larger teams: min-label propagation (:func:`_component_labels`). Both give the same
    exact integers. (..., n, n) -> (..., n), in the float dtype of ``adj``. An isolated (e.g.
    dead) agent has size 1.
    """
    a = _clean_adjacency(adj)
    n = a.shape[-1]
    if n > SQUARING_MAX_AGENTS:
        label = _component_labels(a > 0.5)
        return jnp.sum(label[..., :, None] == label[..., None, :], axis=-1).astype(a.dtype)
    reach = (a > 0.5) | jnp.eye(n, dtype=bool)
    for _ in range(math.ceil(math.log2(max(n, 1))) + 1):
        r = reach.astype(a.dtype)
        reach = matmul(r, r) > 0.5  # integer counts ≤ n: exact in any float dtype
    return jnp.sum(reach, axis=-1).astype(a.dtype)


def _component_labels(linked) -> jax.Array:
    """Each agent's component labelled by its smallest agent index: every agent starts with its
    own index and takes, until no label changes, the smallest label among itself and its
    neighbours, then the label of that label (pointer jumping). Labels only decrease and stay
    inside the component, so the loop ends (at most n rounds; about the graph's diameter).
    ``linked`` (..., n, n) boolean -> (..., n) int32. Under ``vmap`` the loop runs until every
    graph of the batch is done (a finished graph's labels no longer change)."""
    n = linked.shape[-1]
    start = jnp.broadcast_to(jnp.arange(n, dtype=jnp.int32), linked.shape[:-1])

    def body(carry):
        label, _ = carry
        seen = jnp.min(jnp.where(linked, label[..., None, :], n), axis=-1)
        new = jnp.minimum(label, seen)
        new = jnp.take_along_axis(new, new, axis=-1)
        return new, jnp.any(new != label)

    label, _ = jax.lax.while_loop(lambda c: c[1], body, (start, jnp.asarray(True)))
    return label


# --------------------------------------------------------------------------- consensus weights


def laplacian_step_weights(adj) -> jax.Array:
    """Sun et al. 2011 eq. 11 as a matrix: ``x_i ← x_i − (1/(1+d_i)) Σ_j a_ij (x_i − x_j) = Σ_j W_ij x_j``.

    Sun et al. 2011 eq. 11: ``W_ij = a_ij/(1+d_i)`` for j ≠ i and
    ``W_ii = 1/(1+d_i)``. Row-stochastic but in general NOT doubly stochastic (the fixed
    point is the average weighted by ``1 + d_i``); kept as the paper has it
    (docs/equations.md). (..., n, n) -> (..., n, n).
    """
    a = _clean_adjacency(adj)
    n = a.shape[-1]
    d = jnp.sum(a, axis=-1)
    return (a + jnp.eye(n, dtype=a.dtype)) / (1.0 + d)[..., :, None]


def metropolis_weights(adj) -> jax.Array:
    """Metropolis weights ``W_ij = a_ij/(1+max(d_i,d_j))``, ``W_ii = 1 − Σ_{j≠i} W_ij``.

    docs/equations.md (the weights of Ren & Lv 2017, Ren & Lv 2017). Symmetric, non-negative
    and doubly stochastic for any undirected graph. (..., n, n) -> (..., n, n).
    """
    a = _clean_adjacency(adj)
    n = a.shape[-1]
    d = jnp.sum(a, axis=-1)
    off = a / (1.0 + jnp.maximum(d[..., :, None], d[..., None, :]))
    return off + jnp.eye(n, dtype=a.dtype) * (1.0 - jnp.sum(off, axis=-1))[..., :, None]


def max_degree_weights(adj) -> jax.Array:
    """Max-degree weights ``W_ij = a_ij/n``, ``W_ii = 1 − d_i/n`` (Chen & Lu 2013 eq. 7).

    Symmetric, non-negative, doubly stochastic. (..., n, n) -> (..., n, n).
    """
    a = _clean_adjacency(adj)
    n = a.shape[-1]
    d = jnp.sum(a, axis=-1)
    return a / n + jnp.eye(n, dtype=a.dtype) * (1.0 - d / n)[..., :, None]


_WEIGHT_FUNCTIONS = {
    "eq11": laplacian_step_weights,
    "metropolis": metropolis_weights,
    "max_degree": max_degree_weights,
}


def consensus_weights(adj, kind: str) -> jax.Array:
    """Consensus matrix of the given ``kind`` (docs/equations.md).

    ``"eq11"``: :func:`laplacian_step_weights` (Sun et al. 2011 eq. 11); ``"metropolis"``:
    :func:`metropolis_weights`; ``"max_degree"``: :func:`max_degree_weights` (Chen & Lu 2013
    eq. 7). ``kind`` is a Python string (static under ``jit``); anything else raises
    ``ValueError``.
    """
    try:
        fn = _WEIGHT_FUNCTIONS[kind]
    except (KeyError, TypeError):
        raise ValueError(
            f"consensus_weights: argument 'kind' must be one of {WEIGHT_KINDS}, got {kind!r}"
        ) from None
    return fn(adj)


# --------------------------------------------------------------------------- smooth links


def soft_adjacency(positions, radius, temperature, alive=None) -> jax.Array:
    """The comm graph of :func:`adjacency` (Sun et al. 2011 eq. 13) made smooth, for a
    scenario's relaxation switch: each link a weight ``a_ij = sigmoid(m_ij / T)`` in (0, 1), m
    the link margin of :func:`link_margins`, instead of the 0/1 test ``m_ij ≥ 0``. Zero
    diagonal; agents not ``alive`` (optional bool (..., n)) unlinked; finite gradients for
    coincident agents (the safe norm). (..., n, d) -> (..., n, n)."""
    n = positions.shape[-2]
    keep = ~jnp.eye(n, dtype=bool)
    if alive is not None:
        keep = keep & alive[..., :, None] & alive[..., None, :]
    return jnp.where(keep, jax.nn.sigmoid(link_margins(positions, radius) / temperature), 0.0)
