"""Tests of mcjax.tracking.graph against independent references (numpy loops, networkx, brute force).

To keep the file fast, the random graphs are drawn in groups of one agent count n each and
every group goes through ONE jit-compiled call with a leading batch axis (compiling per
graph shape dominates the run time otherwise); the references are computed graph by graph.
"""

from __future__ import annotations

import functools
import itertools
import math

import jax
import jax.numpy as jnp
import networkx as nx
import numpy as np
import pytest

from mcjax.tracking import connectivity, graph

jax.config.update("jax_enable_x64", True)

# Compiling dominates the run time of this file, so the test-only jits ask XLA for a quick,
# unoptimised compile (a per-jit option, nothing global; results agree to rounding).
FAST = {"xla_backend_optimization_level": 0, "xla_llvm_disable_expensive_passes": True}


def fast_jit(fn, **kwargs):
    return jax.jit(fn, compiler_options=FAST, **kwargs)


class F:
    """Fast-compiled versions of the public functions, for the hand-made examples."""

    adjacency = staticmethod(fast_jit(graph.adjacency))
    algebraic_connectivity = staticmethod(fast_jit(graph.algebraic_connectivity))
    component_sizes = staticmethod(fast_jit(graph.component_sizes))
    hysteresis_adjacency = staticmethod(fast_jit(graph.hysteresis_adjacency))
    laplacian_step_weights = staticmethod(fast_jit(graph.laplacian_step_weights))
    metropolis_weights = staticmethod(fast_jit(graph.metropolis_weights))
    max_degree_weights = staticmethod(fast_jit(graph.max_degree_weights))
    consensus_weights = staticmethod(fast_jit(graph.consensus_weights, static_argnames="kind"))
    pair_robustness = staticmethod(fast_jit(connectivity.pair_robustness))
    connectivity_robustness = staticmethod(fast_jit(connectivity.connectivity_robustness))
    smooth_connectivity_robustness = staticmethod(fast_jit(connectivity.smooth_connectivity_robustness))


N_RANGE = range(2, 9)  # agent counts of the random groups
GROUP = 24  # graphs per group
HYST_EPS = 1.0


# --------------------------------------------------------------------------- references


def np_adjacency(pos, radius, alive=None):
    """Link i–j iff ‖q_i − q_j‖ ≤ min(r_i, r_j): plain double loop."""
    n = len(pos)
    r = np.broadcast_to(np.asarray(radius, dtype=float), (n,))
    a = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            if i == j:
                continue
            if alive is not None and not (alive[i] and alive[j]):
                continue
            if math.dist(pos[i], pos[j]) <= min(r[i], r[j]):
                a[i, j] = 1.0
    return a


def np_margins(pos, radius):
    n = len(pos)
    r = np.broadcast_to(np.asarray(radius, dtype=float), (n,))
    m = np.full((n, n), np.inf)
    for i in range(n):
        for j in range(n):
            if i != j:
                m[i, j] = min(r[i], r[j]) - math.dist(pos[i], pos[j])
    return m


def np_laplacian(a):
    return np.diag(a.sum(axis=1)) - a


def to_nx(a):
    g = nx.Graph()
    g.add_nodes_from(range(len(a)))
    g.add_edges_from((i, j) for i in range(len(a)) for j in range(i + 1, len(a)) if a[i, j] > 0)
    return g


def brute_force_rho(m):
    """Widest path by enumerating every simple path i -> (ordered intermediates) -> j."""
    n = len(m)
    rho = np.full((n, n), np.inf)
    for i in range(n):
        for j in range(n):
            if i == j:
                continue
            others = [k for k in range(n) if k not in (i, j)]
            best = -np.inf
            for length in range(len(others) + 1):
                for mid in itertools.permutations(others, length):
                    path = (i, *mid, j)
                    best = max(best, min(m[path[s], path[s + 1]] for s in range(len(path) - 1)))
            rho[i, j] = best
    return rho


def brute_force_robustness(rho, info=None):
    n = len(rho)
    out = np.empty(n)
    for i in range(n):
        vals = [rho[i, j] for j in range(n) if j != i and (info is None or info[i, j])]
        out[i] = 0.5 * min(vals) if vals else np.inf
    return out


# --------------------------------------------------------------------------- the random groups


def _metrics(pos, radius, alive, info, prev, eps):
    """Everything the random-graph tests check, for a batch of graphs (leading axis)."""
    adj = graph.adjacency(pos, radius)
    return {
        "dist": graph.pairwise_distances(pos),
        "adj": adj,
        "adj_alive": graph.adjacency(pos, radius, alive),
        "margins": graph.link_margins(pos, radius),
        "degree": graph.degree(adj),
        "laplacian": graph.laplacian(adj),
        "lambda2": graph.algebraic_connectivity(adj),
        "sizes": graph.component_sizes(adj),
        "sizes_alive": graph.component_sizes(graph.adjacency(pos, radius, alive)),
        "eq11": graph.consensus_weights(adj, "eq11"),
        "metropolis": graph.consensus_weights(adj, "metropolis"),
        "max_degree": graph.consensus_weights(adj, "max_degree"),
        "hyst": graph.hysteresis_adjacency(prev, pos, radius, eps),
        "rho": connectivity.pair_robustness(pos, radius),
        "r_i": connectivity.connectivity_robustness(pos, radius),
        "r_i_info": connectivity.connectivity_robustness(pos, radius, info),
    }


_metrics_j = fast_jit(_metrics)
adjacency_j = fast_jit(graph.adjacency)
smooth_j = fast_jit(connectivity.smooth_connectivity_robustness)


@functools.lru_cache(maxsize=None)
def group(n):
    """GROUP random graphs on n agents: inputs (numpy) and outputs (numpy)."""
    rng = np.random.default_rng(1000 + n)
    d = 2 if n % 2 == 0 else 3
    pos = rng.uniform(0.0, 10.0, size=(GROUP, n, d))
    # first half: one range for everybody (passed per agent), second half: per-agent ranges
    radius = rng.uniform(2.0, 9.0, size=(GROUP, n))
    radius[: GROUP // 2] = radius[: GROUP // 2, :1]
    alive = rng.random((GROUP, n)) < 0.7
    info = rng.random((GROUP, n, n)) < 0.5
    prev = np.triu(rng.random((GROUP, n, n)) < 0.5, 1).astype(float)
    prev = prev + np.swapaxes(prev, -1, -2)
    inputs = dict(pos=pos, radius=radius, alive=alive, info=info, prev=prev)
    out = _metrics_j(pos, radius, alive, info, prev, HYST_EPS)
    return inputs, {k: np.asarray(v) for k, v in out.items()}


def all_graphs(n_max=8):
    for n in N_RANGE:
        if n > n_max:
            continue
        inputs, out = group(n)
        for b in range(GROUP):
            yield {k: v[b] for k, v in inputs.items()}, {k: v[b] for k, v in out.items()}


# --------------------------------------------------------------------------- topology


def test_pairwise_distances_vs_numpy():
    for x, o in all_graphs():
        ref = np.array([[math.dist(p, q) for q in x["pos"]] for p in x["pos"]])
        np.testing.assert_allclose(o["dist"], ref, rtol=1e-13, atol=1e-14)


def test_adjacency_and_margins_vs_numpy_loop():
    n_edges = n_non_edges = 0
    for x, o in all_graphs():
        ref = np_adjacency(x["pos"], x["radius"])
        np.testing.assert_array_equal(o["adj"], ref)
        assert o["adj"].dtype == np.float64
        np.testing.assert_array_equal(o["adj"], o["adj"].T)
        assert np.all(np.diag(o["adj"]) == 0)
        off = ~np.eye(len(ref), dtype=bool)
        n_edges += ref[off].sum()
        n_non_edges += (1 - ref[off]).sum()
        np.testing.assert_allclose(o["margins"], np_margins(x["pos"], x["radius"]), rtol=1e-12, atol=1e-12)
        assert np.all(np.isposinf(np.diag(o["margins"])))
        np.testing.assert_array_equal(o["margins"][off] >= 0, ref[off] > 0)
    assert n_edges > 100 and n_non_edges > 100  # the random cases are not degenerate


def test_adjacency_scalar_and_per_agent_radius():
    pos = np.array([[0.0, 0.0], [5.0, 0.0], [0.0, 3.0]])
    # 0-1 at 5: r0=10, r1=4 -> min 4 < 5, no link; 0-2 at 3: min(10, 3) = 3 -> link (<=).
    a = np.asarray(F.adjacency(pos, np.array([10.0, 4.0, 3.0])))
    np.testing.assert_array_equal(a, [[0, 0, 1], [0, 0, 0], [1, 0, 0]])
    # scalar radius 5: every pair within 5 except 1-2 (√34)
    a = np.asarray(F.adjacency(pos, 5.0))
    np.testing.assert_array_equal(a, [[0, 1, 1], [1, 0, 0], [1, 0, 0]])


def test_adjacency_alive_mask():
    dead_seen = 0
    for x, o in all_graphs():
        alive = x["alive"]
        np.testing.assert_array_equal(o["adj_alive"], np_adjacency(x["pos"], x["radius"], alive))
        assert np.all(o["adj_alive"][~alive] == 0) and np.all(o["adj_alive"][:, ~alive] == 0)
        assert np.all(o["sizes_alive"][~alive] == 1)
        dead_seen += (~alive).sum()
    assert dead_seen > 20


def test_degree_and_laplacian_vs_numpy():
    for _, o in all_graphs():
        a = o["adj"]
        np.testing.assert_array_equal(o["degree"], a.sum(axis=1))
        np.testing.assert_array_equal(o["laplacian"], np_laplacian(a))


def test_lambda2_vs_numpy_and_networkx():
    seen = {True: 0, False: 0}
    for _, o in all_graphs():
        a = o["adj"]
        ref = np.linalg.eigvalsh(np_laplacian(a))[1]
        assert o["lambda2"] == pytest.approx(max(ref, 0.0), abs=1e-10)
        assert o["lambda2"] >= 0.0
        connected = nx.is_connected(to_nx(a))
        assert (o["lambda2"] > 1e-9) == connected
        seen[connected] += 1
    assert seen[True] > 20 and seen[False] > 20


def test_lambda2_known_values():
    # Path on 4 nodes: λ2 = 2(1 − cos(π/4)); complete graph K5: λ2 = 5.
    path = np.diag(np.ones(3), 1)
    path = path + path.T
    assert float(F.algebraic_connectivity(path)) == pytest.approx(2 * (1 - math.cos(math.pi / 4)))
    k5 = np.ones((5, 5)) - np.eye(5)
    assert float(F.algebraic_connectivity(k5)) == pytest.approx(5.0)
    with pytest.raises(ValueError):
        graph.algebraic_connectivity(np.zeros((1, 1)))


def test_component_sizes_vs_networkx():
    for _, o in all_graphs():
        a = o["adj"]
        ref = np.zeros(len(a))
        for comp in nx.connected_components(to_nx(a)):
            for v in comp:
                ref[v] = len(comp)
        assert o["sizes"].dtype == np.float64
        np.testing.assert_array_equal(o["sizes"], ref)


def test_component_sizes_long_path_needs_all_squarings():
    # A path of 8 nodes in scrambled order: the closure must span 7 hops.
    order = [3, 0, 6, 1, 7, 2, 5, 4]
    a = np.zeros((8, 8))
    for u, v in zip(order[:-1], order[1:]):
        a[u, v] = a[v, u] = 1.0
    np.testing.assert_array_equal(np.asarray(F.component_sizes(a)), np.full(8, 8.0))
    a[7, 2] = a[2, 7] = 0.0  # cut it: {3, 0, 6, 1, 7} and {2, 5, 4}
    np.testing.assert_array_equal(np.asarray(F.component_sizes(a)), [5, 5, 3, 5, 3, 3, 5, 5])


def test_component_sizes_of_large_teams_by_label_propagation_vs_networkx():
    """Above ``SQUARING_MAX_AGENTS`` the sizes come from label propagation: the same exact
    integers as networkx on random graphs from nearly empty to dense, a batch at once (the loop
    runs until every graph of it is done), a long path in scrambled order (as many rounds as
    hops) and a path cut in two; no gradient flows through the sizes."""
    n = graph.SQUARING_MAX_AGENTS + 16
    rng = np.random.default_rng(7)
    batch = []
    for p in (0.0, 0.02, 0.05, 0.1, 0.4):
        a = np.triu(rng.random((n, n)) < p, 1)
        batch.append((a | a.T).astype(float))
    order = rng.permutation(n)
    path = np.zeros((n, n))
    for u, v in zip(order[:-1], order[1:]):
        path[u, v] = path[v, u] = 1.0
    cut = path.copy()
    cut[order[9], order[10]] = cut[order[10], order[9]] = 0.0
    batch += [path, cut]
    got = np.asarray(F.component_sizes(np.stack(batch)))
    for a, sizes in zip(batch, got):
        ref = np.zeros(n)
        for comp in nx.connected_components(to_nx(a)):
            ref[list(comp)] = len(comp)
        np.testing.assert_array_equal(sizes, ref)
    assert set(got[-1]) == {10.0, n - 10.0}
    pos = jnp.asarray(rng.random((n, 2)) * 4.0)
    g = np.asarray(jax.grad(lambda q: jnp.sum(graph.component_sizes(graph.adjacency(q, 1.0)) * q[:, 0]))(pos))
    # reverse mode runs through the loop; the sizes are constants to the gradient
    np.testing.assert_array_equal(g[:, 0], np.asarray(graph.component_sizes(graph.adjacency(pos, 1.0))))
    np.testing.assert_array_equal(g[:, 1], 0.0)


@fast_jit
def _adjacency_metrics(a):
    return [graph.degree(a), graph.laplacian(a), graph.component_sizes(a), graph.algebraic_connectivity(a),
            graph.laplacian_step_weights(a), graph.metropolis_weights(a), graph.max_degree_weights(a)]


def test_self_loops_are_ignored():
    a = group(6)[1]["adj"]  # a batch of graphs
    plain = _adjacency_metrics(a)
    looped = _adjacency_metrics(a + np.eye(6))
    for x, y in zip(plain, looped):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


# --------------------------------------------------------------------------- hysteresis


def test_hysteresis_band_explicit():
    radius, eps = 10.0, 2.0
    for dist, kept, created in [
        (9.0, 1, 0),  # R − ε < l < R: kept if it existed, not created
        (8.5, 1, 0),
        (10.0, 0, 0),  # l = R: an existing link breaks (l ≥ R)
        (10.5, 0, 0),
        (7.5, 1, 1),  # l < R − ε: created
        (8.0, 1, 0),  # l = R − ε exactly: not created (strict)
    ]:
        pos = np.array([[0.0, 0.0], [dist, 0.0]])
        on = np.array([[0.0, 1.0], [1.0, 0.0]])
        off = np.zeros((2, 2))
        assert np.asarray(F.hysteresis_adjacency(on, pos, radius, eps))[0, 1] == kept, dist
        assert np.asarray(F.hysteresis_adjacency(off, pos, radius, eps))[0, 1] == created, dist
        assert np.all(np.diag(np.asarray(F.hysteresis_adjacency(np.ones((2, 2)), pos, radius, eps))) == 0)


def test_hysteresis_vs_numpy_rule():
    band_kept = band_refused = 0
    for x, o in all_graphs():
        pos, prev = x["pos"], x["prev"]
        n = len(pos)
        r = x["radius"]
        ref = np.zeros((n, n))
        for i in range(n):
            for j in range(n):
                if i == j:
                    continue
                big_r, l = min(r[i], r[j]), math.dist(pos[i], pos[j])
                in_band = big_r - HYST_EPS <= l < big_r
                band_kept += in_band and prev[i, j] == 1
                band_refused += in_band and prev[i, j] == 0
                ref[i, j] = float((prev[i, j] == 1 and l < big_r) or l < big_r - HYST_EPS)
        np.testing.assert_array_equal(o["hyst"], ref)
        np.testing.assert_array_equal(o["hyst"], o["hyst"].T)
    assert band_kept > 20 and band_refused > 20


# --------------------------------------------------------------------------- consensus weights


def test_metropolis_weights():
    for _, o in all_graphs():
        a, w = o["adj"], o["metropolis"]
        n = len(a)
        d = a.sum(1)
        ref = np.zeros((n, n))
        for i in range(n):
            for j in range(n):
                if i != j and a[i, j]:
                    ref[i, j] = 1.0 / (1.0 + max(d[i], d[j]))
            ref[i, i] = 1.0 - ref[i].sum()
        np.testing.assert_allclose(w, ref, atol=1e-15)
        np.testing.assert_allclose(w, w.T, atol=1e-15)
        np.testing.assert_allclose(w.sum(0), 1.0, atol=1e-14)
        np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-14)
        assert np.all(w >= 0)


def test_eq11_weights_are_the_paper_step():
    rng = np.random.default_rng(8)
    not_doubly = 0
    for _, o in all_graphs():
        a, w = o["adj"], o["eq11"]
        n = len(a)
        np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-14)
        assert np.all(w >= 0)
        not_doubly += not np.allclose(w.sum(0), 1.0)
        # One step of Sun et al. 2011 eq. 11 written out with a loop.
        x = rng.normal(size=n)
        d = a.sum(1)
        step = np.array([x[i] - sum(a[i, j] * (x[i] - x[j]) for j in range(n)) / (1 + d[i]) for i in range(n)])
        np.testing.assert_allclose(w @ x, step, atol=1e-13)
    assert not_doubly > 10


def test_eq11_not_doubly_stochastic_on_a_path():
    a = np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]], dtype=float)  # degrees 1, 2, 1
    w = np.asarray(F.laplacian_step_weights(a))
    np.testing.assert_allclose(w, [[1 / 2, 1 / 2, 0], [1 / 3, 1 / 3, 1 / 3], [0, 1 / 2, 1 / 2]])
    np.testing.assert_allclose(w.sum(1), 1.0)
    assert abs(w.sum(0)[0] - 1.0) > 0.1  # column 0 sums to 5/6
    assert not np.allclose(w, w.T)


def test_max_degree_weights():
    for _, o in all_graphs():
        a, w = o["adj"], o["max_degree"]
        n = len(a)
        ref = np.zeros((n, n))
        for i in range(n):
            for j in range(n):
                ref[i, j] = a[i, j] / n if i != j else 1.0 - a[i].sum() / n
        np.testing.assert_allclose(w, ref, atol=1e-15)
        np.testing.assert_allclose(w.sum(0), 1.0, atol=1e-14)
        np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-14)
        np.testing.assert_allclose(w, w.T, atol=1e-15)
        assert np.all(w >= 0)


def test_consensus_weights_dispatch_and_bad_kind():
    a = np.array([[0, 1, 1, 0], [1, 0, 1, 0], [1, 1, 0, 1], [0, 0, 1, 0]], dtype=float)
    np.testing.assert_array_equal(F.consensus_weights(a, "eq11"), F.laplacian_step_weights(a))
    np.testing.assert_array_equal(F.consensus_weights(a, "metropolis"), F.metropolis_weights(a))
    np.testing.assert_array_equal(F.consensus_weights(a, "max_degree"), F.max_degree_weights(a))
    # The three kinds are genuinely different on this graph.
    assert not np.allclose(F.consensus_weights(a, "eq11"), F.consensus_weights(a, "metropolis"))
    assert not np.allclose(F.consensus_weights(a, "max_degree"), F.consensus_weights(a, "metropolis"))
    with pytest.raises(ValueError, match="kind") as info:
        graph.consensus_weights(a, "laplacian")
    for allowed in ("eq11", "metropolis", "max_degree"):
        assert allowed in str(info.value)


# --------------------------------------------------------------------------- robustness


def test_pair_robustness_and_R_I_vs_brute_force():
    counts = {}
    for x, o in all_graphs(n_max=7):
        n = len(x["pos"])
        counts[n] = counts.get(n, 0) + 1
        if n == 7 and counts[n] > 8:  # brute force on 7 agents is the slow part
            continue
        rho_ref = brute_force_rho(np_margins(x["pos"], x["radius"]))
        np.testing.assert_allclose(o["rho"], rho_ref, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(o["r_i"], brute_force_robustness(rho_ref), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(
            o["r_i_info"], brute_force_robustness(rho_ref, x["info"]), rtol=1e-12, atol=1e-12
        )


def test_eq15_two_hop_example():
    # Line 0 —(6)— 1 —(6)— 2 with range 10: margins 4, 4, and 0–2 at 12 has margin −2.
    pos = np.array([[0.0, 0.0], [6.0, 0.0], [12.0, 0.0]])
    rho = np.asarray(F.pair_robustness(pos, 10.0))
    assert rho[0, 2] == pytest.approx(4.0) and rho[0, 1] == pytest.approx(4.0)
    np.testing.assert_allclose(np.asarray(F.connectivity_robustness(pos, 10.0)), [2.0, 2.0, 2.0])
    # Only agent 2 as info neighbour of 0: still the two-hop value; others have none (+inf).
    info = np.zeros((3, 3), dtype=bool)
    info[0, 2] = True
    r = np.asarray(F.connectivity_robustness(pos, 10.0, info))
    assert r[0] == pytest.approx(2.0) and np.isposinf(r[1]) and np.isposinf(r[2])


def test_rho_sign_is_path_existence_and_least_extra_range():
    checked = 0
    for x, o in all_graphs():
        pos, r, rho = x["pos"], x["radius"], o["rho"]
        n = len(pos)
        g = to_nx(np_adjacency(pos, r))
        for i in range(n):
            for j in range(i + 1, n):
                assert (rho[i, j] >= 0) == nx.has_path(g, i, j)
                assert rho[i, j] == rho[j, i]
                if rho[i, j] < -1e-3 and checked < 150:
                    # −ρ is the least range added to every agent that joins i and j.
                    more = to_nx(np_adjacency(pos, r - rho[i, j] + 1e-9))
                    less = to_nx(np_adjacency(pos, r - rho[i, j] - 1e-6))
                    assert nx.has_path(more, i, j) and not nx.has_path(less, i, j)
                    checked += 1
    assert checked > 30


TEMPERATURES = np.array([1.0, 0.1, 0.01, 0.001])
_smooth_over_t = fast_jit(jax.vmap(connectivity.smooth_connectivity_robustness, in_axes=(None, None, 0, None)))


def test_smooth_robustness_converges_to_exact():
    for n in (4, 7):
        inputs, out = group(n)
        for b in range(0, GROUP, 3):
            pos, radius = inputs["pos"][b], inputs["radius"][b]
            info = inputs["info"][b] if b % 2 else np.ones((n, n), bool)
            exact = out["r_i_info"][b] if b % 2 else out["r_i"][b]
            finite = np.isfinite(exact)
            smooth = np.asarray(_smooth_over_t(pos, radius, TEMPERATURES, info))
            errors = []
            for t, s in zip(TEMPERATURES, smooth):
                np.testing.assert_array_equal(np.isfinite(s), finite)
                err = np.max(np.abs(s[finite] - exact[finite]), initial=0.0)
                assert err <= 0.5 * (2 * n * math.log(2) + math.log(n - 1)) * t + 1e-12
                errors.append(err)
            assert errors[-1] < 1e-2
            assert errors[-1] <= errors[0] + 1e-12


def np_smooth_robustness(pos, radius, t, info):
    """Soft Floyd–Warshall with numpy loops: max -> T·logaddexp(·/T), min -> −T·logaddexp(−·/T).

    Intermediates k ∈ {i, j} are skipped (no-ops of the exact recursion), as documented.
    """
    rho = np_margins(pos, radius)
    n = len(rho)
    for k in range(n):
        for i in range(n):
            for j in range(n):
                if len({i, j, k}) == 3:
                    via = -t * np.logaddexp(-rho[i, k] / t, -rho[k, j] / t)
                    rho[i, j] = t * np.logaddexp(rho[i, j] / t, via / t)
    out = np.full(n, np.inf)
    for i in range(n):
        vals = np.array([rho[i, j] for j in range(n) if j != i and info[i, j]])
        if vals.size:
            out[i] = 0.5 * -t * np.logaddexp.reduce(-vals / t)
    return out


def test_smooth_robustness_vs_numpy_soft_recursion():
    for n in (4, 7):
        inputs, _ = group(n)
        for b in range(0, GROUP, 4):
            pos, radius, info = inputs["pos"][b], inputs["radius"][b], inputs["info"][b]
            smooth = np.asarray(_smooth_over_t(pos, radius, TEMPERATURES, info))
            for t, s in zip(TEMPERATURES, smooth):
                np.testing.assert_allclose(s, np_smooth_robustness(pos, radius, t, info), rtol=1e-12, atol=1e-12)


def test_smooth_robustness_is_genuinely_smooth_at_finite_temperature():
    # At T = 1 the soft value differs from the exact one (the temperatures is not a no-op),
    # and the default info_neighbours (None) agrees with the all-ones mask.
    pos = np.array([[0.0, 0.0], [3.0, 0.0], [0.0, 4.0], [6.0, 5.0]])
    exact = np.asarray(F.connectivity_robustness(pos, 5.0))
    smooth = np.asarray(F.smooth_connectivity_robustness(pos, 5.0, 1.0))
    assert np.max(np.abs(exact - smooth)) > 0.05
    ones = np.asarray(F.smooth_connectivity_robustness(pos, 5.0, 1.0, np.ones((4, 4), bool)))
    np.testing.assert_allclose(smooth, ones, rtol=1e-14)


def _weighted_soft(p, radius, temperature, info, w):
    soft = connectivity.smooth_connectivity_robustness(p, radius, temperature, info)
    return jnp.dot(w, jnp.where(jnp.isfinite(soft), soft, 0.0))  # drop +inf (no info neighbour)


_soft_value_j = fast_jit(jax.vmap(_weighted_soft, in_axes=(0, None, None, None, None)))
_soft_grad_j = fast_jit(jax.grad(_weighted_soft))


def test_gradients_finite_with_coincident_agents():
    pos = np.array([[0.0, 0.0], [0.0, 0.0], [3.0, 4.0], [9.0, 1.0], [6.0, 7.0]])  # 0 and 1 coincide
    radius = np.array([6.0, 5.0, 7.0, 6.0, 5.5])
    w = np.array([1.0, -0.5, 2.0, 0.7, 1.3])
    info_all = np.ones((5, 5), bool)
    info = info_all.copy()
    info[3] = False  # agent 3 has no information neighbour: R_I = +inf
    for mask in (info_all, info):
        g = np.asarray(_soft_grad_j(pos, radius, 0.1, mask, w))
        assert np.all(np.isfinite(g))
        assert np.max(np.abs(g)) > 1e-3
    assert np.isposinf(np.asarray(smooth_j(pos, radius, 0.1, info))[3])

    def exact_losses(p):
        margins = graph.link_margins(p, radius)
        return (
            jnp.sum(connectivity.connectivity_robustness(p, radius))
            + jnp.sum(graph.pairwise_distances(p))
            + jnp.sum(jnp.where(jnp.isfinite(margins), margins, 0.0))
        )

    assert np.all(np.isfinite(np.asarray(fast_jit(jax.grad(exact_losses))(pos))))


def test_smooth_gradient_matches_finite_differences():
    rng = np.random.default_rng(14)
    pos = rng.uniform(0.0, 10.0, size=(5, 2))
    radius = rng.uniform(4.0, 8.0, size=5)
    w = rng.normal(size=5)
    info = rng.random((5, 5)) < 0.7
    g = np.asarray(_soft_grad_j(pos, radius, 0.5, info, w))
    h = 1e-6
    steps = np.zeros((pos.size,) + pos.shape)
    steps.reshape(pos.size, -1)[np.arange(pos.size), np.arange(pos.size)] = h
    plus = np.asarray(_soft_value_j(pos + steps, radius, 0.5, info, w))
    minus = np.asarray(_soft_value_j(pos - steps, radius, 0.5, info, w))
    fd = (plus - minus) / (2 * h)
    np.testing.assert_allclose(g, fd.reshape(pos.shape), rtol=1e-5, atol=1e-7)
    assert np.max(np.abs(g)) > 1e-3


# --------------------------------------------------------------------------- batching and dtypes


def _per_graph(pos, radius, alive, info):
    adj = graph.adjacency(pos, radius, alive)
    return {
        "adj_alive": adj,
        "lambda2_alive": graph.algebraic_connectivity(adj),
        "sizes_alive": graph.component_sizes(adj),
        "metropolis_alive": graph.consensus_weights(adj, "metropolis"),
        "rho": connectivity.pair_robustness(pos, radius),
        "r_i_info": connectivity.connectivity_robustness(pos, radius, info),
        "soft": connectivity.smooth_connectivity_robustness(pos, radius, 0.2, info),
    }


def test_vmap_matches_per_graph_calls():
    n = 6
    inputs, direct = group(n)  # the leading-batch-axis call, no vmap
    args = [inputs[k] for k in ("pos", "radius", "alive", "info")]
    batched = fast_jit(jax.vmap(_per_graph))(*args)
    single = fast_jit(_per_graph)
    for b in range(0, GROUP, 4):
        one = single(*(a[b] for a in args))
        for name in batched:
            np.testing.assert_allclose(batched[name][b], one[name], rtol=1e-13, atol=1e-13, err_msg=name)
            if name in direct:
                np.testing.assert_allclose(direct[name][b], one[name], rtol=1e-13, atol=1e-13, err_msg=name)
    # A batch of scalar radii is given as (B, 1).
    scal = inputs["radius"][:, :1]
    out = np.asarray(adjacency_j(inputs["pos"], scal))
    for b in range(GROUP):
        np.testing.assert_array_equal(out[b], np_adjacency(inputs["pos"][b], float(scal[b, 0])))


def test_float32_inputs_stay_float32():
    pos = np.array([[0.0, 0.0], [3.0, 4.0], [6.0, 8.0]], dtype=np.float32)

    @fast_jit
    def run(p):
        a = graph.adjacency(p, np.float32(5.0))
        return {
            "adj": a,
            "margins": graph.link_margins(p, 5.0),
            "r_i": connectivity.connectivity_robustness(p, 5.0),
            "soft": connectivity.smooth_connectivity_robustness(p, 5.0, 0.1),
            "metropolis": graph.metropolis_weights(a),
            "sizes": graph.component_sizes(a),
            "lambda2": graph.algebraic_connectivity(a),
        }

    out = run(pos)
    for name, v in out.items():
        assert v.dtype == jnp.float32, name
    np.testing.assert_array_equal(np.asarray(out["adj"]), [[0, 1, 0], [1, 0, 1], [0, 1, 0]])
    np.testing.assert_allclose(np.asarray(out["r_i"]), [0.0, 0.0, 0.0], atol=1e-6)
    assert float(out["lambda2"]) == pytest.approx(1.0, abs=1e-5)  # path P3: λ2 = 1
