"""The filterpy peer of mcjax's local EKF, and the runs the filter peers are compared on.

* :func:`make_runs` -- independent open-loop runs of Sun et al. 2011's set-up from the numpy
  simulator (:mod:`benchmarks.peers.numpy_peer`): measurements, sensor positions, adjacency, truth.
* :func:`filterpy_local` -- filterpy's ``ExtendedKalmanFilter`` loop over one run, the tool a
  researcher reaches for (filterpy is imported when it is called: a test and benchmark dependency).
* :func:`max_relative_error` -- the largest difference of two filters' estimates and covariances,
  relative to each component's scale.
"""

from __future__ import annotations

import math

import numpy as np

from benchmarks.peers import numpy_peer

KM = 1e3


def make_runs(n_runs: int, steps: int, seed: int = 0):
    """``n_runs`` independent open-loop runs of Sun et al. 2011's set-up (numpy simulator)."""
    rng = np.random.default_rng(seed)
    positions = np.array([[20, 150], [80, 150], [130, 200], [130, 100], [180, 150]]) * KM
    heading = np.full(5, np.arctan2(-1000.0, 200.0))
    runs = [numpy_peer.simulate_open_loop_numpy(
        rng, steps, positions, heading, 800.0, np.array([200 * KM, 200.0, 180 * KM, -1000.0]),
        1.0, 50.0, 10.0, 0.017, 120 * KM, 100 * KM) for _ in range(n_runs)]
    z, s, a, truth = (np.stack(x) for x in zip(*runs))
    F, Q = numpy_peer.cv_matrices(1.0, 50.0)
    common = dict(P0=np.diag([1e4, 1e2, 1e4, 1e2]), F=F, Q=Q, R=np.diag([10.0**2, 0.017**2]))
    return z, s, a, truth, common


def filterpy_local(z, s, x0, P0, F, Q, R):
    """filterpy's ``ExtendedKalmanFilter``, one object per agent, over one run (T, n, ·):
    predict from step 1 on, update when both components of z are finite (bearing residual
    wrapped). Returns ``(estimates (T, n, 4), covariances (T, n, 4, 4))``."""
    from filterpy.kalman import ExtendedKalmanFilter

    def hx(x, sensor):
        dx, dy = x[0, 0] - sensor[0], x[2, 0] - sensor[1]
        return np.array([[math.hypot(dx, dy)], [math.atan2(dy, dx)]])

    def jac(x, sensor):
        dx, dy = x[0, 0] - sensor[0], x[2, 0] - sensor[1]
        r2 = dx * dx + dy * dy
        r = math.sqrt(r2)
        return np.array([[dx / r, 0.0, dy / r, 0.0], [-dy / r2, 0.0, dx / r2, 0.0]])

    def residual(a, b):
        y = a - b
        y[1, 0] = (y[1, 0] + math.pi) % (2 * math.pi) - math.pi
        return y

    T, n = z.shape[:2]
    xs, Ps = np.empty((T, n, 4)), np.empty((T, n, 4, 4))
    for i in range(n):
        ekf = ExtendedKalmanFilter(dim_x=4, dim_z=2)
        ekf.x, ekf.P, ekf.F, ekf.Q, ekf.R = x0.reshape(4, 1).copy(), P0.copy(), F, Q, R
        for t in range(T):
            if t > 0:
                ekf.predict()
            if np.isfinite(z[t, i, 0]) and np.isfinite(z[t, i, 1]):
                ekf.update(z[t, i].reshape(2, 1), jac, hx, args=(s[t, i],), hx_args=(s[t, i],),
                           residual=residual)
            xs[t, i], Ps[t, i] = ekf.x[:, 0], ekf.P
    return xs, Ps


def max_relative_error(est, cov, ref_est, ref_cov):
    """Largest error relative to each component's scale: estimates by the largest |value| of
    the state component, covariances by ``sqrt(max P_ii) sqrt(max P_jj)``."""
    scale = np.abs(ref_est).reshape(-1, 4).max(axis=0)
    d = np.sqrt(np.abs(np.diagonal(ref_cov, axis1=-2, axis2=-1)).reshape(-1, 4).max(axis=0))
    return max(np.max(np.abs(est - ref_est) / scale), np.max(np.abs(cov - ref_cov) / np.outer(d, d)))
