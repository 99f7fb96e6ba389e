"""The posterior Cramér–Rao bound (mcjax.tracking.filters.bounds, Tichavský, Muravchik & Nehorai 1998):
on a linear Gaussian model it is the Kalman filter's covariance (a numpy filter written here) at every
step to 1e-9; it falls when information is added (more sensors, smaller noise, a measurement
taken rather than gated out); with a range–bearing sensor its measurement information is the
textbook Hᵀ R⁻¹ H of the polar Jacobian; and an EKF on that sensor does no better than it."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mcjax.analysis.statistics import mean_ci
from mcjax.tracking.filters.bounds import measurement_information, pcrb, pcrb_covariance_step, pcrb_step
from mcjax.tracking.models.motion import cv_matrices, cv_process_noise
from mcjax.tracking.models.sensors import range_bearing

DT, SIGMA_A, STEPS = 1.0, 0.7, 40


def _cv():
    F, _ = cv_matrices(DT)
    return np.asarray(F), np.asarray(cv_process_noise(DT, SIGMA_A))


def _kalman_covariances(P0, F, Q, H, R, steps):
    """The Kalman filter's posterior covariance per step (numpy, Joseph form)."""
    P, out = P0, []
    for _ in range(steps):
        P = F @ P @ F.T + Q
        K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
        A = np.eye(len(P)) - K @ H
        P = A @ P @ A.T + K @ R @ K.T
        out.append(P)
    return np.stack(out)


@pytest.mark.parametrize("sensors", [1, 3])
def test_linear_gaussian_bound_is_the_kalman_covariance(sensors):
    F, Q = _cv()
    H1 = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
    R1 = np.diag([4.0, 9.0])
    H = np.vstack([H1] * sensors)
    R = np.kron(np.eye(sensors), R1)
    P0 = np.diag([100.0, 4.0, 100.0, 4.0])
    Jz = np.broadcast_to(sensors * H1.T @ np.linalg.inv(R1) @ H1, (STEPS, 4, 4))
    bound = np.asarray(pcrb(jnp.asarray(np.linalg.inv(P0)), jnp.asarray(F), jnp.asarray(Q), jnp.asarray(Jz)))
    kf = _kalman_covariances(P0, F, Q, H, R, STEPS)
    np.testing.assert_allclose(bound, kf, rtol=1e-9, atol=1e-12 * np.abs(kf).max())


def test_the_covariance_form_is_the_inverse_and_allows_a_known_initial_state():
    """pcrb_covariance_step is the inverse of pcrb_step where J is invertible; from C0 = 0 (the state
    known) it is the Kalman filter's covariance started from P0 = 0 (numpy, Joseph form)."""
    F, Q = _cv()
    rng = np.random.default_rng(5)
    A = rng.normal(size=(4, 4))
    J = A @ A.T + np.eye(4)
    H1 = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
    Jz = H1.T @ np.diag([0.25, 1 / 9]) @ H1
    info = np.asarray(pcrb_step(jnp.asarray(J), jnp.asarray(F), jnp.asarray(Q), jnp.asarray(Jz)))
    cov = np.asarray(pcrb_covariance_step(jnp.asarray(np.linalg.inv(J)), jnp.asarray(F), jnp.asarray(Q),
                                          jnp.asarray(Jz)))
    np.testing.assert_allclose(cov, np.linalg.inv(info), rtol=1e-9)
    C, out = jnp.zeros((4, 4)), []
    for _ in range(STEPS):
        C = pcrb_covariance_step(C, jnp.asarray(F), jnp.asarray(Q), jnp.asarray(Jz))
        out.append(np.asarray(C))
    kf = _kalman_covariances(np.zeros((4, 4)), F, Q, H1, np.diag([4.0, 9.0]), STEPS)
    np.testing.assert_allclose(np.stack(out), kf, rtol=1e-9, atol=1e-12 * np.abs(kf).max())


def test_the_bound_falls_when_information_is_added():
    F, Q = _cv()
    J0 = jnp.asarray(np.diag([0.01, 0.25, 0.01, 0.25]))
    H1 = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])

    def final_position_variance(sensors, sigma, taken=1.0):
        Jz = taken * sensors * H1.T @ H1 / sigma**2
        P = pcrb(J0, jnp.asarray(F), jnp.asarray(Q), jnp.broadcast_to(jnp.asarray(Jz), (STEPS, 4, 4)))[-1]
        return float(P[0, 0] + P[2, 2])

    base = final_position_variance(2, 3.0)
    assert final_position_variance(4, 3.0) < base          # more agents
    assert final_position_variance(2, 1.5) < base          # smaller measurement noise
    assert final_position_variance(2, 3.0, taken=0.0) > base  # no measurement: only the prior and the motion


def test_range_bearing_information_is_the_polar_jacobians():
    x = jnp.asarray([3000.0, 10.0, 4000.0, -5.0])
    sensor = jnp.asarray([0.0, 0.0])
    Rinv = jnp.diag(jnp.asarray([1 / 10.0**2, 1 / 0.017**2]))
    info = np.asarray(measurement_information(lambda s: range_bearing(s, sensor), x, Rinv))
    r = 5000.0
    dx, dy = 3000.0, 4000.0
    H = np.array([[dx / r, 0, dy / r, 0], [-dy / r**2, 0, dx / r**2, 0]])  # ∂(range, bearing)/∂[x, ẋ, y, ẏ]
    np.testing.assert_allclose(info, H.T @ np.asarray(Rinv) @ H, rtol=1e-12)
    gated = measurement_information(lambda s: range_bearing(s, sensor), x, Rinv, taken=False)
    assert not np.any(np.asarray(gated))


def test_an_ekf_on_range_bearing_data_is_not_below_the_bound():
    """500 runs of a CV target seen by two range–bearing sensors: the EKF's mean squared position
    error over steps 10–29 is not below the bound's (the Monte-Carlo PCRB: its position variance
    along each run's own trajectory, averaged): the error's 95 % interval reaches the bound, and
    the EKF, nearly efficient here, is within 20 % of it."""
    rng = np.random.default_rng(3)
    F, Q = _cv()
    sensors = np.array([[0.0, 0.0], [6000.0, 0.0]])
    sig = np.array([10.0, 0.017])
    Rinv = np.diag(1 / sig**2)
    runs, steps = 500, 30
    P0 = np.diag([200.0**2, 5.0**2, 200.0**2, 5.0**2])
    x = np.array([3000.0, 10.0, 5000.0, -5.0]) + rng.normal(size=(runs, 4)) * np.sqrt(np.diag(P0))
    xh = np.broadcast_to(np.array([3000.0, 10.0, 5000.0, -5.0]), (runs, 4)).copy()
    P = np.broadcast_to(P0, (runs, 4, 4)).copy()
    chol = np.linalg.cholesky(Q + 1e-12 * np.eye(4))
    truth, sq = [], []
    for _ in range(steps):
        x = x @ F.T + rng.normal(size=(runs, 4)) @ chol.T
        truth.append(x.copy())
        xh, P = xh @ F.T, F @ P @ F.T + Q
        for s in sensors:
            d = np.stack([xh[:, 0] - s[0], xh[:, 2] - s[1]], -1)
            r = np.hypot(d[:, 0], d[:, 1])
            H = np.zeros((runs, 2, 4))
            H[:, 0, 0], H[:, 0, 2] = d[:, 0] / r, d[:, 1] / r
            H[:, 1, 0], H[:, 1, 2] = -d[:, 1] / r**2, d[:, 0] / r**2
            zt = np.stack([np.hypot(x[:, 0] - s[0], x[:, 2] - s[1]), np.arctan2(x[:, 2] - s[1], x[:, 0] - s[0])], -1)
            z = zt + rng.normal(size=(runs, 2)) * sig
            nu = z - np.stack([r, np.arctan2(d[:, 1], d[:, 0])], -1)
            nu[:, 1] = (nu[:, 1] + np.pi) % (2 * np.pi) - np.pi
            S = H @ P @ H.transpose(0, 2, 1) + np.diag(sig**2)
            K = P @ H.transpose(0, 2, 1) @ np.linalg.inv(S)
            xh = xh + np.einsum("bij,bj->bi", K, nu)
            P = (np.eye(4) - K @ H) @ P
        sq.append((xh[:, 0] - x[:, 0]) ** 2 + (xh[:, 2] - x[:, 2]) ** 2)
    truth = np.stack(truth, 1)                       # (runs, T, 4)
    Jz = jax.vmap(jax.vmap(lambda xt: sum(measurement_information(
        lambda q, s=jnp.asarray(s): range_bearing(q, s), xt, jnp.asarray(Rinv)) for s in sensors)))(jnp.asarray(truth))
    bound = jax.vmap(lambda jz: pcrb(jnp.asarray(np.linalg.inv(P0)), jnp.asarray(F), jnp.asarray(Q), jz))(Jz)
    floor = np.asarray(bound[..., 0, 0] + bound[..., 2, 2]).mean(0)   # the Monte-Carlo PCRB's position MSE
    per_run = np.stack(sq, 1)[:, 10:].mean(1)        # each run's mean squared position error
    m = mean_ci(per_run)
    assert m.high >= floor[10:].mean(), (m, floor[10:].mean())
    assert m.mean < 1.2 * floor[10:].mean(), (m, floor[10:].mean())


def test_in_ren2017_no_filter_is_below_the_floor_given_the_modes():
    """Ren & Lv 2017 (20 runs, the paper's turn; the IMM-UKF and the CV-only filter, two of its three
    to keep the compile short): neither's mean squared position error is below the bound given the
    true mode sequence, and the turn-aware IMM is the nearer to it."""
    from mcjax.study import build_spec, run_sweep

    spec = build_spec({"base": "../configs/ren2017.toml", "config": {"bound": "on", "filters": ["imm", "cv"]}},
                      Path(__file__).parents[2], seeds=20)
    df = run_sweep(spec)
    ratio = {}
    for f, g in df.groupby("filter"):
        m, floor = mean_ci((g["rmse"] ** 2).to_numpy()), float(np.mean(g["pcrb_rmse"] ** 2))
        assert m.high >= floor, (f, m, floor)
        ratio[f] = m.mean / floor
    assert min(ratio, key=ratio.get) == "imm", ratio
