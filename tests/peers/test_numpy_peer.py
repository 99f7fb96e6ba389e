"""Validate the plain-numpy peer (benchmarks/peers/numpy_peer.py) against independent references.

References: filterpy's ExtendedKalmanFilter (single agent; sequential updates), exact
algebraic identities of the consensus filters (complete graph → centralised, empty graph →
local), and hand-computed consensus weights.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from filterpy.kalman import ExtendedKalmanFilter

from benchmarks.peers import numpy_peer as peer

# ---------------------------------------------------------------- seed-000-like scenario

KM = 1000.0
T = 30
DT = 1.0
SIGMA_A = 50.0
SIGMA_R = 10.0
SIGMA_B = 0.017
POSITIONS0 = np.array([[20, 150], [80, 150], [130, 200], [130, 100], [180, 150]]) * KM
HEADINGS = np.zeros(5)
SPEED = 800.0
X_TARGET0 = np.array([200 * KM, 200.0, 180 * KM, -1000.0])
SENSING = 120 * KM
COMM = 100 * KM
P0 = np.diag([1e4, 1e2, 1e4, 1e2])
R = np.diag([SIGMA_R**2, SIGMA_B**2])


def _scenario(seed=0, agents=None, sensing=SENSING, positions=None, headings=None):
    rng = np.random.default_rng(seed)
    pos = POSITIONS0 if agents is None else POSITIONS0[agents]
    if positions is not None:
        pos = np.asarray(positions, dtype=float)
    head = HEADINGS[: len(pos)] if headings is None else np.asarray(headings, dtype=float)
    z, s, a, truth = peer.simulate_open_loop_numpy(
        rng, T, pos, head, SPEED, X_TARGET0, DT,
        SIGMA_A, SIGMA_R, SIGMA_B, sensing, COMM,
    )
    x0 = X_TARGET0 + np.sqrt(np.diag(P0)) * rng.standard_normal(4)
    F, Q = peer.cv_matrices(DT, SIGMA_A)
    return dict(measurements=z, sensor_positions=s, adjacency=a, x0=x0, P0=P0, F=F, Q=Q, R=R)


@pytest.fixture(scope="module")
def scen5():
    return _scenario(seed=0)


def _assert_est_close(est, ref, tol):
    """Relative comparison with a per-state-component scale (positions vs velocities)."""
    scale = np.abs(ref).reshape(-1, 4).max(axis=0)
    _assert_close(est, ref, tol, tol * scale)


def _assert_cov_close(cov, ref, tol):
    d = np.sqrt(np.abs(np.diagonal(ref, axis1=-2, axis2=-1)).reshape(-1, 4).max(axis=0))
    _assert_close(cov, ref, tol, tol * np.outer(d, d))


def _assert_close(a, b, rtol, atol):
    """``|a − b| <= rtol |b| + atol`` elementwise, with an array-valued ``atol``."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape, (a.shape, b.shape)
    excess = np.abs(a - b) / (rtol * np.abs(b) + atol)
    assert np.all(np.isfinite(a)) and np.all(excess <= 1.0), (
        f"max |a-b|/(rtol|b|+atol) = {np.nanmax(excess):.3g}; max |a-b| = {np.max(np.abs(a - b)):.3g}"
    )


# ---------------------------------------------------------------- independent EKF model


def _h(x, s):
    px, py = float(x[0, 0]), float(x[2, 0])
    return np.array([[math.hypot(px - s[0], py - s[1])], [math.atan2(py - s[1], px - s[0])]])


def _H(x, s):
    dx, dy = float(x[0, 0]) - s[0], float(x[2, 0]) - s[1]
    r2 = dx * dx + dy * dy
    r = math.sqrt(r2)
    return np.array([[dx / r, 0.0, dy / r, 0.0], [-dy / r2, 0.0, dx / r2, 0.0]])


def _residual(a, b):
    y = a - b
    y[1, 0] = (y[1, 0] + math.pi) % (2 * math.pi) - math.pi
    return y


def _make_ekf(x0, P0, F, Q):
    ekf = ExtendedKalmanFilter(dim_x=4, dim_z=2)
    ekf.x = x0.reshape(4, 1).copy()
    ekf.P = P0.copy()
    ekf.F = F.copy()
    ekf.Q = Q.copy()
    ekf.R = R.copy()
    return ekf


# ---------------------------------------------------------------- (1) single agent vs filterpy


# Agent 2 of the scenario, and a sensor due east of the target flying south alongside it, so
# the bearing to the target hovers around ±π (dy from +3 km to −3 km at ~60 km range, σ_b =
# 0.017 rad): measurement and prediction often straddle the branch cut, exercising the
# bearing wrapping of the innovation and of the simulated measurement.
_SINGLE = {
    "agent2": dict(agents=[2]),
    "wrap": dict(positions=[[260 * KM, 177 * KM]], headings=[-np.pi / 2]),
}


@pytest.mark.parametrize("geometry", sorted(_SINGLE))
@pytest.mark.parametrize("kind", ["cif", "local"])
def test_single_agent_matches_filterpy_ekf(kind, geometry):
    sc = _scenario(seed=1, **_SINGLE[geometry])
    z = sc["measurements"].copy()
    z[[5, 6, 17], 0, :] = np.nan  # exercise missed measurements
    z[11, 0, 1] = np.nan  # one invalid component invalidates the whole measurement
    sc["measurements"] = z
    assert np.isfinite(z[:, 0, 0]).sum() >= T - 5
    if geometry == "wrap":
        b = z[np.isfinite(z[:, 0, 1]), 0, 1]
        assert (b > 3.0).sum() >= 5 and (b < -3.0).sum() >= 5

    ekf = _make_ekf(sc["x0"], sc["P0"], sc["F"], sc["Q"])
    ref_x, ref_P = [], []
    for t in range(T):
        if t > 0:
            ekf.predict()
        if np.all(np.isfinite(z[t, 0])):
            s = sc["sensor_positions"][t, 0]
            ekf.update(z[t, 0].reshape(2, 1), _H, _h, args=(s,), hx_args=(s,),
                       residual=_residual)
        ref_x.append(ekf.x[:, 0].copy())
        ref_P.append(ekf.P.copy())
    ref_x, ref_P = np.array(ref_x), np.array(ref_P)

    est, cov = peer.run_filter_numpy(kind, **sc)
    assert est.shape == (T, 1, 4) and cov.shape == (T, 1, 4, 4)
    _assert_est_close(est[:, 0], ref_x, 1e-8)
    _assert_cov_close(cov[:, 0], ref_P, 1e-8)


# ---------------------------------------------------------------- (2) two agents, sequential updates


def test_two_agent_cif_matches_sequential_linearised_updates():
    """CIF linearises both measurements at the common prior, so the reference is filterpy's
    EKF doing two sequential updates with the measurement model linearised at the prior
    (a linear KF step) — sequential and batch linear updates are algebraically identical."""
    sc = _scenario(seed=2, agents=[2, 3], sensing=1e12)
    z, s_all = sc["measurements"], sc["sensor_positions"]
    assert np.all(np.isfinite(z))

    ekf = _make_ekf(sc["x0"], sc["P0"], sc["F"], sc["Q"])
    ref_x, ref_P = [], []
    for t in range(T):
        if t > 0:
            ekf.predict()
        xbar = ekf.x.copy()
        for j in range(2):
            s = s_all[t, j]
            Hj = _H(xbar, s)
            hbar = _h(xbar, s)
            ekf.update(
                z[t, j].reshape(2, 1),
                lambda x, Hj=Hj: Hj,
                lambda x, Hj=Hj, hbar=hbar: hbar + Hj @ (x - xbar),
                residual=_residual,
            )
        ref_x.append(ekf.x[:, 0].copy())
        ref_P.append(ekf.P.copy())
    ref_x, ref_P = np.array(ref_x), np.array(ref_P)

    est, cov = peer.run_filter_numpy("cif", **sc)
    for i in range(2):  # the CIF reports the same estimate for every agent
        _assert_est_close(est[:, i], ref_x, 1e-6)
        _assert_cov_close(cov[:, i], ref_P, 1e-6)


# ---------------------------------------------------------------- (3)/(4) complete graph → CIF


def _complete(sc):
    n = sc["measurements"].shape[1]
    sc = dict(sc)
    sc["adjacency"] = np.broadcast_to(np.ones((n, n)) - np.eye(n), (T, n, n)).copy()
    return sc


@pytest.fixture(scope="module")
def cif5(scen5):
    return peer.run_filter_numpy("cif", **scen5)


@pytest.mark.xdist_group("test_numpy_peer")  # one worker builds the module fixture once
def test_scenario_is_nontrivial(scen5):
    valid = np.all(np.isfinite(scen5["measurements"]), axis=-1)
    assert valid.any(axis=0).sum() >= 3  # several agents measure at some point
    assert (~valid).any()  # and some measurements are missing
    assert scen5["adjacency"].sum() > 0


@pytest.mark.xdist_group("test_numpy_peer")  # one worker builds the module fixture once
@pytest.mark.parametrize("weights", peer.WEIGHT_KINDS)
@pytest.mark.parametrize("steps", [1, 20])
def test_modified_icf_complete_graph_equals_cif(scen5, cif5, weights, steps):
    est, cov = peer.run_filter_numpy(
        "modified_icf", **_complete(scen5), consensus_steps=steps, weights=weights,
        contribution="component",
    )
    _assert_est_close(est, cif5[0], 1e-8)
    _assert_cov_close(cov, cif5[1], 1e-8)


@pytest.mark.xdist_group("test_numpy_peer")  # one worker builds the module fixture once
@pytest.mark.parametrize("weights", peer.WEIGHT_KINDS)
@pytest.mark.parametrize("steps", [1, 20])
def test_icf_contributions_complete_graph_equals_cif(scen5, cif5, weights, steps):
    est, cov = peer.run_filter_numpy(
        "icf", **_complete(scen5), consensus_steps=steps, weights=weights,
        contribution="component", icf_variant="contributions",
    )
    _assert_est_close(est, cif5[0], 1e-8)
    _assert_cov_close(cov, cif5[1], 1e-8)


@pytest.mark.xdist_group("test_numpy_peer")  # one worker builds the module fixture once
@pytest.mark.parametrize("gain", peer.KCF_GAINS)
def test_kcf_complete_graph_equals_cif(scen5, cif5, gain):
    """With everyone a neighbour and identical priors, S_i = Σ_j U_j, the consensus term
    vanishes, and the KCF update is the centralised one."""
    est, cov = peer.run_filter_numpy("kcf", **_complete(scen5), kcf_gain=gain)
    _assert_est_close(est, cif5[0], 1e-8)
    _assert_cov_close(cov, cif5[1], 1e-8)


@pytest.mark.xdist_group("test_numpy_peer")  # one worker builds the module fixture once
def test_modified_icf_without_component_weighting_differs_from_cif(scen5, cif5):
    """Sanity: the identities above are not vacuous (s_i = 1 under-weights the data)."""
    est, _ = peer.run_filter_numpy("modified_icf", **_complete(scen5), contribution="one")
    assert np.max(np.abs(est - cif5[0])) > 1e-3


# ---------------------------------------------------------------- (5) empty graph → local


@pytest.mark.parametrize(
    "kind, kwargs",
    [
        ("modified_icf", dict(consensus_steps=3, weights="metropolis")),
        ("modified_icf", dict(consensus_steps=1, weights="eq11", contribution="one")),
        ("icf", dict(consensus_steps=3, weights="max_degree", icf_variant="contributions")),
        ("icf", dict(consensus_steps=3, weights="eq11", icf_variant="priors")),
        ("kcf", dict(kcf_gain="gamma_M")),
        ("kcf", dict(kcf_gain="mu_P", kcf_epsilon=0.5)),
    ],
)
@pytest.mark.xdist_group("test_numpy_peer")  # one worker builds the module fixture once
def test_empty_graph_equals_local(scen5, kind, kwargs):
    sc = dict(scen5)
    sc["adjacency"] = np.zeros_like(scen5["adjacency"])
    ref = peer.run_filter_numpy("local", **sc)
    est, cov = peer.run_filter_numpy(kind, **sc, **kwargs)
    # Relative to each array's overall magnitude: the KCF (moment form) and the post-consensus
    # prior x̄ = Ȳ⁻¹ȳ of the "priors" variant take different rounding routes from the
    # information-form local filter, whose own round-off is ~cond(Y)·eps·‖x‖∞ (≈1e-12 of
    # 2e5 m here); that couples into velocities and into near-singular bearing-only
    # covariances, so per-component scaling would test floating point, not the algebra.
    _assert_close(est, ref[0], 1e-10, 1e-10 * np.abs(ref[0]).max())
    _assert_close(cov, ref[1], 1e-10, 1e-10 * np.abs(ref[1]).max())


# ---------------------------------------------------------------- (6) consensus weights


# Path 0–1–2 plus isolated node 3: degrees [1, 2, 1, 0].
_A_PATH = np.array([[0, 1, 0, 0], [1, 0, 1, 0], [0, 1, 0, 0], [0, 0, 0, 0]], dtype=float)
_W_EXPECTED = {
    "eq11": [[1 / 2, 1 / 2, 0, 0], [1 / 3, 1 / 3, 1 / 3, 0], [0, 1 / 2, 1 / 2, 0], [0, 0, 0, 1]],
    "metropolis": [[2 / 3, 1 / 3, 0, 0], [1 / 3, 1 / 3, 1 / 3, 0], [0, 1 / 3, 2 / 3, 0],
                   [0, 0, 0, 1]],
    "max_degree": [[3 / 4, 1 / 4, 0, 0], [1 / 4, 1 / 2, 1 / 4, 0], [0, 1 / 4, 3 / 4, 0],
                   [0, 0, 0, 1]],
}


@pytest.mark.parametrize("kind", peer.WEIGHT_KINDS)
def test_weights_hand_computed(kind):
    np.testing.assert_allclose(peer.consensus_weights(_A_PATH, kind), _W_EXPECTED[kind],
                               atol=1e-15)


@pytest.mark.parametrize("kind", peer.WEIGHT_KINDS)
def test_weights_row_sums_random_graphs(kind):
    rng = np.random.default_rng(6)
    for _ in range(50):
        n = int(rng.integers(1, 9))
        A = np.triu((rng.random((n, n)) < 0.4).astype(float), 1)
        A = A + A.T
        W = peer.consensus_weights(A, kind)
        np.testing.assert_allclose(W.sum(axis=1), 1.0, atol=1e-14)
        assert np.all(W >= 0)
        assert np.all(W[(A == 0) & ~np.eye(n, dtype=bool)] == 0)
        if kind != "eq11":  # Metropolis and max-degree weights are symmetric
            np.testing.assert_allclose(W, W.T, atol=1e-15)
            np.testing.assert_allclose(W.sum(axis=0), 1.0, atol=1e-14)


def test_component_sizes():
    np.testing.assert_array_equal(peer.component_sizes(_A_PATH), [3, 3, 3, 1])
    np.testing.assert_array_equal(peer.component_sizes(np.zeros((3, 3))), [1, 1, 1])


# ---------------------------------------------------------------- simulator sanity


def test_simulator_noise_free_geometry():
    rng = np.random.default_rng(0)
    n = 5
    z, s, a, truth = peer.simulate_open_loop_numpy(
        rng, T, POSITIONS0, HEADINGS, SPEED, X_TARGET0, DT, 0.0, 0.0, 0.0, SENSING, COMM
    )
    for t in range(T):
        # zero process noise: straight-line target
        exp_x = [X_TARGET0[0] + t * DT * X_TARGET0[1], X_TARGET0[1],
                 X_TARGET0[2] + t * DT * X_TARGET0[3], X_TARGET0[3]]
        np.testing.assert_allclose(truth[t], exp_x, rtol=1e-12)
        for i in range(n):
            sx = POSITIONS0[i, 0] + t * DT * SPEED
            sy = POSITIONS0[i, 1]
            np.testing.assert_allclose(s[t, i], [sx, sy], rtol=1e-12)
            r = math.hypot(exp_x[0] - sx, exp_x[2] - sy)
            if r > SENSING:
                assert np.all(np.isnan(z[t, i]))
            else:
                np.testing.assert_allclose(z[t, i], [r, math.atan2(exp_x[2] - sy, exp_x[0] - sx)],
                                           rtol=1e-12)
            for j in range(n):
                d = math.hypot(POSITIONS0[i, 0] - POSITIONS0[j, 0],
                               POSITIONS0[i, 1] - POSITIONS0[j, 1])
                assert a[t, i, j] == (1.0 if (i != j and d <= COMM) else 0.0)
