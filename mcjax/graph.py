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
* Distances use :func:`mcjax.numerics.safe_norm`, so gradients stay finite (zero) when two
  agents coincide.
* Margins and robustness values are in the units of the positions (metres in mcjax); the
  ``temperature`` of the smooth forms is in the same units.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from mcjax.numerics import matmul, require_x64, safe_norm, softmin

WEIGHT_KINDS = ("eq11", "metropolis", "max_degree")


# --------------------------------------------------------------------------- helpers


def _float_positions(positions) -> jax.Array:
    require_x64("mcjax.graph")
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
    require_x64("mcjax.graph")
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
    disconnected. (..., n, n) -> (...,), via ``jnp.linalg.eigvalsh``. Round-off can make the
    eigenvalue of a disconnected graph a tiny negative number (~−1e−16); it is clipped to 0,
    so the result is always ≥ 0. Needs ``n ≥ 2`` (λ2 does not exist for one agent): a
    ``ValueError`` otherwise.
    """
    n = jnp.shape(adj)[-1]
    if n < 2:
        raise ValueError(f"algebraic_connectivity needs at least 2 agents, got adj with n={n}")
    lam = jnp.linalg.eigvalsh(laplacian(adj))
    return jnp.maximum(lam[..., 1], 0.0)


def component_sizes(adj) -> jax.Array:
    """Size of each agent's connected component, itself included (docs/equations.md).

    Boolean transitive closure of ``A ∨ I`` by repeated squaring — a static
    ``ceil(log2 n) + 1`` squarings, enough for paths of any length ≤ n − 1. (..., n, n) ->
    (..., n), in the float dtype of ``adj``. An isolated (e.g. dead) agent has size 1.
    """
    a = _clean_adjacency(adj)
    n = a.shape[-1]
    reach = (a > 0.5) | jnp.eye(n, dtype=bool)
    for _ in range(math.ceil(math.log2(max(n, 1))) + 1):
        r = reach.astype(a.dtype)
        reach = matmul(r, r) > 0.5  # integer counts ≤ n: exact in any float dtype
    return jnp.sum(reach, axis=-1).astype(a.dtype)


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


# --------------------------------------------------------------------------- connectivity robustness


def pair_robustness(positions, radius) -> jax.Array:
    """Pair robustness ρ(i,j): the widest (max over paths of the min link margin) path.

    Spanos & Murray 2004; Sun et al. 2011 eq. 14 extended to multi-hop paths as
    in docs/equations.md. Paths run over the complete graph with signed margins
    ``m_ij = min(r_i, r_j) − l_ij`` (:func:`link_margins`), so ρ(i,j) ≥ 0 iff a path of
    links joins i and j, and otherwise −ρ(i,j) is the least extra range (added to every
    agent) that would join them. Exact, by Floyd–Warshall in the (max, min) semiring:
    ``ρ ← max(ρ, min(ρ[:, k], ρ[k, :]))`` for k = 1..n (a static loop). Diagonal ``+inf``.
    (..., n, d) -> (..., n, n).
    """
    rho = link_margins(positions, radius)
    n = rho.shape[-1]
    for k in range(n):
        rho = jnp.maximum(rho, jnp.minimum(rho[..., :, k, None], rho[..., None, k, :]))
    return rho


def _info_mask(n: int, info_neighbours) -> jax.Array:
    mask = _offdiag_mask(n)
    if info_neighbours is not None:
        mask = mask & jnp.asarray(info_neighbours, dtype=bool)
    return mask


def connectivity_robustness(positions, radius, info_neighbours=None) -> jax.Array:
    """Connectivity robustness ``R_I(i) = ½ min_{j ∈ N_I(i), j≠i} ρ(i,j)``.

    Sun et al. 2011 eq. 15 (Spanos & Murray 2004), with ρ the exact multi-hop pair
    robustness of :func:`pair_robustness` (docs/equations.md). ``info_neighbours``:
    optional bool (..., n, n) mask of the information neighbours N_I(i) (row i), default
    every other agent. An agent with no information neighbour gets ``+inf``. ``radius``
    scalar or per agent. (..., n, d) -> (..., n).
    """
    rho = pair_robustness(positions, radius)
    mask = _info_mask(rho.shape[-1], info_neighbours)
    return 0.5 * jnp.min(jnp.where(mask, rho, jnp.inf), axis=-1)


@functools.lru_cache(maxsize=None)
def _pair_tables(n: int):
    """Index tables of the unordered pairs i < j of n agents: ``(I, J)`` the pairs, ``ID`` (n, n)
    the pair index of (i, j) and (j, i) (0 on the diagonal, which callers mask), and per
    relaxation agent k the pairs not involving k (``SEL`` (n, Q)) with the pair indices of
    (i, k) and (k, j) (``A``, ``B``), Q = (n − 1)(n − 2)/2."""
    I, J = np.triu_indices(n, 1)
    ID = np.zeros((n, n), np.int32)
    ID[I, J] = ID[J, I] = np.arange(len(I))
    sel = [[p for p in range(len(I)) if k not in (I[p], J[p])] for k in range(n)]
    SEL = np.asarray(sel, np.int32).reshape(n, -1)
    A = ID[I[SEL], np.arange(n)[:, None]]
    B = ID[np.arange(n)[:, None], J[SEL]]
    return I, J, ID, SEL, A, B


def smooth_pair_robustness(positions, radius, temperature) -> jax.Array:
    """Smooth ρ(i,j): :func:`pair_robustness` with max/min replaced by soft forms.

    Spanos & Murray 2004; Sun et al. 2011 eq. 14, multi-hop as in
    docs/equations.md. The Floyd–Warshall update becomes
    ``ρ_ij ← softmax_T(ρ_ij, softmin_T(ρ_ik, ρ_kj))`` for k ∉ {i, j} (the k = i, j updates
    are no-ops of the exact recursion and are skipped, so no ``T log 2`` bias is added
    there). Every soft operation is within ``T log 2`` of the hard one and both are
    1-Lipschitz, so ``|ρ_T − ρ| ≤ 2 n T log 2``. ``temperature`` T > 0 is a scalar (``vmap``
    for one per graph). ρ is symmetric (the margins are, and so is each update), so the
    recursion runs on the n(n − 1)/2 unordered pairs only, and for each k on the pairs that do
    not involve k — the same operations on the same numbers as on the full matrix, about 4×
    fewer. No infinity enters a soft operation (the diagonal is never touched), so ``jax.grad``
    is finite, also with coincident agents. Diagonal ``+inf`` on output. (..., n, d) -> (..., n, n).
    """
    m = link_margins(positions, radius)
    n = m.shape[-1]
    I, J, ID, SEL, A, B = _pair_tables(n)
    if n < 2:  # no pair: nothing to be robust about
        return jnp.full(m.shape, jnp.inf, m.dtype)
    rho = m[..., I, J]  # (..., P): one entry per unordered pair
    t = jnp.asarray(temperature, dtype=m.dtype)
    tables = jnp.asarray(np.stack([SEL, A, B]))  # (3, n, Q)

    def relax(k, rho):
        s, a, b = tables[:, k]
        # mcjax.numerics.softmin / softmax_value of two values, written with logaddexp: the same
        # functions, but fewer operations (about half the compile time).
        via_k = -t * jnp.logaddexp(-rho[..., a] / t, -rho[..., b] / t)
        widened = t * jnp.logaddexp(rho[..., s] / t, via_k / t)
        return rho.at[..., s].set(widened)

    if SEL.shape[1]:  # n ≥ 3: there are paths through a third agent
        # A fori_loop with static bounds (a scan, so reverse-differentiable): compile time does
        # not grow with n, unlike the unrolled loop of the exact version.
        rho = jax.lax.fori_loop(0, n, relax, rho)
    return jnp.where(_offdiag_mask(n), rho[..., ID], jnp.inf)


def smooth_connectivity_robustness(positions, radius, temperature, info_neighbours=None) -> jax.Array:
    """Smooth ``R_I(i) ≈ ½ min_{j ∈ N_I(i)} ρ(i,j)`` for gradient-based planning.

    Sun et al. 2011 eq. 15 (Spanos & Murray 2004) with every max/min — in the
    Floyd–Warshall recursion (:func:`smooth_pair_robustness`) and in the outer minimum —
    replaced by ``softmax_value`` / ``softmin`` at ``temperature`` T (same units as the
    positions). Tends to :func:`connectivity_robustness` as T → 0, within
    ``½ (2 n log 2 + log(n − 1)) T``; it is neither an upper nor a lower bound. ``jax.grad``
    with respect to positions is finite, also when agents coincide; an agent with no
    information neighbour gets ``+inf`` (with zero gradient). (..., n, d) -> (..., n).
    """
    rho = smooth_pair_robustness(positions, radius, temperature)
    temperature = jnp.asarray(temperature, dtype=rho.dtype)
    n = rho.shape[-1]
    mask = jnp.broadcast_to(_info_mask(n, info_neighbours), rho.shape)
    any_valid = jnp.any(mask, axis=-1)
    # Masked entries -> +inf (weight exactly 0 in the softmin); rows with no valid entry are
    # replaced by zeros before the softmin so that no all-(-inf) logsumexp yields NaN gradients.
    x = jnp.where(mask, rho, jnp.inf)
    x = jnp.where(any_valid[..., None], x, jnp.zeros((), rho.dtype))
    r = 0.5 * softmin(x, temperature, axis=-1)
    return jnp.where(any_valid, r, jnp.inf)


def soft_adjacency(positions, radius, temperature, alive=None) -> jax.Array:
    """The comm graph of :func:`adjacency` (Sun et al. 2011 eq. 13) made smooth, for a
    scenario's smoothing switch: each link a weight ``a_ij = sigmoid(m_ij / T)`` in (0, 1), m
    the link margin of :func:`link_margins`, instead of the 0/1 test ``m_ij ≥ 0``. Zero
    diagonal; agents not ``alive`` (optional bool (..., n)) unlinked; finite gradients for
    coincident agents (the safe norm). (..., n, d) -> (..., n, n)."""
    n = positions.shape[-2]
    keep = ~jnp.eye(n, dtype=bool)
    if alive is not None:
        keep = keep & alive[..., :, None] & alive[..., None, :]
    return jnp.where(keep, jax.nn.sigmoid(link_margins(positions, radius) / temperature), 0.0)


def soft_component_sizes(positions, radius, temperature, alive=None) -> jax.Array:
    """Smooth size of each agent's connected component: ``1 + Σ_{j≠i} sigmoid(ρ_ij/T)`` with ρ
    the smooth multi-hop pair robustness (Sun et al. 2011 eq. 14, :func:`smooth_pair_robustness`):
    j is in i's component iff ρ_ij ≥ 0, and sigmoid(ρ/T) is the widest path of the links of
    :func:`soft_adjacency` (sigmoid is monotone). Agents not ``alive`` count for none, but
    paths through them are not excluded. (n, d) -> (n,)."""
    n = positions.shape[-2]
    rho = smooth_pair_robustness(positions, radius, temperature)
    keep = ~jnp.eye(n, dtype=bool)
    if alive is not None:
        keep = keep & alive[:, None] & alive[None, :]
    reach = jnp.where(keep, jax.nn.sigmoid(jnp.where(keep, rho, 0.0) / temperature), 0.0)
    return 1.0 + jnp.sum(reach, axis=-1)


# --------------------------------------------------------------------------- robustness on a spanning tree


def _widest_tree(margins, root):
    """Prim's algorithm for the maximum spanning tree of the complete graph with link margins
    ``margins`` (n, n), grown from ``root``: ``(parent, order, width)`` — each agent's parent
    in the tree (the root its own), the agents in the order they joined, and
    ``width[v] = ρ(root, v)``, the widest-path value of :func:`pair_robustness` (the least key
    taken so far when v joins: every root–v path crosses each earlier cut, whose widest
    crossing link is that key, and the tree path attains it). O(n²), n sequential steps."""
    n = margins.shape[-1]
    dtype = margins.dtype
    in_tree = jnp.arange(n) == root
    key = jnp.where(in_tree, -jnp.inf, margins[root])
    parent = jnp.full(n, root)
    width = jnp.full(n, jnp.inf, dtype)
    order = jnp.full(n, root)

    def add(t, c):
        in_tree, key, parent, width, order, run = c
        v = jnp.argmax(jnp.where(in_tree, -jnp.inf, key))
        run = jnp.minimum(run, key[v])
        width, order, in_tree = width.at[v].set(run), order.at[t].set(v), in_tree.at[v].set(True)
        better = (margins[v] > key) & ~in_tree
        return in_tree, jnp.where(better, margins[v], key), jnp.where(better, v, parent), width, order, run

    init = (in_tree, key, parent, width, order, jnp.asarray(jnp.inf, dtype))
    _, _, parent, width, order, _ = jax.lax.fori_loop(1, n, add, init)
    return parent, order, width


def _alive_root(n: int, alive):
    alive = jnp.ones(n, bool) if alive is None else jnp.asarray(alive, bool)
    return alive, jnp.argmax(alive), jnp.sum(alive) >= 2


def tree_connectivity_robustness(positions, radius, alive=None) -> jax.Array:
    """:func:`connectivity_robustness` with the information neighbours N_I(i) = every other agent
    alive (Sun et al. 2011 eq. 15, Spanos & Murray 2004), in O(n²) instead of O(n³): the same
    numbers, bit for bit. The widest paths ρ are those of a maximum spanning tree of the margins
    (:func:`_widest_tree`), and since ρ is an ultrametric (ρ_ij ≥ min(ρ_ik, ρ_kj)), the least ρ
    from any alive agent to the other alive ones is one number B = min over alive j of ρ(root, j):
    ``R_I(i) = B/2`` for every alive agent; ``+inf`` for the others, and for all when fewer than
    two are alive. Paths may run through agents not alive, as in :func:`pair_robustness`.
    ``alive`` optional bool (n,). (n, d) -> (n,)."""
    m = link_margins(positions, radius)
    n = m.shape[-1]
    alive, root, some = _alive_root(n, alive)
    _, _, width = _widest_tree(m, root)
    b = jnp.min(jnp.where(alive & (jnp.arange(n) != root), width, jnp.inf))
    return jnp.where(alive & some, 0.5 * b, jnp.inf)


def smooth_tree_connectivity_robustness(positions, radius, temperature, alive=None) -> jax.Array:
    """A smooth ``R_I`` (Sun et al. 2011 eq. 15, Spanos & Murray 2004) on a maximum spanning
    tree, O(n²) per evaluation where :func:`smooth_connectivity_robustness` is O(n³).

    Exactly, ``R_I(i) = B/2`` for every alive agent with B the weakest link of the spanning tree
    joining the alive agents (:func:`tree_connectivity_robustness`). Here the tree (its
    topology: which links) is that of the exact margins and held fixed, and the minimum over
    its links (those whose removal separates two alive agents) is replaced by ``softmin_T``:
    ``R_I(i) = ½ softmin_T(m_e, e in tree)``, within ``½ T log(n − 1)`` below the exact value.
    Gradients flow through the tree's link margins only; the tree changes where two margins
    tie, and there the surrogate jumps by at most that bound. ``+inf`` (zero gradient) for
    agents not alive, and for all when fewer than two are alive. ``alive`` optional bool (n,);
    ``temperature`` T > 0 a scalar. (n, d) -> (n,)."""
    m = link_margins(positions, radius)
    n = m.shape[-1]
    alive, root, some = _alive_root(n, alive)
    parent, order, _ = _widest_tree(jax.lax.stop_gradient(m), root)

    def up(t, has):  # children before parents: does v's subtree hold an alive agent?
        v = order[n - t]
        return has.at[parent[v]].set(has[parent[v]] | has[v])

    has = jax.lax.fori_loop(1, n, up, alive)
    needed = has & (jnp.arange(n) != root)  # the link v–parent(v) separates alive v-side from the root
    x = jnp.where(needed, m[jnp.arange(n), parent], jnp.inf)
    x = jnp.where(some, x, jnp.zeros((), m.dtype))
    r = 0.5 * softmin(x, jnp.asarray(temperature, m.dtype), axis=-1)
    return jnp.where(alive & some, r, jnp.inf)
