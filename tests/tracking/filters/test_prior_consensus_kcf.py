"""The consensus Kalman filter of Chen & Lu 2013 (eqs. 6–12; ``kcf_gain = "prior_consensus"``)
against numpy written from the paper's equations and against filterpy's Kalman filter."""

import jax
import jax.numpy as jnp
import numpy as np
from filterpy.kalman import KalmanFilter

from mcjax.tracking.filters.consensus import FilterOptions, Measurements, prior_consensus_kcf_step
from mcjax.tracking.filters.gaussian import Gaussian

OPTS = FilterOptions(weights="max_degree", kcf_gain="prior_consensus")
D = 2  # a wind vector [w_x, w_y]


def _wind(x, sensor):
    del sensor
    return x


def _max_degree_numpy(A):
    """Eq. 7: w_il = 1/N for a neighbour, 1 − d_i/N on the diagonal."""
    n = len(A)
    W = A / n
    W[np.diag_indices(n)] = 1.0 - A.sum(1) / n
    return W


def _step_numpy(xb, Pb, z, R, A, formation):
    """One step of eqs. 6–9 (both lines of eq. 9) and eq. 12, from the priors (x̄_i, P̄_i)."""
    n = len(xb)
    W = _max_degree_numpy(A)
    J = A + np.eye(n)
    Rinv = np.linalg.inv(R)
    S = np.array([sum(J[i, j] * Rinv for j in range(n)) for i in range(n)])
    y = np.array([sum(J[i, j] * Rinv @ z[j] for j in range(n)) for i in range(n)])
    M = np.array([np.linalg.inv(np.linalg.inv(Pb[i]) + S[i]) for i in range(n)])
    xc = W @ xb                                                      # eq. 6
    first = np.array([xc[i] + M[i] @ (y[i] - S[i] @ xc[i]) for i in range(n)])   # eq. 9, line 1
    second = np.array([xb[i] + M[i] @ (y[i] - S[i] @ xb[i])
                       + (np.eye(D) - M[i] @ S[i]) @ sum(W[i, j] * (xb[j] - xb[i]) for j in range(n) if j != i)
                       for i in range(n)])                           # eq. 9, line 2
    eq12 = np.array([xb[i] + M[i] @ (y[i] - S[i] @ xb[i])
                     + (np.eye(D) - M[i] @ S[i]) @ sum(W[i, j] * (xb[j] - xb[i] + formation[i, j])
                                                       for j in range(n) if j != i)
                     for i in range(n)])                             # eq. 12
    return first, second, eq12, M


def _random_case(rng, n=4):
    A = np.zeros((n, n))
    for i in range(n - 1):  # a path, plus one random chord
        A[i, i + 1] = A[i + 1, i] = 1
    A[0, n - 1] = A[n - 1, 0] = 1
    xb = rng.normal(0, 3, (n, D))
    L = rng.normal(0, 1, (n, D, D))
    Pb = L @ np.swapaxes(L, 1, 2) + 0.5 * np.eye(D)
    R = np.diag(rng.uniform(1, 4, D))
    z = rng.normal(0, 5, (n, D))
    formation = rng.normal(0, 2, (n, n, D))
    return A, xb, Pb, R, z, formation


@jax.jit
def _mcjax_step(xb, Pb, z, R, A, formation):
    n = xb.shape[0]
    post = Gaussian(jnp.asarray(xb), jnp.asarray(Pb), jnp.linalg.inv(jnp.asarray(Pb)))
    meas = Measurements(jnp.asarray(z), jnp.zeros((n, 2)), jnp.asarray(A),
                        jnp.broadcast_to(jnp.linalg.inv(jnp.asarray(R)), (n, D, D)))
    F, Q = jnp.eye(D), jnp.zeros((D, D))
    return prior_consensus_kcf_step(_wind, jnp.array([False, False]), OPTS, post, meas, F, Q, formation)


def _mcjax(xb, Pb, z, R, A, formation=None):
    """One step; no formation term (``None``) is passed as zeros — eq. 12 with η = 0 is eq. 9,
    which the test checks separately against the numpy eq. 9."""
    return _mcjax_step(xb, Pb, z, R, A, np.zeros(xb.shape[:1] * 2 + xb.shape[1:]) if formation is None else formation)


def test_both_lines_of_eq9_and_eq12_match_numpy():
    rng = np.random.default_rng(0)
    for _ in range(5):
        A, xb, Pb, R, z, formation = _random_case(rng)
        first, second, eq12, M = _step_numpy(xb, Pb, z, R, A, formation)
        np.testing.assert_allclose(first, second, rtol=0, atol=1e-12 * np.abs(first).max())
        got = _mcjax(xb, Pb, z, R, A)
        np.testing.assert_allclose(np.asarray(got.x), first, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(np.asarray(got.P), M, rtol=1e-12, atol=1e-14)
        got12 = _mcjax(xb, Pb, z, R, A, formation)
        np.testing.assert_allclose(np.asarray(got12.x), eq12, rtol=1e-12, atol=1e-12)
        assert np.abs(eq12 - first).max() > 1e-3  # the formation term really acts
        # η = 0 (a zero formation term) is eq. 9
        np.testing.assert_allclose(np.asarray(_mcjax(xb, Pb, z, R, A, 0 * formation).x), first, rtol=1e-13,
                                   atol=1e-13)
    # formation=None (eq. 9 without the term), called directly (jitted: op by op it took seconds)
    n = len(xb)
    none = jax.jit(lambda post, meas: prior_consensus_kcf_step(_wind, jnp.array([False, False]), OPTS, post, meas,
                                                               jnp.eye(D), jnp.zeros((D, D))))(
        Gaussian(jnp.asarray(xb), jnp.asarray(Pb), jnp.linalg.inv(Pb)),
        Measurements(jnp.asarray(z), jnp.zeros((n, 2)), jnp.asarray(A), jnp.broadcast_to(jnp.linalg.inv(R), (n, D, D))))
    np.testing.assert_allclose(np.asarray(none.x), first, rtol=1e-12, atol=1e-12)


def test_complete_graph_equals_centralised_kalman_filter():
    """Max-degree weights on a complete graph average all priors in one exchange, and every
    agent adds every agent's measurement: with equal priors each agent is the centralised KF
    on the stacked measurements (filterpy), step after step."""
    rng = np.random.default_rng(1)
    n, T = 4, 25
    A = np.ones((n, n)) - np.eye(n)
    F = np.eye(D)
    Q = np.eye(D) * 0.3
    R = np.diag([4.0, 9.0])
    kf = KalmanFilter(dim_x=D, dim_z=D * n)
    kf.x = np.zeros(D)
    kf.P = np.eye(D) * 100.0
    kf.F, kf.Q = F, Q
    kf.H = np.vstack([np.eye(D)] * n)
    kf.R = np.kron(np.eye(n), R)
    truth = np.array([28.3, 28.3])
    n_agents = n
    post = Gaussian(jnp.zeros((n, D)), jnp.broadcast_to(jnp.eye(D) * 100.0, (n, D, D)),
                    jnp.broadcast_to(jnp.eye(D) / 100.0, (n, D, D)))
    step = jax.jit(lambda post, z, first: prior_consensus_kcf_step(
        _wind, jnp.array([False, False]), OPTS, post,
        Measurements(z, jnp.zeros((n_agents, 2)), jnp.asarray(A), jnp.broadcast_to(jnp.linalg.inv(R), (n, D, D))),
        jnp.where(first, jnp.eye(D), F), jnp.where(first, 0.0, Q)))
    for t in range(T):
        z = truth + rng.uniform(-10, 10, (n, D))
        if t > 0:
            kf.predict()
        kf.update(z.reshape(-1))
        post = step(post, jnp.asarray(z), t == 0)
        for i in range(n):
            np.testing.assert_allclose(np.asarray(post.x[i]), kf.x, rtol=1e-10, atol=1e-10)
            np.testing.assert_allclose(np.asarray(post.P[i]), kf.P, rtol=1e-10, atol=1e-12)
