"""The sparse consensus exchange (mcjax.tracking.filters.exchange, ``FilterOptions.exchange = "sparse"``):
its weights against the equations written in numpy here, its component sizes against networkx,
every filter kind against the dense exchange and the modified ICF, ICF and KCF against the numpy
peer's filters, on random graphs with split teams, isolated agents and links and agents lost;
an agent with more links than slots is NaN, never a link silently dropped; the Config choice."""

import dataclasses

import jax
import jax.numpy as jnp
import networkx as nx
import numpy as np
import pytest

from benchmarks.peers import numpy_peer
from mcjax.scenarios import sun2011 as lf
from mcjax.tracking.filters import exchange
from mcjax.tracking.filters.consensus import FilterOptions, Late, Measurements, prior_consensus_kcf_step
from mcjax.tracking.filters.registry import FILTER_KINDS
from mcjax.tracking.filters.steps import filter_step, init_states
from mcjax.tracking.models.sensors import range_bearing

N, T = 8, 4
ANGLE = jnp.array([False, True])
R = np.diag([10.0**2, 0.017**2])


def _graphs(seed, n=N, steps=T, radius=45e3):
    """Per step: sensor positions, a comm graph with links lost (20 %) and one agent lost from step 2
    (no links, no measurement), range–bearing measurements of a target, NaN out of a 60 km range."""
    rng = np.random.default_rng(seed)
    target = np.array([50e3, 100.0, 50e3, -50.0])
    pos, adj, zs = [], [], []
    p = rng.uniform(0, 100e3, (n, 2))
    for t in range(steps):
        p = p + rng.normal(0, 2e3, (n, 2))
        d = np.linalg.norm(p[:, None] - p[None], axis=-1)
        a = (d <= radius) & ~np.eye(n, dtype=bool)
        lost = np.triu(rng.random((n, n)) < 0.2, 1)
        a &= ~(lost | lost.T)
        if t >= 2:
            a[3, :] = a[:, 3] = False
        a[n - 1, :] = a[:, n - 1] = False           # an isolated agent throughout
        x = target + t * np.array([100.0, 0, -50.0, 0])
        z = np.stack([numpy_peer.range_bearing(x, s) for s in p]) + rng.normal(0, [10.0, 0.017], (n, 2))
        z[np.linalg.norm(p - x[[0, 2]], axis=-1) > 60e3] = np.nan
        if t >= 2:
            z[3] = np.nan
        pos.append(p.copy()), adj.append(a.astype(float)), zs.append(z)
    return np.array(pos), np.array(adj), np.array(zs), target


def _model(t):
    F, Q = numpy_peer.cv_matrices(1.0, 5.0)
    return (np.eye(4), np.zeros((4, 4))) if t == 0 else (F, Q)


def _run(kinds, opts, pos, adj, zs, x0, late=False):
    """The filters of ``kinds`` over the steps (jitted once per options): every step's states."""
    step = jax.jit(lambda st, m, F, Q: filter_step(kinds, opts, range_bearing, ANGLE, st, m, F, Q, 0.1))
    states = init_states(kinds, jnp.asarray(x0), jnp.diag(jnp.array([1e4, 100.0, 1e4, 100.0])), N)
    out = []
    Rinv = jnp.broadcast_to(jnp.asarray(np.linalg.inv(R)), (N, 2, 2))
    for t in range(T):
        m = Measurements(jnp.asarray(zs[t]), jnp.asarray(pos[t]), jnp.asarray(adj[t]), Rinv)
        if late:  # messages one step old: the previous step's means over the previous step's links
            m = m._replace(late=Late(states[0].x, jnp.asarray(adj[max(t - 1, 0)])))
        F, Q = _model(t)
        states = step(states, m, jnp.asarray(F), jnp.asarray(Q))
        out.append(states)
    return out


def _close(a, b, tol=1e-12):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        x, y = np.asarray(x), np.asarray(y)
        assert np.all(np.isfinite(x)) and np.all(np.isfinite(y))
        np.testing.assert_allclose(x, y, rtol=tol, atol=tol * np.max(np.abs(y)))


# --------------------------------------------------------------------------- the lists, weights, sizes


def _weights_np(A, kind):
    """The consensus matrices from their equations, loops over agents (Sun et al. 2011 eq. 11;
    Metropolis; Chen & Lu 2013 eq. 7)."""
    n, d = A.shape[0], A.sum(1)
    W = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            if i != j and A[i, j]:
                W[i, j] = {"eq11": 1 / (1 + d[i]), "metropolis": 1 / (1 + max(d[i], d[j])), "max_degree": 1 / n}[kind]
        W[i, i] = {"eq11": 1 / (1 + d[i]), "max_degree": 1 - d[i] / n}.get(kind, 1 - W[i].sum())
    return W


@pytest.mark.parametrize("kind", ["eq11", "metropolis", "max_degree"])
def test_sparse_weights_are_the_equations(kind):
    _, adj, _, _ = _graphs(1)
    for A in adj:
        sw = exchange.sparse_weights(exchange.neighbour_lists(jnp.asarray(A), 5), kind, N)
        W = np.diag(np.asarray(sw.own))
        for i in range(N):
            for k in range(sw.link.shape[1]):
                if sw.lists.valid[i, k]:
                    W[i, int(sw.lists.index[i, k])] += float(sw.link[i, k])
        np.testing.assert_allclose(W, _weights_np(A, kind), rtol=0, atol=1e-15)
        assert np.all(np.asarray(sw.lists.valid).sum(1) == A.sum(1))       # every link listed once


def test_component_sizes_match_networkx():
    rng = np.random.default_rng(7)
    sizes = jax.jit(lambda a: exchange.component_sizes(exchange.neighbour_lists(a, 13)))
    for trial in range(30):                                    # from many small components to one
        A = np.triu(rng.random((14, 14)) < rng.uniform(0.02, 0.4), 1)
        A = (A | A.T).astype(float)
        g = nx.from_numpy_array(A)
        want = [len(nx.node_connected_component(g, i)) for i in range(14)]
        assert np.asarray(sizes(jnp.asarray(A))).tolist() == want, trial
    assert np.asarray(exchange.component_sizes(exchange.neighbour_lists(jnp.zeros((1, 1)), 4))).tolist() == [1]


def test_an_agent_with_more_links_than_slots_is_nan():
    A = np.zeros((6, 6))
    A[0, 1:] = A[1:, 0] = 1.0                                              # a star: agent 0 has 5 links
    sw = exchange.sparse_weights(exchange.neighbour_lists(jnp.asarray(A), 3), "eq11", 6)
    out = np.asarray(exchange.mix(sw, jnp.arange(6.0)[:, None]))
    assert np.all(np.isnan(out[0])) and np.all(np.isfinite(out[1:]))
    assert np.asarray(exchange.neighbour_lists(jnp.asarray(A), 3).overflow).tolist() == [True] + [False] * 5


# --------------------------------------------------------------------------- every filter, sparse = dense

#: every kind with Sun et al.'s weights; with the other weights, the kinds that read opts.weights
OPTIONS = [(FILTER_KINDS, FilterOptions(2, "eq11")), (("modified_icf", "kcf"), FilterOptions(2, "metropolis",
                                                                                            kcf_gain="mu_P")),
           (("icf", "modified_icf"), FilterOptions(1, "max_degree", "one", "priors"))]


@pytest.mark.parametrize("kinds, opts", OPTIONS, ids=lambda o: getattr(o, "weights", ""))
def test_every_filter_kind_sparse_equals_dense(kinds, opts):
    pos, adj, zs, x0 = _graphs(3)
    dense = _run(kinds, opts, pos, adj, zs, x0)
    k = int(adj.sum(-1).max())                                              # lists exactly full at the busiest agent
    assert 2 < k < N - 1
    _close(dense, _run(kinds, dataclasses.replace(opts, exchange="sparse", max_neighbours=k), pos, adj, zs, x0))


def test_late_kcf_messages_sparse_equals_dense():
    pos, adj, zs, x0 = _graphs(4)
    opts = FilterOptions()
    dense = _run(("kcf",), opts, pos, adj, zs, x0, late=True)
    _close(dense, _run(("kcf",), dataclasses.replace(opts, exchange="sparse"), pos, adj, zs, x0, late=True))


def test_prior_consensus_kcf_with_formation_sparse_equals_dense():
    pos, adj, zs, x0 = _graphs(5)
    rng = np.random.default_rng(5)
    formation = jnp.asarray(rng.normal(0, 10.0, (N, N, 4)))
    post = init_states(("kcf",), jnp.asarray(x0), jnp.eye(4) * 100.0, N)[0]
    post = post._replace(x=post.x + jnp.asarray(rng.normal(0, 50.0, (N, 4))))
    Rinv = jnp.broadcast_to(jnp.asarray(np.linalg.inv(R)), (N, 2, 2))
    m = Measurements(jnp.asarray(zs[1]), jnp.asarray(pos[1]), jnp.asarray(adj[1]), Rinv)
    F, Q = map(jnp.asarray, _model(1))
    out = [jax.jit(lambda p, m, o=FilterOptions(weights="max_degree", exchange=e): prior_consensus_kcf_step(
        range_bearing, ANGLE, o, p, m, F, Q, formation))(post, m) for e in ("dense", "sparse")]
    _close(out[0], out[1])


# --------------------------------------------------------------------------- against the numpy peer


@pytest.mark.parametrize("kind, variant", [("modified_icf", "contributions"), ("icf", "contributions"),
                                           ("icf", "priors"), ("kcf", "contributions")])
def test_sparse_filters_match_the_numpy_peer(kind, variant):
    pos, adj, zs, x0 = _graphs(6)
    opts = FilterOptions(1, "eq11", "component", variant, exchange="sparse", max_neighbours=5)
    got = _run((kind,), opts, pos, adj, zs, x0)
    F, Q = numpy_peer.cv_matrices(1.0, 5.0)
    want_x, want_P = numpy_peer.run_filter_numpy(kind, zs, pos, adj, x0, np.diag([1e4, 100.0, 1e4, 100.0]), F, Q, R,
                                                 icf_variant=variant)
    for t in range(T):
        np.testing.assert_allclose(np.asarray(got[t][0].x), want_x[t], rtol=1e-9, atol=1e-6)
        np.testing.assert_allclose(np.asarray(got[t][0].P), want_P[t], rtol=1e-8, atol=1e-8)


# --------------------------------------------------------------------------- the Config choice


def test_config_choice_names_the_field_and_auto_picks_by_team_size():
    with pytest.raises(ValueError, match=r"consensus_exchange must be one of dense, sparse, auto"):
        lf.Config(consensus_exchange="csr")
    with pytest.raises(ValueError, match="consensus_neighbours"):
        lf.Config(consensus_neighbours=0)
    with pytest.raises(ValueError, match=r"exchange must be one of 'dense', 'sparse'"):
        FilterOptions(exchange="auto")
    assert lf.filter_options(lf.Config()).exchange == "dense"                      # the built-in 5 UAVs
    assert lf.filter_options(lf.Config(n_agents=100)).exchange == "dense"          # the default, any size
    assert lf.filter_options(lf.Config(n_agents=20, consensus_exchange="auto")).exchange == "dense"
    assert lf.filter_options(lf.Config(n_agents=21, consensus_exchange="auto")).exchange == "sparse"
    assert lf.filter_options(lf.Config(n_agents=21, consensus_exchange="sparse"), smooth=True).exchange == "dense"
    assert lf.filter_options(lf.Config(consensus_exchange="sparse", consensus_neighbours=7)).max_neighbours == 7
