"""The flocking sensor network of Lou, Cui & Li 2013 (``mcjax.scenarios.lou2013.dynamics``, the KCF of
``mcjax.tracking.filters.consensus`` and ``mcjax.scenarios.lou2013``) against independent references:
closed forms and finite differences of the potential (eq. 12), autodiff of sums written here,
the exact time derivative of the energy (eq. 15) by ``jax.jvp``, ``scipy.integrate.solve_ivp``
of eqs. 1, 11 and 13 written in numpy, filterpy's Kalman filter, a numpy transcription of
Alg. 1, networkx for the graphs, and the CLI's input validation.

Cost: one compiled scenario program (6 runs in one batch, ``filters = ["kcf"]`` to keep its
compile time down) serves every scenario-level check; everything else is a few small jits.
"""

import dataclasses
import itertools
from pathlib import Path

import jax
import jax.numpy as jnp
import networkx as nx
import numpy as np
import pytest
from click.testing import CliRunner
from filterpy.kalman import KalmanFilter
from scipy.integrate import solve_ivp
from scipy.linalg import block_diag

from mcjax import engine
from mcjax.cli import main
from mcjax.scenarios import lou2013 as S
from mcjax.scenarios.lou2013 import dynamics as fl
from mcjax.tracking import graph
from mcjax.tracking.filters.consensus import FilterOptions, Measurements, kcf_step, local_step
from mcjax.tracking.filters.gaussian import Gaussian
from mcjax.tracking.models.motion import cv_matrices, cv_process_noise

CONFIG = str((Path(__file__).parents[3] / "configs" / "lou2013.toml").resolve())


# --------------------------------------------------------------------------- numpy references


def np_psi(r, R):
    """Eq. 12 as printed."""
    return 1.0 / r**2 + r**2 / (R - r)


def np_dpsi(r, R):
    """ψ′ derived on paper in a different algebraic form: r²/(R − r) = −r − R + R²/(R − r)
    (polynomial division), so ψ′ = −2/r³ − 1 + R²/(R − r)²."""
    return -2.0 / r**3 - 1.0 + R**2 / (R - r) ** 2


def np_d2psi(r, R):
    """ψ″ = 6/r⁴ + 2R²/(R − r)³ (from the form of :func:`np_dpsi`)."""
    return 6.0 / r**4 + 2.0 * R**2 / (R - r) ** 3


def dpsi_scale(r, R):
    """Magnitude of the terms of ψ′ (ψ′ itself crosses 0 at the equilibrium distance, where a
    relative error against |ψ′| means nothing)."""
    return 2.0 / r**3 + 1.0 + R**2 / (R - r) ** 2


_FD8 = np.array([1 / 280, -4 / 105, 1 / 5, -4 / 5, 0.0, 4 / 5, -1 / 5, 4 / 105, -1 / 280])


def fd8(f, r, s):
    """8th-order central difference of f at r with step s."""
    return sum(c * f(r + (m - 4) * s) for m, c in enumerate(_FD8)) / s


def np_forces(q, adj, R):
    """−Σ_{j∈N_i} ∇_{q_i} ψ(‖q_i − q_j‖) by a double loop (diagonal of adj ignored)."""
    n = len(q)
    out = np.zeros_like(q)
    for i in range(n):
        for j in range(n):
            if i != j and adj[i, j] > 0.5:
                d = q[i] - q[j]
                r = np.linalg.norm(d)
                out[i] -= np_dpsi(r, R) * d / r
    return out


def np_energy(q, p, b, adj, h, tq, tp, c1, k, l, R):
    """Eq. 15: ½ Σ_i [Σ_{j∈N_i} ψ(r_ij) + h_i c1‖q_i − q_γ‖² + ‖p_i − p_γ‖²
    + Σ_{j∈N_i} (1 − h_i)(b_ij − l)²/(2k)]."""
    n = len(q)
    total = 0.0
    for i in range(n):
        term = h[i] * c1 * np.sum((q[i] - tq) ** 2) + np.sum((p[i] - tp) ** 2)
        for j in range(n):
            if i != j and adj[i, j] > 0.5:
                term += np_psi(np.linalg.norm(q[i] - q[j]), R)
                term += (1 - h[i]) * (b[i, j] - l) ** 2 / (2 * k)
        total += 0.5 * term
    return total


def np_hysteresis(prev, q, R, eps):
    """Lou et al. 2013 §1.1 rules 2–3: a link kept while r < R, a new one only below R − ε."""
    n = len(q)
    out = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            if i != j:
                r = np.linalg.norm(q[i] - q[j])
                out[i, j] = float((prev[i, j] > 0.5 and r < R) or r < R - eps)
    return out


def nx_graph(adj):
    g = nx.Graph()
    g.add_nodes_from(range(len(adj)))
    g.add_edges_from((i, j) for i, j in zip(*np.nonzero(np.triu(adj, 1) > 0.5)))
    return g


def nx_lambda2(adj):
    lap = nx.laplacian_matrix(nx_graph(adj), nodelist=range(len(adj))).toarray().astype(float)
    return max(np.linalg.eigvalsh(lap)[1], 0.0)


def distances(q):
    return np.linalg.norm(q[:, None, :] - q[None, :, :], axis=-1)


# --------------------------------------------------------------------------- 1. the potential (eq. 12)


@pytest.mark.parametrize("R", [8.4, 1.5])
def test_potential_slope_and_curvature_against_closed_forms_and_differences(R):
    """ψ, ψ′, ψ″ on (0, R) including r = 1e-2 and r = R − 1e-3: against eq. 12 / the paper
    derivation of :func:`np_dpsi` (1e-12 of the terms' magnitude), against an 8th-order
    central difference with step 1e-2·min(r, R − r) (relative 1e-8 of the terms' magnitude:
    truncation ~ 6e-14, round-off ~ 1e-14), and ψ′ = jax.grad(ψ), ψ″ = jax.grad(ψ′)
    to round-off."""
    r = np.r_[1e-2, R - 1e-3, np.linspace(0.02, 0.995, 40) * R]
    scale1 = dpsi_scale(r, R)
    scale2 = np_d2psi(r, R)  # both of its terms are positive: a true relative scale
    psi = np.asarray(fl.potential(r, R))
    slope = np.asarray(fl.potential_slope(r, R))
    curv = np.asarray(fl.potential_curvature(r, R))
    np.testing.assert_allclose(psi, np_psi(r, R), rtol=1e-13)
    assert np.all(np.abs(slope - np_dpsi(r, R)) <= 1e-12 * scale1)
    np.testing.assert_allclose(curv, np_d2psi(r, R), rtol=1e-12)

    s = 1e-2 * np.minimum(r, R - r)
    fd1 = fd8(lambda x: np_psi(x, R), r, s)
    fd2 = fd8(lambda x: np_dpsi(x, R), r, s)
    assert np.max(np.abs(slope - fd1) / scale1) < 1e-8
    assert np.max(np.abs(curv - fd2) / scale2) < 1e-8

    ad1 = np.asarray(jax.vmap(jax.grad(lambda x: fl.potential(x, R)))(jnp.asarray(r)))
    ad2 = np.asarray(jax.vmap(jax.grad(lambda x: fl.potential_slope(x, R)))(jnp.asarray(r)))
    assert np.max(np.abs(slope - ad1) / scale1) < 1e-14
    assert np.max(np.abs(curv - ad2) / scale2) < 1e-14


def test_potential_outside_its_domain_is_inf_or_nan():
    """Documented: ψ = +∞ and ψ′ = NaN at or beyond R and at r ≤ 0 (a broken run is never a
    silent number); ψ″ is not finite there either. Just inside R it is finite."""
    R = 8.4
    r = np.array([0.0, -0.5, R, R * (1 + 1e-15), R + 1.0, 2 * R])
    assert np.all(np.isposinf(np.asarray(fl.potential(r, R))))
    assert np.all(np.isnan(np.asarray(fl.potential_slope(r, R))))
    assert not np.any(np.isfinite(np.asarray(fl.potential_curvature(r, R))))
    inside = np.array([R * (1 - 1e-12), 1e-6])
    for f in (fl.potential, fl.potential_slope, fl.potential_curvature):
        assert np.all(np.isfinite(np.asarray(f(inside, R))))


def test_potential_forces_are_minus_the_gradient_of_the_link_potential():
    """potential_forces = −∇_q Σ_{links} ψ(‖q_i − q_j‖): by jax.grad of that sum written here
    pair by pair, and by a numpy double loop over ψ′ of :func:`np_dpsi`. A 7th node far out
    (beyond R from everybody) is not linked and feels nothing; ones on the diagonal of the
    adjacency (self-loops) are ignored. A link at or beyond R gives NaN forces (not a silent 0)."""
    R = 8.4
    rng = np.random.default_rng(3)
    q = np.vstack([rng.uniform(0.0, 5.0, (6, 2)), [[30.0, 30.0]]])
    adj = np.triu((rng.uniform(size=(7, 7)) < 0.6).astype(float), 1)
    adj[:, 6] = 0.0
    adj = adj + adj.T
    links = [(i, j) for i, j in itertools.combinations(range(7), 2) if adj[i, j] > 0.5]
    assert 5 <= len(links) < 15
    adj_loops = adj + np.eye(7)

    def link_potential(qq):
        total = 0.0
        for i, j in links:
            r = jnp.sqrt(jnp.sum((qq[i] - qq[j]) ** 2))
            total = total + 1.0 / r**2 + r**2 / (R - r)
        return total

    got = np.asarray(fl.potential_forces(jnp.asarray(q), jnp.asarray(adj_loops), R))
    auto = -np.asarray(jax.jit(jax.grad(link_potential))(jnp.asarray(q)))  # compiled once, not op by op
    loop = np_forces(q, adj, R)
    scale = np.max(np.abs(loop))
    np.testing.assert_allclose(got, auto, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(got, loop, rtol=0, atol=1e-12 * scale)
    assert np.all(got[6] == 0.0) and scale > 0.1

    bad = adj.copy()
    bad[0, 6] = bad[6, 0] = 1.0  # a "link" 40 m long
    f = np.asarray(fl.potential_forces(jnp.asarray(q), jnp.asarray(bad), R))
    assert np.all(np.isnan(f[[0, 6]]))


# --------------------------------------------------------------------------- 2. the energy identity


C1, C2, KGAIN, RADIUS = 1.0, 2.0, 0.5, 8.4
N5 = 5


@jax.jit
def energy_rate(q, p, b, adj, h, tq, v):
    """(φ, dφ/dt) along the flow of eqs. 1, 11, 13 with the true constant-velocity target fed
    to the controller (q_γ(t) = tq + v t, p_γ = v): jax.jvp of fl.energy in the direction
    (derivative(...), ∂q_γ/∂t = v). l = c2 (eq. 16)."""
    g = fl.Gains(C1, C2, KGAIN, RADIUS)
    state = fl.FlockState(q, p, b)
    n = q.shape[0]
    ds = fl.derivative(state, adj, h, jnp.broadcast_to(tq, (n, 2)), jnp.broadcast_to(v, (n, 2)), g)
    return jax.jvp(lambda s, t: fl.energy(s, adj, h, t, v, g, C2), (state, tq), (ds, v))


def random_flock(seed, n=N5, box=4.0, r_min=0.8):
    """Positions with every pair in [r_min, box√2] (well inside R = 8.4), a connected
    non-complete graph (a ring plus a chord), velocities, a target and positive gains."""
    rng = np.random.default_rng(seed)
    while True:
        q = rng.uniform(0.0, box, (n, 2))
        if np.min(distances(q) + 1e9 * np.eye(n)) > r_min:
            break
    adj = np.zeros((n, n))
    for i in range(n):
        adj[i, (i + 1) % n] = adj[(i + 1) % n, i] = 1.0
    adj[0, 2] = adj[2, 0] = 1.0
    p = rng.normal(0.0, 1.0, (n, 2))
    tq = rng.uniform(0.0, box, 2)
    v = rng.normal(0.0, 1.0, 2)
    b = rng.uniform(0.1, 5.0, (n, n))
    return q, p, b, adj, tq, v


def exact_rate(p, b, adj, h, v, l=C2):
    """dφ/dt derived from eqs. 11, 13, 15 (true target, ṗ_γ = 0, fixed topology), with
    v_i = p_i − p_γ:

        dφ/dt = −c2 Σ_i h_i ‖v_i‖²
                − Σ_i (1 − h_i) Σ_{j∈N_i} [ b_ij v_iᵀ(v_i − v_j) − ½ (b_ij − l) ‖v_i − v_j‖² ].

    Derivation: d/dt ½Σ_iΣ_{j∈N_i} ψ = Σ_i p_iᵀ∇_{q_i}(Σ_links ψ) = −Σ_i v_iᵀ f_i (f the
    potential forces; Σ_i f_i = 0 lets p_i become v_i); ½ h_i c1 ‖q_i − q_γ‖² gives
    h_i c1 x_iᵀv_i; ½‖v_i‖² gives v_iᵀu_i, where u_i = f_i − (1 − h_i)Σ_j b_ij(p_i − p_j)
    − h_i(c1 x_i + c2 v_i): the potential and c1 terms cancel. The gain term gives
    ½(1 − h_i)Σ_j (b_ij − l) ḃ_ij / k = ½(1 − h_i)Σ_j (b_ij − l)‖v_i − v_j‖². Nothing assumes b
    symmetric."""
    vv = p - v
    out = -C2 * np.sum(h * np.sum(vv**2, 1))
    for i, j in itertools.product(range(len(p)), repeat=2):
        if i != j and adj[i, j] > 0.5 and h[i] == 0:
            dv = vv[i] - vv[j]
            out -= b[i, j] * vv[i] @ dv - 0.5 * (b[i, j] - l) * dv @ dv
    return out


def paper_eq22(p, adj, h, v, l=C2):
    """Eq. 22 of the paper: Σ_i [−(1 − h_i) l v_iᵀ Σ_{j∈N_i}(v_i − v_j) − h_i c2 ‖v_i‖²]."""
    vv = p - v
    out = 0.0
    for i in range(len(p)):
        out -= h[i] * C2 * vv[i] @ vv[i]
        if h[i] == 0:
            out -= l * vv[i] @ sum(vv[i] - vv[j] for j in range(len(p)) if j != i and adj[i, j] > 0.5)
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_energy_decreases_as_minus_c2_speed_mismatch_when_every_node_senses(seed):
    """The ideal case of Theorem 2: every node senses (h = 1), the true target (constant
    velocity) is fed to the controller, fixed topology: dφ/dt = −c2 Σ_i ‖p_i − p_γ‖² exactly
    (relative 1e-10), the time dependence of q_γ(t) included in the jvp."""
    q, p, b, adj, tq, v = random_flock(seed)
    h = np.ones(N5)
    phi, rate = energy_rate(q, p, b, adj, h, tq, v)
    want = -C2 * np.sum((p - v) ** 2)
    assert np.isfinite(float(phi))
    np.testing.assert_allclose(float(rate), want, rtol=1e-10)
    # the ∂/∂t of q_γ matters: without it the c1 term does not cancel
    g = fl.Gains(C1, C2, KGAIN, RADIUS)
    ds = fl.derivative(fl.FlockState(q, p, b), adj, h, np.broadcast_to(tq, (N5, 2)), np.broadcast_to(v, (N5, 2)), g)
    _, no_dt = jax.jvp(lambda s: fl.energy(s, adj, h, tq, v, g, C2), (fl.FlockState(q, p, b),), (ds,))
    assert abs(float(no_dt) - want) > 1e-3 * abs(want)


@pytest.mark.parametrize("seed", [3, 4])
def test_energy_rate_with_type_ii_nodes_has_mixed_pair_terms_eq22_drops(seed):
    """Mixed flock (h = [1, 1, 0, 0, 0]), random positive b: the jvp of φ equals the
    exact rate of :func:`exact_rate` (relative 1e-10), for an arbitrary (asymmetric) b and
    for a b symmetric on type-II pairs (what the dynamics keeps). With the symmetric b the
    II–II terms collapse to −l Σ_{II–II links} ‖v_i − v_j‖² as in the paper's eq. 22, but a
    link between a type-II node i and a type-I node j is counted from i's side only, and
    leaves −½ (b_ij − l)(‖v_i‖² − ‖v_j‖²) beyond eq. 22:

        exact − eq. 22 = −½ Σ_{links i∈II, j∈I} (b_ij − l)(‖v_i‖² − ‖v_j‖²)

    (checked to 1e-10, and non-zero here): eq. 22 holds only when b_ij = l on mixed links."""
    q, p, b, adj, tq, v = random_flock(seed)
    adj = np.ones((N5, N5)) - np.eye(N5)  # every mixed pair linked
    h = np.array([1.0, 1.0, 0.0, 0.0, 0.0])
    _, rate = energy_rate(q, p, b, adj, h, tq, v)
    np.testing.assert_allclose(float(rate), exact_rate(p, b, adj, h, v), rtol=1e-10)

    bs = b.copy()
    bs[2:, 2:] = 0.5 * (b[2:, 2:] + b[2:, 2:].T)
    _, rate_s = energy_rate(q, p, bs, adj, h, tq, v)
    exact = exact_rate(p, bs, adj, h, v)
    np.testing.assert_allclose(float(rate_s), exact, rtol=1e-10)
    vv2 = np.sum((p - v) ** 2, 1)
    mixed = sum(-0.5 * (bs[i, j] - C2) * (vv2[i] - vv2[j]) for i in range(2, N5) for j in range(2))
    np.testing.assert_allclose(exact - paper_eq22(p, adj, h, v), mixed, rtol=1e-10, atol=1e-12 * abs(exact))
    assert abs(mixed) > 1e-2 * abs(exact)


def test_energy_can_rise_with_the_true_target_when_a_mixed_gain_exceeds_3c2():
    """A consequence of the mixed-pair term (paper's Theorem 2 claims dφ/dt ≤ 0 here): every
    node at the target velocity except type-I node 0, off by w; type-II node 2 linked to it
    with b_20 = 20 > 3 c2, no other type-II node linked to a type-I node. Then
    dφ/dt = (−c2 + ½ (b_20 − l)) ‖w‖² = 7 ‖w‖² > 0 with l = c2 = 2 (the potential and c1
    terms cancel whatever the positions). The scenario's gains do reach such values (its
    config: Σ_j b_ij ≈ 60 per node)."""
    q, _, _, _, tq, v = random_flock(5)
    adj = np.zeros((N5, N5))
    for i, j in [(0, 1), (0, 2), (2, 3), (3, 4), (1, 4)]:
        adj[i, j] = adj[j, i] = 1.0
    h = np.array([1.0, 1.0, 0.0, 0.0, 0.0])
    w = np.array([0.3, -0.4])
    p = np.broadcast_to(v, (N5, 2)).copy()
    p[0] += w
    b = np.zeros((N5, N5))
    b[2, 0] = 20.0
    b[2, 3], b[3, 2], b[3, 4], b[4, 3] = 1.0, 1.0, 3.0, 3.0
    _, rate = energy_rate(q, p, b, adj, h, tq, v)
    np.testing.assert_allclose(float(rate), (-C2 + 0.5 * (20.0 - C2)) * w @ w, rtol=1e-10)
    assert float(rate) > 0


# --------------------------------------------------------------------------- 3. a fixed-topology window


DT = 0.1
Q_TARGET0, V_TARGET = np.array([1.0, 1.0]), np.array([1.0, 0.3])
H_MIX = np.array([1.0, 1.0, 0.0, 0.0, 0.0])
G_IVP = dict(c1=1.0, c2=2.0, k=0.5, R=8.4)


def ivp_flock():
    q, p, b, adj, _, _ = random_flock(7, box=4.0, r_min=1.0)
    return q, 0.3 * p, b, adj


def np_rhs(t, y, adj, h, c1, c2, k, R):
    """Eqs. 1, 11, 13 in numpy with the CV reference q_γ = q0 + v t, p_γ = v (every type-I
    node steers to the true target): y = [q (N·2), p (N·2), b (N·N)]."""
    n = len(h)
    q, p, b = y[: 2 * n].reshape(n, 2), y[2 * n: 4 * n].reshape(n, 2), y[4 * n:].reshape(n, n)
    u = np.zeros((n, 2))
    bdot = np.zeros((n, n))
    ref = Q_TARGET0 + V_TARGET * t
    for i in range(n):
        for j in range(n):
            if i == j or adj[i, j] < 0.5:
                continue
            d = q[i] - q[j]
            r = np.sqrt(d @ d)
            u[i] -= (-2.0 / r**3 - 1.0 + R**2 / (R - r) ** 2) * d / r
            if h[i] == 0:
                u[i] -= b[i, j] * (p[i] - p[j])
                bdot[i, j] = k * (p[i] - p[j]) @ (p[i] - p[j])
        if h[i] == 1:
            u[i] -= c1 * (q[i] - ref) + c2 * (p[i] - V_TARGET)
    return np.concatenate([p.ravel(), u.ravel(), bdot.ravel()])


@pytest.fixture(scope="module")
def ivp_window():
    """The flock integrated with rk4_step over 5 steps of dt = 0.1 (static 200 sub-steps and
    the adaptive count), and by solve_ivp (DOP853, rtol 1e-11, atol 1e-12) of :func:`np_rhs`."""
    q, p, b, adj = ivp_flock()
    g = fl.Gains(**G_IVP)
    h = jnp.asarray(H_MIX)

    @jax.jit
    def advance(q, p, b, t0, n):
        def reference(tau):
            return (jnp.broadcast_to(Q_TARGET0 + V_TARGET * (t0 + tau), (N5, 2)),
                    jnp.broadcast_to(V_TARGET, (N5, 2)))

        s, margin, dmin = fl.rk4_step(fl.FlockState(q, p, b), adj, h, reference, g, DT, n)
        return s.q, s.p, s.b, margin, dmin

    substeps = jax.jit(lambda q, p, b: fl.stable_substeps(fl.FlockState(q, p, b), adj, h, g, DT, 200))

    steps = 5
    static, adaptive, counts, starts = [(q, p, b)], [(q, p, b)], [], []
    margins = []
    for m in range(steps):
        qs, ps, bs, margin, dmin = advance(*static[-1], m * DT, 200)
        static.append((np.asarray(qs), np.asarray(ps), np.asarray(bs)))
        margins.append((float(margin), float(dmin)))
        starts.append(adaptive[-1])
        n = int(substeps(*adaptive[-1]))
        counts.append(n)
        qa, pa, ba, _, _ = advance(*adaptive[-1], m * DT, n)
        adaptive.append((np.asarray(qa), np.asarray(pa), np.asarray(ba)))

    one_step = {n: advance(q, p, b, 0.0, n)[:3] for n in (8, 16, 32)}  # RK4's order of convergence

    y0 = np.concatenate([q.ravel(), p.ravel(), b.ravel()])
    sol = solve_ivp(np_rhs, (0.0, steps * DT), y0, method="DOP853", rtol=1e-11, atol=1e-12, dense_output=True,
                    args=(adj, H_MIX, G_IVP["c1"], G_IVP["c2"], G_IVP["k"], G_IVP["R"]))
    assert sol.success
    return dict(adj=adj, static=static, adaptive=adaptive, counts=counts, starts=starts, margins=margins, sol=sol,
                steps=steps, one_step=one_step)


def _split(y):
    return y[: 2 * N5].reshape(N5, 2), y[2 * N5: 4 * N5].reshape(N5, 2), y[4 * N5:].reshape(N5, N5)


@pytest.mark.xdist_group("test_flocking")  # one worker builds the module fixture once
def test_rk4_window_matches_solve_ivp(ivp_window):
    """q, p and b after each of 5 steps: rk4_step with 200 sub-steps per 0.1 s (h = 5e-4,
    RK4 global error ~1e-12 here) equals solve_ivp of the numpy equations to 1e-8 (absolute;
    q ~ 5 m, p ~ 1 m/s, b ~ 1). Over one step with 8, 16, 32 sub-steps the error falls by
    2⁴ per halving (ratios in [14, 20]: classical RK4, the reference evaluated at the right
    intermediate times). The adaptive count of stable_substeps is a stability bound, not an
    accuracy one: here it takes 1 sub-step per step (h = 0.1 with Σ_j b_ij up to ~10 on
    type-II rows, h·γ ≈ 1), and the velocities are off by up to 4e-3 after the first step;
    checked: within 1e-2 (RK4's local error ~(hγ)⁵/5! of the velocity scale) and not growing."""
    w = ivp_window
    sol = w["sol"]
    worst_static, adaptive_err = 0.0, []
    for m in range(1, w["steps"] + 1):
        ref = _split(sol.sol(m * DT))
        worst_static = max(worst_static, *(np.max(np.abs(a - r)) for a, r in zip(w["static"][m], ref)))
        adaptive_err.append(max(np.max(np.abs(a - r)) for a, r in zip(w["adaptive"][m], ref)))
    assert worst_static < 1e-8, worst_static
    assert max(adaptive_err) < 1e-2 and adaptive_err[-1] <= adaptive_err[0], adaptive_err
    ref1 = _split(sol.sol(DT))
    err = [max(np.max(np.abs(np.asarray(a) - r)) for a, r in zip(w["one_step"][n], ref1)) for n in (8, 16, 32)]
    assert 14 < err[0] / err[1] < 20 and 14 < err[1] / err[2] < 20, err
    # the window is not trivial: b of the type-II rows grew, the flock moved
    b0, b5 = w["static"][0][2], w["static"][-1][2]
    assert np.all(b5[2:][w["adj"][2:] > 0.5] > b0[2:][w["adj"][2:] > 0.5] + 1e-3)
    np.testing.assert_array_equal(b5[:2], b0[:2])  # type-I rows: no adaptation
    assert np.max(np.abs(w["static"][-1][0] - w["static"][0][0])) > 0.05


@pytest.mark.xdist_group("test_flocking")  # one worker builds the module fixture once
def test_rk4_margins_are_the_substep_minima(ivp_window):
    """rk4_step's min_link_margin (smallest R − r over links) and min_distance (smallest
    pairwise distance) are the minima over the sub-step ends t0 + m·h, m = 1..200: the
    same from solve_ivp's dense output at those times (1e-8)."""
    w = ivp_window
    links = w["adj"] > 0.5
    off = ~np.eye(N5, dtype=bool)
    for m, (margin, dmin) in enumerate(w["margins"]):
        ts = m * DT + DT * np.arange(1, 201) / 200
        ys = w["sol"].sol(ts).T
        d = np.array([distances(_split(y)[0]) for y in ys])
        assert abs(margin - np.min(G_IVP["R"] - d[:, links])) < 1e-8
        assert abs(dmin - np.min(d[:, off])) < 1e-8


@pytest.mark.xdist_group("test_flocking")  # one worker builds the module fixture once
def test_stable_substeps_is_its_documented_formula(ivp_window):
    """stable_substeps = clip(ceil(dt / (safety·min(1/√κ, 1/γ))), 1, max) with
    κ = max_i Σ_{j∈N_i} (ψ″(r_ij) + |ψ′(r_ij)|/r_ij) and γ = max(c2, max_{i∈II} Σ_{j∈N_i} b_ij),
    recomputed in numpy from the closed forms at each step's start; and the cap and the floor."""
    w = ivp_window
    adj = w["adj"]
    g = fl.Gains(**G_IVP)
    R = G_IVP["R"]
    for (q, p, b), n in zip(w["starts"], w["counts"]):
        d = distances(q)
        kappa = max(sum(np_d2psi(d[i, j], R) + abs(np_dpsi(d[i, j], R)) / d[i, j]
                        for j in range(N5) if adj[i, j] > 0.5) for i in range(N5))
        gamma = max(G_IVP["c2"], max(np.sum(b[i][adj[i] > 0.5]) for i in range(N5) if H_MIX[i] == 0))
        want = int(np.clip(np.ceil(DT / min(1 / np.sqrt(kappa), 1 / gamma)), 1, 200))
        assert n == want
        st = fl.FlockState(q, p, b)
        assert int(fl.stable_substeps(st, adj, H_MIX, g, 1e3, 7)) == 7        # capped
        assert int(fl.stable_substeps(st, adj, H_MIX, g, 1e-9, 200)) == 1     # at least one
        assert int(fl.stable_substeps(st, adj, H_MIX, g, DT, 200, 0.01)) == int(np.ceil(DT / (0.01 * min(
            1 / np.sqrt(kappa), 1 / gamma))))


# --------------------------------------------------------------------------- 4. the Kalman-consensus filter


NK = 4
KCF_DT, SIGMA_A = 0.1, 0.5
HPOS = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
MASK = jnp.array([False, False])


def _position(x, sensor):
    del sensor
    return jnp.stack([x[0], x[2]])


@pytest.fixture(scope="module")
def kcf_fns():
    opts = FilterOptions(kcf_gain="mu_P")
    kcf = jax.jit(lambda eps, post, meas, F, Q: kcf_step(_position, MASK, opts, eps, post, meas, F, Q))
    loc = jax.jit(lambda post, meas, F, Q: local_step(_position, MASK, post, meas, F, Q))
    return kcf, loc


def kcf_problem(seed, steps=20):
    """A CV target, NK nodes with their own measurement covariances R_i, measurements."""
    rng = np.random.default_rng(seed)
    F = np.asarray(cv_matrices(KCF_DT)[0])
    Q = np.asarray(cv_process_noise(KCF_DT, SIGMA_A))
    Rs = []
    for i in range(NK):
        a = rng.normal(0.0, 0.1, (2, 2))
        Rs.append(a @ a.T + 0.01 * (i + 1) * np.eye(2))
    x = np.array([0.0, 1.0, 0.0, 0.5])
    zs = []
    for t in range(steps):
        if t > 0:
            x = F @ x + np.linalg.cholesky(Q + 1e-15 * np.eye(4)) @ rng.normal(size=4)
        zs.append(np.array([HPOS @ x + np.linalg.cholesky(Rs[i]) @ rng.normal(size=2) for i in range(NK)]))
    return F, Q, Rs, zs


def _gauss(x, P):
    return Gaussian(jnp.asarray(x), jnp.asarray(P), jnp.asarray(np.linalg.inv(P)))


def _meas(z, A, Rs):
    return Measurements(jnp.asarray(z), jnp.zeros((NK, 2)), jnp.asarray(A), jnp.asarray(np.linalg.inv(np.array(Rs))))


@pytest.mark.xdist_group("test_flocking")  # one worker builds the module fixture once
def test_kcf_on_a_complete_graph_is_the_centralised_kalman_filter(kcf_fns):
    """Every node senses, complete graph, the same prior: with S_i = Σ_j H R_j⁻¹ H and
    y_i = Σ_j H R_j⁻¹ z_j over all nodes and no disagreement, each node's KCF (μP gain) is
    filterpy's KalmanFilter on the stacked measurements (H 8×4, R block-diagonal), to 1e-9
    over 20 steps (step 0 updates the prior without predicting: F = I, Q = 0)."""
    kcf, _ = kcf_fns
    F, Q, Rs, zs = kcf_problem(0)
    x0, P0 = np.array([0.2, 0.8, -0.1, 0.6]), np.diag([1.0, 0.5, 1.0, 0.5])
    kf = KalmanFilter(dim_x=4, dim_z=2 * NK)
    kf.x, kf.P, kf.F, kf.Q = x0.copy(), P0.copy(), F, Q
    kf.H, kf.R = np.tile(HPOS, (NK, 1)), block_diag(*Rs)
    post = _gauss(np.tile(x0, (NK, 1)), np.tile(P0, (NK, 1, 1)))
    A = np.ones((NK, NK)) - np.eye(NK)
    for t, z in enumerate(zs):
        Ft, Qt = (np.eye(4), np.zeros((4, 4))) if t == 0 else (F, Q)
        post = kcf(0.3, post, _meas(z, A, Rs), Ft, Qt)
        if t > 0:
            kf.predict()
        kf.update(z.reshape(-1))
        for i in range(NK):
            np.testing.assert_allclose(np.asarray(post.x[i]), kf.x, rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(np.asarray(post.P[i]), kf.P, rtol=1e-9, atol=1e-12)
    assert np.trace(kf.P) < 0.5 * np.trace(P0)


@pytest.mark.xdist_group("test_flocking")  # one worker builds the module fixture once
def test_kcf_on_an_empty_graph_and_local_filters_are_each_nodes_kalman_filter(kcf_fns):
    """No links: each node's KCF is its own Kalman filter (filterpy, its own R_i and prior);
    node 3 misses every other measurement (NaN: predict only). local_step (the paper's
    Fig. 2 baseline) is the same, on any graph."""
    kcf, loc = kcf_fns
    F, Q, Rs, zs = kcf_problem(1)
    rng = np.random.default_rng(11)
    x0 = np.array([0.0, 1.0, 0.0, 0.5]) + rng.normal(0.0, 0.3, (NK, 4))
    P0 = np.array([np.diag(rng.uniform(0.2, 2.0, 4)) for _ in range(NK)])
    kfs = []
    for i in range(NK):
        kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.x, kf.P, kf.F, kf.Q, kf.H, kf.R = x0[i].copy(), P0[i].copy(), F, Q, HPOS, Rs[i]
        kfs.append(kf)
    post_k = post_l = _gauss(x0, P0)
    empty, full = np.zeros((NK, NK)), np.ones((NK, NK)) - np.eye(NK)
    for t, z in enumerate(zs):
        z = z.copy()
        if t % 2:
            z[3] = np.nan
        Ft, Qt = (np.eye(4), np.zeros((4, 4))) if t == 0 else (F, Q)
        post_k = kcf(0.3, post_k, _meas(z, empty, Rs), Ft, Qt)
        post_l = loc(post_l, _meas(z, full, Rs), Ft, Qt)
        for i, kf in enumerate(kfs):
            if t > 0:
                kf.predict()
            if np.all(np.isfinite(z[i])):
                kf.update(z[i])
            for post in (post_k, post_l):
                np.testing.assert_allclose(np.asarray(post.x[i]), kf.x, rtol=1e-9, atol=1e-9)
                np.testing.assert_allclose(np.asarray(post.P[i]), kf.P, rtol=1e-9, atol=1e-12)


@pytest.mark.xdist_group("test_flocking")  # one worker builds the module fixture once
def test_kcf_step_is_algorithm_1_on_a_path_graph(kcf_fns):
    """One KCF step on the path 0–1–2–3 with different priors, node 2 without a measurement:
    Lou et al. 2013 Alg. 1 transcribed in numpy (P̄ = F P Fᵀ + Q, x̄ = F x;
    S_i = Σ_{J_i} Hᵀ R_j⁻¹ H, y_i = Σ_{J_i} Hᵀ R_j⁻¹ z_j over i and its neighbours;
    M_i = (P̄_i⁻¹ + S_i)⁻¹, μ = ε/(‖P̄_i‖_F + 1) (the code's norm: the paper's ‖P_i‖ is not
    specified), x̂_i = x̄_i + M_i(y_i − S_i x̄_i) + μ P̄_i Σ_{N_i}(x̄_j − x̄_i), P_i ← M_i), 1e-10.
    The consensus term is large enough here that dropping it fails the check."""
    kcf, _ = kcf_fns
    F, Q, Rs, zs = kcf_problem(2, steps=1)
    z = zs[0].copy()
    z[2] = np.nan
    rng = np.random.default_rng(5)
    x0 = rng.normal(0.0, 1.0, (NK, 4))
    P0 = []
    for _ in range(NK):
        a = rng.normal(size=(4, 4))
        P0.append(a @ a.T + 0.5 * np.eye(4))
    P0 = np.array(P0)
    A = np.zeros((NK, NK))
    for i in range(NK - 1):
        A[i, i + 1] = A[i + 1, i] = 1.0
    eps = 0.5
    post = kcf(eps, _gauss(x0, P0), _meas(z, A, Rs), F, Q)

    xb = x0 @ F.T
    Pb = np.array([F @ P @ F.T + Q for P in P0])
    W = [HPOS.T @ np.linalg.inv(Rs[j]) @ HPOS if np.all(np.isfinite(z[j])) else np.zeros((4, 4)) for j in range(NK)]
    w = [HPOS.T @ np.linalg.inv(Rs[j]) @ z[j] if np.all(np.isfinite(z[j])) else np.zeros(4) for j in range(NK)]
    for i in range(NK):
        J = [i] + [j for j in range(NK) if A[i, j] > 0.5]
        Si, yi = sum(W[j] for j in J), sum(w[j] for j in J)
        Mi = np.linalg.inv(np.linalg.inv(Pb[i]) + Si)
        mu = eps / (np.linalg.norm(Pb[i], "fro") + 1.0)
        cons = mu * Pb[i] @ sum(xb[j] - xb[i] for j in range(NK) if A[i, j] > 0.5)
        want = xb[i] + Mi @ (yi - Si @ xb[i]) + cons
        np.testing.assert_allclose(np.asarray(post.x[i]), want, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(np.asarray(post.P[i]), Mi, rtol=1e-10, atol=1e-12)
        assert np.linalg.norm(cons) > 1e-3


# --------------------------------------------------------------------------- 5. the scenario


SCN_CFG = S.Config(n_agents=6, n_steps=40, warmup_steps=5, filters=("kcf",))
# (overrides, seed index): four ordinary runs (box 8 as the paper: a complete graph; wider boxes:
# sparse graphs where links form by hysteresis; every node sensing), an impossible start
# (6 nodes ≥ 7.9 m apart in an 8 m box), and run 0 again with a step so long that the RK4
# sub-steps used before blew up (dt = 5 s; substep_safety = 1e6 made it one RK4 sub-step): the
# error-controlled pair (the default integrator) splits it.
RUNS = [({}, 0), (dict(box=12.0), 1), (dict(box=14.0), 2), (dict(n_sensing=6.0, box=11.0), 3),
        (dict(start_min_distance=7.9), 4), (dict(dt=5.0, substep_safety=1e6), 0)]
NORMAL = range(4)


def _extended_step(cfg, params, state, key):
    """The scenario's step, also recording the state before and after (for the graph checks)."""
    new, rec = S.step(cfg, params, state, key)
    return new, (rec, state.adj, state.flock.q, new.adj, new.flock)


@pytest.fixture(scope="module")
def scenario_runs():
    scenario = dataclasses.replace(S.SCENARIO, step=_extended_step)
    params = engine.stack_points([S.default_params(SCN_CFG, **o) for o, _ in RUNS])
    keys = jax.vmap(lambda s: engine.run_key(0, s))(jnp.asarray([s for _, s in RUNS], jnp.uint32))
    out = engine.compiled(scenario, SCN_CFG, records=True)(params, keys)
    rec, adj0, q0, adj, flock = jax.tree.map(np.asarray, out)
    reduced = jax.tree.map(np.asarray, jax.jit(jax.vmap(lambda r, p: S.reduce(SCN_CFG, r, p)))(out[0], params))
    return dict(rec=rec, adj0=adj0, q0=q0, adj=adj, flock=flock, out=reduced, params=params)


@pytest.mark.xdist_group("test_flocking")  # one worker builds the module fixture once
def test_scenario_start_is_a_valid_draw(scenario_runs):
    """The start of each ordinary run: its graph (r < R, rule 1) is connected (networkx), no
    pair in [R − start_margin, R), none closer than start_min_distance; the initial adjacency
    is that graph. The rejection is exercised (some run needed more than one draw)."""
    w = scenario_runs
    p = w["params"]
    attempts = []
    for r in NORMAL:
        q = w["q0"][r, 0]
        R, margin, dmin = float(p.R[r]), float(p.start_margin[r]), float(p.start_min_distance[r])
        d = distances(q)
        off = ~np.eye(6, dtype=bool)
        g = nx_graph((d < R) & off)
        assert nx.is_connected(g)
        assert not np.any((d[off] >= R - margin) & (d[off] < R))
        assert np.min(d[off]) >= dmin
        assert np.all(q >= 0) and np.all(q <= float(p.box[r]))
        np.testing.assert_array_equal(w["adj0"][r, 0], ((d < R) & off).astype(float))
        assert not w["out"]["start_failed"][r]
        attempts.append(int(w["out"]["start_attempts_used"][r]))
    assert max(attempts) > 1, attempts


def test_init_draws_for_20_nodes_are_valid_or_flagged():
    """``init`` for the paper's 20 nodes in the 8 m box, a batch of 8 keys: each start's graph
    (r < R) is connected (networkx), no pair in [R − start_margin, R), none closer than
    start_min_distance, the adjacency is that graph, the gains 0 and every filter at the true
    target with covariance diag(p0_diag); the margin band makes rejections common (some key
    needs several draws). Two more keys ask for 7.9 m between 20 nodes: flagged after all
    start_attempts draws (no hang). The kept draws are the documented uniform draw, re-drawn
    here from the keys."""
    cfg = S.Config(n_agents=20, n_steps=2, warmup_steps=1, filters=("kcf",))
    over = [{}] * 6 + [dict(start_min_distance=7.9)] * 2
    params = engine.stack_points([S.default_params(cfg, **o) for o in over])
    keys = jax.vmap(lambda s: engine.run_key(3, s))(jnp.arange(8, dtype=jnp.uint32))
    st = jax.tree.map(np.asarray, jax.jit(jax.vmap(lambda p, k: S.init(cfg, p, k)))(params, keys))
    R, margin, dmin = 8.4, 0.2, 0.3
    off = ~np.eye(20, dtype=bool)
    for r in range(6):
        q = st.flock.q[r]
        d = distances(q)
        assert nx.is_connected(nx_graph((d < R) & off))
        assert not np.any((d[off] >= R - margin) & (d[off] < R)) and np.min(d[off]) >= dmin
        assert np.all((q >= 0) & (q <= 8.0)) and np.all((st.flock.p[r] >= 0) & (st.flock.p[r] <= 0.1))
        np.testing.assert_array_equal(st.adj[r], ((d < R) & off).astype(float))
        assert not st.start_failed[r] and 1 <= st.attempts[r] <= cfg.start_attempts
        assert np.all(st.flock.b[r] == 0) and st.t[r] == 0
        np.testing.assert_array_equal(st.filters[0].x[r], np.broadcast_to([0.0, 1.0, 0.0, 1.0], (20, 4)))
        np.testing.assert_array_equal(st.filters[0].P[r], np.broadcast_to(np.diag([0.1] * 4), (20, 4, 4)))
    assert np.max(st.attempts[:6]) > 1
    assert np.all(st.start_failed[6:]) and np.all(st.attempts[6:] == cfg.start_attempts)
    # the default start_layout, "uniform": the kept draw is box · U[0, 1]² and v0 · U[0, 1]² from
    # the two halves of that attempt's key (attempt keys: split(run key, start_attempts)), bit for bit
    assert cfg.start_layout == "uniform"
    for r in (0, 1):
        kq, kp = jax.random.split(jax.random.split(keys[r], cfg.start_attempts)[int(st.attempts[r]) - 1])
        np.testing.assert_array_equal(st.flock.q[r], 8.0 * jax.random.uniform(kq, (20, 2), jnp.float64))
        np.testing.assert_array_equal(st.flock.p[r], 0.1 * jax.random.uniform(kp, (20, 2), jnp.float64))


@pytest.mark.parametrize("n", [20, 50, 100])
def test_lattice_start_meets_the_start_rule(n):
    """start_layout = "lattice" (defaults: 1.75 m spacing, jitter 0.1 m) for 20, 50 and 100
    nodes, 6 keys each, one draw allowed: every start is valid at the first draw — its graph
    (r < R) is connected (scipy's connected components), no pair in [R − start_margin, R),
    none closer than start_min_distance, each node within the jitter of its own site of a
    1.75 m square grid of ceil(sqrt(n)) columns, velocities in [0, v0]², the adjacency that
    graph — and check_params accepts the set-up."""
    from scipy.sparse.csgraph import connected_components

    cfg = S.Config(n_agents=n, n_steps=2, warmup_steps=1, filters=("kcf",), start_layout="lattice", start_attempts=1)
    assert S.check_params(cfg, {}) == []
    p = S.default_params(cfg)
    keys = jax.vmap(lambda s: engine.run_key(5, s))(jnp.arange(6, dtype=jnp.uint32))
    st = jax.tree.map(np.asarray, jax.jit(jax.vmap(lambda k: S.init(cfg, p, k)))(keys))
    R, margin, dmin, spacing, jitter = 8.4, 0.2, 0.3, 1.75, 0.1
    cols = int(np.ceil(np.sqrt(n)))
    off = ~np.eye(n, dtype=bool)
    for r in range(6):
        q = st.flock.q[r]
        d = distances(q)
        assert connected_components((d < R) & off, directed=False)[0] == 1
        assert not np.any((d[off] >= R - margin) & (d[off] < R)) and np.min(d[off]) >= dmin
        cell = np.round(q / spacing - 0.5)
        assert np.all(np.abs(q - (cell + 0.5) * spacing) <= jitter)
        assert len({tuple(c) for c in cell}) == n and np.all((cell >= 0) & (cell[:, :1] < cols))
        assert np.all((st.flock.p[r] >= 0) & (st.flock.p[r] <= 0.1))
        np.testing.assert_array_equal(st.adj[r], ((d < R) & off).astype(float))
        assert not st.start_failed[r] and st.attempts[r] == 1
    assert np.ptp(st.flock.q[:, 0, 0]) > 0  # the jitter differs between keys


def test_default_start_is_the_papers_uniform_draw():
    """The default start_layout is "uniform", also in configs/lou2013.toml (the draw itself,
    bit for bit: test_init_draws_for_20_nodes_are_valid_or_flagged)."""
    from mcjax.study import load_config_file

    assert S.Config().start_layout == "uniform"
    assert load_config_file(CONFIG)[1].start_layout == "uniform"


@pytest.mark.xdist_group("test_flocking")  # one worker builds the module fixture once
def test_scenario_impossible_start_is_flagged_not_hung(scenario_runs):
    """start_min_distance = 7.9 m for 6 nodes in an 8 m box cannot be met: every one of the 64
    draws fails, the run is flagged (start_failed) and still runs its 40 steps from its last
    draw (which indeed violates the requirement)."""
    w = scenario_runs
    r = 4
    assert bool(w["out"]["start_failed"][r]) and int(w["out"]["start_attempts_used"][r]) == SCN_CFG.start_attempts
    d = distances(w["q0"][r, 0])
    assert np.min(d[~np.eye(6, dtype=bool)]) < 7.9
    assert w["rec"].edges.shape[1] == SCN_CFG.n_steps


@pytest.mark.xdist_group("test_flocking")  # one worker builds the module fixture once
def test_scenario_huge_step_is_split_by_the_error_control(scenario_runs):
    """Run 0 again with dt = 5 s (one RK4 sub-step blew it up before: substep_safety has no
    say on the default integrator): the step-size control splits each step into tens of
    sub-steps, none capped, and the run is clean, as run 0 itself. (A capped, broken step is
    flagged: tests/scenarios/lou2013/test_integrator.py.)"""
    out = scenario_runs["out"]
    for r in (0, 5):
        assert not bool(out["link_reached_R"][r]) and not np.any(out["nonfinite"][r])
        assert int(out["substeps_capped"][r]) == 0
    assert int(scenario_runs["rec"].substeps[5, 0]) > 20


@pytest.mark.xdist_group("test_flocking")  # one worker builds the module fixture once
def test_scenario_graph_records_match_networkx_and_the_hysteresis_rules(scenario_runs):
    """Every step of the ordinary runs: the new adjacency is rules 2–3 applied in numpy to the
    previous one and the step-end positions; λ2 equals networkx's (Laplacian eigenvalues),
    edges/added/removed the edge-set differences; the energy is eq. 15 in numpy at the true
    target at the step's end (l = c2); speed_mismatch, min_distance and min_link_margin (over
    the links the step flew with) agree with the step-end positions; b stays 0 on type-I
    rows, ≥ 0 and symmetric on type-II pairs. Reduce: no link removed or reaching R,
    connected throughout, no failed start."""
    w = scenario_runs
    rec, p = w["rec"], w["params"]
    added_total = 0
    for r in NORMAL:
        R, eps, dt, v = (float(getattr(p, f)[r]) for f in ("R", "epsilon", "dt", "target_speed"))
        h = (np.arange(6) < float(p.n_sensing[r])).astype(float)
        prev = w["adj0"][r, 0]
        for t in range(SCN_CFG.n_steps):
            q, pv, b = w["flock"].q[r, t], w["flock"].p[r, t], w["flock"].b[r, t]
            adj = w["adj"][r, t]
            np.testing.assert_array_equal(w["adj0"][r, t], prev)
            np.testing.assert_array_equal(adj, np_hysteresis(prev, q, R, eps))
            assert abs(rec.lambda2[r, t] - nx_lambda2(adj)) < 1e-9
            e_new, e_old = set(nx_graph(adj).edges), set(nx_graph(prev).edges)
            assert rec.edges[r, t] == len(e_new)
            assert rec.added[r, t] == len(e_new - e_old) and rec.removed[r, t] == len(e_old - e_new)
            added_total += len(e_new - e_old)
            x = v * (t + 1) * dt
            tq, tp = np.array([x, np.sin(x)]), np.array([v, v * np.cos(x)])
            xs = v * t * dt
            np.testing.assert_allclose(rec.target[r, t], [xs, v, np.sin(xs), v * np.cos(xs)], rtol=1e-12, atol=1e-12)
            e = np_energy(q, pv, b, adj, h, tq, tp, float(p.c1[r]), float(p.k[r]), float(p.c2[r]), R)
            np.testing.assert_allclose(rec.energy[r, t], e, rtol=1e-10)
            np.testing.assert_allclose(rec.speed_mismatch[r, t], np.sum((pv - tp) ** 2), rtol=1e-10)
            d = distances(q)
            off = ~np.eye(6, dtype=bool)
            assert 0 < rec.min_distance[r, t] <= np.min(d[off]) + 1e-12
            assert 0 < rec.min_link_margin[r, t] <= np.min(R - d[prev > 0.5]) + 1e-12  # the step's links
            assert np.all(b[h > 0.5] == 0) and np.all(b >= 0)
            bii = b[np.ix_(h < 0.5, h < 0.5)]
            np.testing.assert_allclose(bii, bii.T, rtol=1e-12, atol=1e-14)
            prev = adj
        out = w["out"]
        assert out["edges_removed"][r] == 0 and not out["link_reached_R"][r] and not out["start_failed"][r]
        assert out["min_distance"][r] > 0 and out["lambda2_min"][r] > 0 and out["disconnected_steps"][r] == 0
        assert out["edges_added"][r] == np.sum(rec.added[r])
    assert added_total > 0  # the hysteresis path was exercised


def test_hysteresis_rules_at_the_thresholds():
    """Two nodes at distance r (exact in floating point), previous link or not: an existing
    link at R − ε/2 stays, a new one there does not form; at exactly R a link breaks (rule 3,
    r ≥ R); just below R it stays; a new link forms just below R − ε, not at R − ε."""
    R, eps = 8.0, 0.5
    cases = [(R - eps / 2, 1, 1), (R - eps / 2, 0, 0), (R, 1, 0), (R, 0, 0), (R - 2**-40, 1, 1),
             (R - eps - 2**-40, 0, 1), (R - eps, 0, 0), (R + 1.0, 1, 0), (1.0, 0, 1)]
    for r, prev, want in cases:
        q = jnp.array([[0.0, 0.0], [r, 0.0]])
        adj = np.asarray(graph.hysteresis_adjacency(jnp.array([[0.0, prev], [prev, 0.0]]), q, R, eps))
        assert adj[0, 1] == adj[1, 0] == want, (r, prev)
        assert adj[0, 0] == adj[1, 1] == 0


def test_hysteresis_and_lambda2_on_random_graphs_match_networkx():
    """A batch of 40 random 7-node layouts with random previous links: hysteresis_adjacency
    (batched) equals the numpy rules; algebraic_connectivity equals networkx's (Laplacian
    eigenvalues, and nx.algebraic_connectivity for the connected ones), 0 iff disconnected."""
    rng = np.random.default_rng(8)
    B, n, R, eps = 40, 7, 5.0, 1.0
    q = rng.uniform(0.0, 9.0, (B, n, 2))
    prev = np.triu(rng.uniform(size=(B, n, n)) < 0.5, 1).astype(float)
    prev = prev + np.swapaxes(prev, 1, 2)
    adj = np.asarray(graph.hysteresis_adjacency(prev, q, R, eps))
    lam = np.asarray(graph.algebraic_connectivity(adj))
    connected = 0
    for k in range(B):
        np.testing.assert_array_equal(adj[k], np_hysteresis(prev[k], q[k], R, eps))
        g = nx_graph(adj[k])
        assert abs(lam[k] - nx_lambda2(adj[k])) < 1e-10
        if nx.is_connected(g):
            connected += 1
            np.testing.assert_allclose(lam[k], nx.algebraic_connectivity(g, method="tracemin_lu", tol=1e-12),
                                       rtol=1e-7)
            assert lam[k] > 1e-9
        else:
            assert lam[k] < 1e-12
    assert 5 < connected < B - 5


# --------------------------------------------------------------------------- 6. bad input


def test_check_params_names_the_field():
    cfg = S.Config(n_agents=6, n_steps=40, warmup_steps=5)
    assert S.check_params(cfg, {}) == []
    for values, field in [({"n_sensing": 7.0}, "n_sensing"), ({"epsilon": 8.4}, "epsilon"),
                          ({"epsilon": 9.0}, "epsilon"), ({"R": 2.0, "epsilon": 2.5}, "epsilon"),
                          ({"start_margin": 8.4}, "start_margin")]:
        bad = S.check_params(cfg, values)
        assert [f for f, _ in bad] == [field], (values, bad)
        assert all(isinstance(a, str) and a and "\n" not in a for _, a in bad)
    assert S.check_params(cfg, {"n_sensing": 6.0, "epsilon": 8.3}) == []


def test_lattice_start_rejects_bad_spacing_or_jitter_and_layouts():
    """check_params with start_layout = "lattice": a spacing that puts some lattice pair in
    [R − 0.2, R) (5 × 1.65 = 8.25 m) or leaves neighbours unlinked (9 m) names
    lattice_spacing; a jitter that could push a pair into that band or below 0.3 m names
    lattice_jitter; 1.6 m without jitter passes (no lattice distance in the band), and the
    uniform layout ignores both. An unknown layout is a Config error naming the field, and
    ``mcjax list flocking`` shows the allowed values."""
    lattice = S.Config(n_agents=20, n_steps=40, warmup_steps=5, start_layout="lattice")
    assert S.check_params(lattice, {}) == []
    for values, field in [({"lattice_spacing": 1.65}, "lattice_spacing"), ({"lattice_spacing": 9.0}, "lattice_spacing"),
                          ({"lattice_jitter": 0.2}, "lattice_jitter"), ({"lattice_jitter": 0.7}, "lattice_jitter"),
                          ({"lattice_spacing": 1.6}, "lattice_jitter"),
                          ({"lattice_spacing": np.array([1.75, 1.65])}, "lattice_spacing")]:
        bad = S.check_params(lattice, values)
        assert [f for f, _ in bad] == [field], (values, bad)
        assert all(isinstance(a, str) and a and "\n" not in a for _, a in bad)
    assert S.check_params(lattice, {"lattice_spacing": 1.6, "lattice_jitter": 0.0}) == []
    uniform = S.Config(n_agents=20, n_steps=40, warmup_steps=5)
    assert S.check_params(uniform, {"lattice_spacing": 1.65, "lattice_jitter": 0.7}) == []
    with pytest.raises(ValueError, match="start_layout"):
        S.Config(start_layout="hex")
    r = CliRunner().invoke(main, ["list", "flocking"])
    assert r.exit_code == 0 and "start_layout" in r.output and "allowed one of uniform, lattice" in r.output


def test_param_table_and_config_reject_bad_values():
    T = S.Params.TABLE
    for name, bad, good in [("n_sensing", 0.0, 1.0), ("n_sensing", 2.5, 2.0), ("epsilon", 0.0, 0.1),
                            ("epsilon", -1.0, 0.1), ("c1", 0.0, 1.0), ("c2", 0.0, 2.0), ("k", 0.0, 0.1),
                            ("k", -0.1, 0.1), ("R", 0.0, 8.4), ("dt", np.inf, 0.1)]:
        assert T[name].problem(bad) is not None, (name, bad)
        assert T[name].problem(good) is None, (name, good)
    for field, value in (("max_substeps", 0), ("start_attempts", 0), ("max_substeps", 2.5)):
        with pytest.raises(ValueError, match=field):
            S.Config(**{field: value})


def _cli_spec(tmp_path, config="", params="n_sensing = 2\n"):
    spec = tmp_path / "spec.toml"
    spec.write_text(f'base = "{CONFIG}"\nseeds = 2\n[config]\nn_agents = 4\nn_steps = 5\nwarmup_steps = 1\n{config}'
                    f"[params]\n{params}")
    return spec


def test_cli_spec_without_bad_input_validates(tmp_path):
    """The control for the cases below: the same small spec passes validation."""
    from mcjax.study import load_spec

    spec = load_spec(_cli_spec(tmp_path))
    assert spec.scenario is S.SCENARIO and spec.config.n_agents == 4 and spec.n_runs == 2


@pytest.mark.parametrize("case, where", [
    (("", "n_sensing = 9\n"), "params.n_sensing: must be an integer in [1, n_agents = 4]"),  # check_params
    (("", "n_sensing = 2\nepsilon = 9.0\n"), "params.epsilon: must be in (0, R)"),            # check_params
    (("", "n_sensing = 2\nc2 = 0.0\n"), "params.c2: must be > 0"),                           # Param table
    (("", "n_sensing = 0\n"), "params.n_sensing: must be an integer >= 1"),                   # Param table
    (("max_substeps = 0\n", "n_sensing = 2\n"), "config.max_substeps: must be"),             # Config
    (('start_layout = "hex"\n', "n_sensing = 2\n"), "config.start_layout: must be one of uniform, lattice"),
    (('start_layout = "lattice"\n', "n_sensing = 2\nlattice_spacing = 9.0\n"),
     "params.lattice_spacing: must be such that"),                                             # check_params
])
def test_cli_rejects_bad_input_exit_2_nothing_written(tmp_path, case, where):
    """One line, ``error: <where>: …``, exit code 2, nothing written."""
    spec = _cli_spec(tmp_path, *case)
    out = tmp_path / "o"
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out)])
    assert r.exit_code == 2, r.output
    lines = [line for line in r.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: " + where), r.output
    assert not out.exists()


def test_rk4_adaptive_matches_solve_ivp_and_resizes_mid_step():
    """rk4_adaptive (sub-steps sized before each one from the current state) over the same
    5-step window: with a small safety factor it equals solve_ivp to 1e-7; with the
    default it stays within RK4's stability-sized error (1e-2). Two linked nodes closing at
    40 m/s from 1 m apart get sub-steps from the kinematic bound (half the gap per sub-step),
    so they never pass through each other: the smallest distance stays > 0 and finite."""
    q, p, b, adj = ivp_flock()
    g = fl.Gains(**G_IVP)
    h = jnp.asarray(H_MIX)

    @jax.jit
    def advance(q, p, b, t0, safety):
        def reference(tau):
            return (jnp.broadcast_to(Q_TARGET0 + V_TARGET * (t0 + tau), (N5, 2)),
                    jnp.broadcast_to(V_TARGET, (N5, 2)))

        s, margin, dmin, k, capped = fl.rk4_adaptive(fl.FlockState(q, p, b), adj, h, reference, g, DT, 2000, safety)
        return s.q, s.p, s.b, k, capped

    y0 = np.concatenate([q.ravel(), p.ravel(), b.ravel()])
    sol = solve_ivp(np_rhs, (0.0, 5 * DT), y0, method="DOP853", rtol=1e-11, atol=1e-12, dense_output=True,
                    args=(adj, H_MIX, G_IVP["c1"], G_IVP["c2"], G_IVP["k"], G_IVP["R"]))
    for safety, tol in ((0.02, 1e-7), (1.0, 1e-2)):
        state = (q, p, b)
        for m in range(5):
            *state, k, capped = advance(*state, m * DT, safety)
            assert not bool(capped)
        ref = _split(sol.sol(5 * DT))
        err = max(np.max(np.abs(np.asarray(a) - r)) for a, r in zip(state, ref))
        assert err < tol, (safety, err)

    # two nodes closing fast
    q2 = jnp.array([[0.0, 0.0], [1.0, 0.0]])
    p2 = jnp.array([[20.0, 0.0], [-20.0, 0.0]])
    adj2 = jnp.array([[0.0, 1.0], [1.0, 0.0]])
    g2 = fl.Gains(1.0, 2.0, 0.1, 8.4)
    ref2 = lambda tau: (jnp.zeros((2, 2)), jnp.zeros((2, 2)))  # noqa: E731
    s, margin, dmin, k, capped = jax.jit(lambda: fl.rk4_adaptive(
        fl.FlockState(q2, p2, jnp.zeros((2, 2))), adj2, jnp.zeros(2), ref2, g2, 0.1, 500))()
    assert int(k) >= 4 and not bool(capped)
    assert np.isfinite(float(dmin)) and 0 < float(dmin) < 1.0 and np.all(np.isfinite(np.asarray(s.q)))
    # the pair bounced: they end moving apart
    assert float((s.q[1, 0] - s.q[0, 0]) * (s.p[1, 0] - s.p[0, 0])) > 0


def test_the_flock_runs_on_every_device_and_one_device_still_means_one():
    """Lou, Cui & Li 2013's flock declared ``one_device`` until 2026-12-04 (its λ2 eigenvalue batches
    deadlocked two CPU devices: tests/tracking/test_numerics.py, mcjax.tracking.numerics.eigvalsh); it now gets every
    device, and a scenario that declares ``one_device`` still gets one (a subprocess with two CPU
    devices: the count is fixed when JAX starts)."""
    import os
    import subprocess
    import sys

    code = ("import dataclasses, mcjax; mcjax.configure(); from mcjax import engine; "
            "from mcjax.scenarios import lou2013, sun2011; "
            "print(len(engine.devices()), len(engine.devices(lou2013.SCENARIO)), "
            "len(engine.devices(dataclasses.replace(sun2011.SCENARIO, one_device=True))))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                       env={**os.environ, "MCJAX_CPU_DEVICES": "2"})
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.split() == ["2", "2", "1"], r.stdout
