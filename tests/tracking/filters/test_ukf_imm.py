"""UKF and IMM (docs/equations.md) against filterpy and textbook moments."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from filterpy.kalman import ExtendedKalmanFilter, IMMEstimator, KalmanFilter

from mcjax.tracking.filters.gaussian import (
    Unscented, ekf_update, predict_moments, ukf_predict, ukf_pseudo_measurement, ukf_update, unscented_transform,
)
from mcjax.tracking.filters.imm import IMMState, imm_step
from mcjax.tracking.models.motion import ct_matrix, cv_matrices, cv_process_noise
from mcjax.tracking.models.sensors import range_bearing

DT = 1.0
F, _ = cv_matrices(DT, jnp.float64)
H = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
R = np.diag([4.0, 9.0])


def data(steps=40, seed=0):
    rng = np.random.default_rng(seed)
    x = np.array([0.0, 5.0, 0.0, 5.0])
    zs = []
    for k in range(steps):
        accel = rng.normal(0, 2.0 if 15 <= k < 25 else 0.05, 2)  # a manoeuvre in the middle
        x = np.asarray(F) @ x + np.array([0.5 * accel[0], accel[0], 0.5 * accel[1], accel[1]])
        zs.append(H @ x + rng.normal(0, np.sqrt(np.diag(R))))
    return np.array(zs)


def kf(q):
    f = KalmanFilter(dim_x=4, dim_z=2)
    f.x = np.array([[0.0], [5.0], [0.0], [5.0]])
    f.P = np.diag([10.0, 4.0, 10.0, 4.0])
    f.F = np.asarray(F)
    f.Q = np.asarray(cv_process_noise(DT, q, jnp.float64))
    f.H, f.R = H.copy(), R.copy()
    return f


def linear_h(x):
    return jnp.asarray(H) @ x


def ukf_mode(x, P, Q, z):
    xb, Pb = ukf_predict(x, P, lambda s: F @ s, Q)
    return ukf_update(xb, Pb, z, linear_h, jnp.asarray(R))


def test_ukf_equals_kalman_filter_on_a_linear_model():
    ref = kf(1.0)
    x, P = jnp.asarray(ref.x[:, 0]), jnp.asarray(ref.P)
    Q = cv_process_noise(DT, 1.0, jnp.float64)
    step = jax.jit(ukf_mode)
    for z in data():
        ref.predict()
        ref.update(z)
        x, P, ll = step(x, P, Q, jnp.asarray(z))
        np.testing.assert_allclose(np.asarray(x), ref.x[:, 0], rtol=1e-8, atol=1e-8)
        np.testing.assert_allclose(np.asarray(P), ref.P, rtol=1e-8, atol=1e-10)
        np.testing.assert_allclose(float(ll), ref.log_likelihood, rtol=1e-8)


def test_unscented_transform_of_polar_to_cartesian():
    """r ~ N(r0, σ_r²), θ ~ N(θ0, σ_θ²): E[x] = r0 cos θ0 e^{−σ_θ²/2}; the UT captures the
    e^{−σ_θ²/2} shrinkage the linearisation misses, and the covariance to second order."""
    r0, th0, sr, st = 1000.0, 0.7, 10.0, 0.15
    mean, cov, _ = unscented_transform(lambda p: jnp.stack([p[0] * jnp.cos(p[1]), p[0] * jnp.sin(p[1])]),
                                       jnp.array([r0, th0]), jnp.diag(jnp.array([sr**2, st**2])),
                                       Unscented(alpha=1.0, beta=2.0, kappa=1.0))
    shrink = np.exp(-st**2 / 2)
    exact_mean = r0 * shrink * np.array([np.cos(th0), np.sin(th0)])
    linearised = r0 * np.array([np.cos(th0), np.sin(th0)])
    ut_err = np.linalg.norm(np.asarray(mean) - exact_mean)
    assert ut_err < 0.05 * np.linalg.norm(linearised - exact_mean)
    # exact covariance of the polar -> Cartesian map
    m2 = r0**2 + sr**2
    e2 = np.exp(-2 * st**2)
    exx = 0.5 * m2 * (1 + np.cos(2 * th0) * e2)
    eyy = 0.5 * m2 * (1 - np.cos(2 * th0) * e2)
    exy = 0.5 * m2 * np.sin(2 * th0) * e2
    exact_cov = np.array([[exx, exy], [exy, eyy]]) - np.outer(exact_mean, exact_mean)
    np.testing.assert_allclose(np.asarray(cov), exact_cov, rtol=0.02, atol=0.02 * np.abs(exact_cov).max())


def test_pseudo_measurement_is_the_linear_information_on_a_linear_model():
    x = jnp.array([3.0, 1.0, -2.0, 0.5])
    P = jnp.diag(jnp.array([5.0, 2.0, 7.0, 3.0])) + 0.3
    z = jnp.array([4.0, -1.0])
    Rinv = jnp.linalg.inv(jnp.asarray(R))
    i, I, ok = ukf_pseudo_measurement(x, P, z, linear_h, Rinv)
    np.testing.assert_allclose(np.asarray(I), H.T @ np.linalg.inv(R) @ H, atol=1e-10)
    np.testing.assert_allclose(np.asarray(i), H.T @ np.linalg.inv(R) @ np.asarray(z), atol=1e-10)
    assert bool(ok)


TRANSITION = np.array([[0.95, 0.05], [0.10, 0.90]])
QS = (0.05, 2.0)


@jax.jit
def imm_ukf_step(state, z):
    """One step of the IMM of two linear-model UKFs (process noises QS), compiled once for the tests below."""
    Qs = jnp.stack([cv_process_noise(DT, q, jnp.float64) for q in QS])
    return imm_step(state, jnp.asarray(TRANSITION), ukf_mode, Qs, z)


@pytest.mark.xdist_group("test_ukf_imm")  # one worker compiles imm_ukf_step once
def test_imm_equals_filterpy():
    filters = [kf(q) for q in QS]
    ref = IMMEstimator(filters, np.array([0.6, 0.4]), TRANSITION)
    state = IMMState(jnp.array([0.6, 0.4]), jnp.stack([jnp.asarray(f.x[:, 0]) for f in filters]),
                     jnp.stack([jnp.asarray(f.P) for f in filters]))
    for z in data():
        ref.predict()
        ref.update(z)
        state, (x, P) = imm_ukf_step(state, jnp.asarray(z))
        np.testing.assert_allclose(np.asarray(x), ref.x[:, 0], rtol=1e-8, atol=1e-8)
        np.testing.assert_allclose(np.asarray(P), ref.P, rtol=1e-8, atol=1e-10)
        np.testing.assert_allclose(np.asarray(state.mu), ref.mu, rtol=1e-8, atol=1e-12)


def test_imm_of_ekfs_equals_filterpy_on_range_bearing():
    """The same IMM code with EKF modes (the base filter of Chen & Hao 2022's IMM-EKF): CV and CT
    (ω = 0.1 rad/s) EKFs on range–bearing measurements of a target that turns mid-way, vs
    filterpy's IMMEstimator of ExtendedKalmanFilters, to 1e-8 at every step."""
    sensor = np.array([-300.0, 150.0])
    R = np.diag([4.0, 0.01**2])
    Fs = [np.asarray(F), np.asarray(ct_matrix(DT, 0.1, jnp.float64))]
    Q = np.asarray(cv_process_noise(DT, 0.1, jnp.float64))
    rng = np.random.default_rng(3)
    rb, rb_jacobian = jax.jit(range_bearing), jax.jit(jax.jacfwd(range_bearing))  # compiled once, not op by op
    x, zs = np.array([0.0, 5.0, 0.0, 5.0]), []
    for k in range(40):
        x = Fs[1 if 15 <= k < 30 else 0] @ x
        zs.append(np.asarray(rb(jnp.asarray(x), jnp.asarray(sensor))) + rng.normal(0, np.sqrt(np.diag(R))))

    def hx(s):
        return np.asarray(rb(jnp.asarray(s), jnp.asarray(sensor)))

    def jac(s):
        return np.asarray(rb_jacobian(jnp.asarray(s), jnp.asarray(sensor)))

    def residual(a, b):
        d = a - b
        d[1] = (d[1] + np.pi) % (2 * np.pi) - np.pi
        return d

    class EKF(ExtendedKalmanFilter):  # binds h for IMMEstimator's update(z); no control input
        def predict(self, u=None):
            super().predict(0)

        def update(self, z):
            super().update(z, jac, hx, residual=residual)

    refs = []
    for Fm in Fs:
        f = EKF(4, 2)
        f.x, f.P, f.F, f.Q, f.R = np.array([0.0, 5.0, 0.0, 5.0]), np.diag([25.0, 1.0, 25.0, 1.0]), Fm, Q, R
        refs.append(f)
    ref = IMMEstimator(refs, np.array([0.5, 0.5]), TRANSITION)

    def mode(x0, P0, Fm, z):
        xb, Pb = predict_moments(x0, P0, Fm, jnp.asarray(Q))
        return ekf_update(xb, Pb, z, lambda s: range_bearing(s, jnp.asarray(sensor)), jnp.asarray(R),
                          jnp.array([False, True]))

    state = IMMState(jnp.array([0.5, 0.5]), jnp.stack([jnp.asarray(f.x) for f in refs]),
                     jnp.stack([jnp.asarray(f.P) for f in refs]))
    step = jax.jit(lambda s, z: imm_step(s, jnp.asarray(TRANSITION), mode, jnp.asarray(np.stack(Fs)), z))
    mu_ct = []
    for z in zs:
        ref.predict()
        ref.update(z)
        state, (xc, Pc) = step(state, jnp.asarray(z))
        mu_ct.append(float(state.mu[1]))
        np.testing.assert_allclose(np.asarray(xc), ref.x, rtol=1e-8, atol=1e-8)
        np.testing.assert_allclose(np.asarray(Pc), ref.P, rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(np.asarray(state.mu), ref.mu, rtol=1e-8, atol=1e-12)
    # the comparison covers both regimes: CT likely during the turn, CV after it
    assert max(mu_ct[15:32]) > 0.8 and min(mu_ct[33:]) < 0.1, np.round(mu_ct, 2)


@pytest.mark.parametrize("sigmas", [100.0, 1e4])
@pytest.mark.xdist_group("test_ukf_imm")  # one worker compiles imm_ukf_step once
def test_mode_probabilities_survive_an_outlier(sigmas):
    state = IMMState(jnp.array([0.5, 0.5]), jnp.zeros((2, 4)), jnp.stack([jnp.eye(4)] * 2))
    z = jnp.array([sigmas * 2.0, -sigmas * 3.0])  # σ of z is ≥ 2 (R) in each component
    new, (x, P) = imm_ukf_step(state, z)
    mu = np.asarray(new.mu)
    assert np.all(np.isfinite(mu)) and np.all((mu >= 0) & (mu <= 1))
    np.testing.assert_allclose(mu.sum(), 1.0, rtol=1e-12)
    assert mu[1] > mu[0]  # the high-noise mode explains the jump better
    assert np.all(np.isfinite(np.asarray(x))) and np.all(np.isfinite(np.asarray(P)))


def test_moment_prediction_matches_ukf_prediction_for_linear_f():
    x = jnp.array([1.0, 2.0, 3.0, 4.0])
    P = jnp.diag(jnp.array([1.0, 2.0, 3.0, 4.0]))
    Q = cv_process_noise(DT, 1.0, jnp.float64)
    a = ukf_predict(x, P, lambda s: F @ s, Q)
    b = predict_moments(x, P, F, Q)
    for u, v in zip(a, b):
        np.testing.assert_allclose(np.asarray(u), np.asarray(v), rtol=1e-10, atol=1e-10)


def test_consensus_imm_ukf_approaches_the_centralised_imm_ukf():
    """Ren & Lv 2017's consensus IMM-UKF on a complete graph with many iterations tracks the
    centralised IMM-UKF that stacks every node's range-bearing measurement; with no links
    it does not (the test can fail)."""
    from mcjax.tracking.filters.consensus_imm import consensus_imm_ukf_step
    from mcjax.tracking.models.motion import ct_matrix
    from mcjax.tracking.models.sensors import range_bearing

    n = 4
    Fm = jnp.stack([F, ct_matrix(DT, 0.1, jnp.float64)])
    Qm = jnp.stack([cv_process_noise(DT, 0.5, jnp.float64)] * 2)
    Pi = jnp.array([[0.95, 0.05], [0.05, 0.95]])
    sensors = jnp.array([[0.0, 0.0], [500.0, 0.0], [0.0, 500.0], [500.0, 500.0]])
    Rrb = jnp.diag(jnp.array([5.0, 0.01]))
    am = jnp.array([False, True])
    rng = np.random.default_rng(0)
    x = np.array([100.0, 5.0, 200.0, 5.0])
    truth, zs = [], []
    for k in range(40):  # CV, a CT manoeuvre for 15 s, CV
        x = np.asarray(Fm[1] if 15 <= k < 30 else Fm[0]) @ x
        truth.append(x)
        clean = np.asarray(jax.vmap(range_bearing, (None, 0))(jnp.asarray(x), sensors))
        zs.append(clean + rng.normal(0, np.sqrt([5.0, 0.01]), (n, 2)))
    x0, P0 = jnp.array([100.0, 5.0, 200.0, 5.0]), jnp.diag(jnp.array([25.0, 4.0, 25.0, 4.0]))

    def h_all(s):
        return jax.vmap(range_bearing, (None, 0))(s, sensors).reshape(-1)

    def mode(xm, Pm, p, z):
        xb, Pb = ukf_predict(xm, Pm, lambda s: p[0] @ s, p[1])
        return ukf_update(xb, Pb, z, h_all, jnp.kron(jnp.eye(n), Rrb), angle_mask=jnp.tile(am, n))

    state = IMMState(jnp.array([0.5, 0.5]), jnp.tile(x0, (2, 1)), jnp.tile(P0, (2, 1, 1)))
    step = jax.jit(lambda s, z: imm_step(s, Pi, mode, (Fm, Qm), z))
    central = []
    for z in zs:
        state, (xc, _) = step(state, jnp.asarray(z).reshape(-1))
        central.append(np.asarray(xc)[[0, 2]])
    central = np.array(central)
    rmse = np.sqrt(np.mean(np.sum((central - np.array(truth)[:, [0, 2]]) ** 2, -1)))

    @jax.jit  # the graph and L are arguments: one compiled step for both graphs
    def consensus_step(s, z, adj, L):
        return consensus_imm_ukf_step(s, Pi, Fm, Qm, z, sensors, range_bearing, Rrb, adj, steps=L, angle_mask=am)

    def distributed(adj, L):
        s = IMMState(jnp.tile(jnp.array([0.5, 0.5]), (n, 1)), jnp.tile(x0, (n, 2, 1)), jnp.tile(P0, (n, 2, 1, 1)))
        out = []
        for z in zs:
            s, (xc, _) = consensus_step(s, jnp.asarray(z), jnp.asarray(adj), L)
            mu = np.asarray(s.mu)
            assert np.all(np.isfinite(mu)) and np.allclose(mu.sum(-1), 1.0)
            out.append(np.asarray(xc)[:, [0, 2]])
        return np.abs(np.array(out) - central[:, None]).max()

    complete = distributed(1.0 - np.eye(n), 20)
    empty = distributed(np.zeros((n, n)), 1)
    assert complete < 0.15 * rmse, (complete, rmse)
    assert empty > 10 * complete
