"""Connectivity robustness of a team's comm graph (Spanos & Murray 2004; Sun et al. 2011 eqs.
14–15): the widest multi-hop paths over the link margins (:func:`mcjax.tracking.graph.link_margins`), the
robustness R_I of each agent, exact and smooth (for gradient-based planning), over all pairs
(O(n³)) or on a maximum spanning tree (O(n²)); and the smooth component sizes built on them.

The conventions are :mod:`mcjax.tracking.graph`'s: positions ``(..., n, d)``, ``radius`` a scalar or
one per agent, margins and robustness in the units of the positions, the ``temperature`` of
the smooth forms in the same units.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from mcjax.tracking.graph import link_margins
from mcjax.tracking.numerics import softmin


def _offdiag_mask(n: int) -> jax.Array:
    return ~jnp.eye(n, dtype=bool)


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
    """Relaxation ρ(i,j): :func:`pair_robustness` with max/min replaced by soft forms.

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
        # mcjax.tracking.numerics.softmin / softmax_value of two values, written with logaddexp: the same
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
    """Relaxation ``R_I(i) ≈ ½ min_{j ∈ N_I(i)} ρ(i,j)`` for gradient-based planning.

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


def soft_component_sizes(positions, radius, temperature, alive=None) -> jax.Array:
    """Relaxation size of each agent's connected component: ``1 + Σ_{j≠i} sigmoid(ρ_ij/T)`` with ρ
    the smooth multi-hop pair robustness (Sun et al. 2011 eq. 14, :func:`smooth_pair_robustness`):
    j is in i's component iff ρ_ij ≥ 0, and sigmoid(ρ/T) is the widest path of the links of
    :func:`mcjax.tracking.graph.soft_adjacency` (sigmoid is monotone). Agents not ``alive`` count for none, but
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
