"""mcjax.tracking.models (CV target, range–bearing radar, unicycle UAV) against independent references:
textbook matrices written out by hand, math.hypot/atan2, analytic Jacobians, finite
differences, sampling statistics and scipy.integrate.solve_ivp."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from mcjax.tracking.models.motion import cv_matrices, cv_process_noise, cv_step
from mcjax.tracking.models.platforms import UnicycleLimits, unicycle_step
from mcjax.tracking.models.sensors import measure_range_bearing, range_bearing

N_SAMPLES = 20000
DTS = [0.1, 1.0, 2.5]

# Everything is called through a few shared jitted entry points with fixed shapes: eager
# dispatch compiles each primitive separately and would dominate the run time.
_cv = jax.jit(lambda dt, sigma: (*cv_matrices(dt), cv_process_noise(dt, sigma)))
_cv_samples = jax.jit(jax.vmap(cv_step, in_axes=(None, 0, None, None)))

# --------------------------------------------------------------------------- CV target


def _textbook_fg(t):
    """Sun et al. 2011 eq. 1, written out independently."""
    f = np.array([[1, t, 0, 0], [0, 1, 0, 0], [0, 0, 1, t], [0, 0, 0, 1]], float)
    g = np.array([[t * t / 2, 0], [t, 0], [0, t * t / 2], [0, t]], float)
    return f, g


@pytest.mark.parametrize("dt", DTS)
def test_cv_matrices_textbook(dt):
    f, g, _ = _cv(dt, 1.0)
    f_ref, g_ref = _textbook_fg(dt)
    assert f.shape == (4, 4) and g.shape == (4, 2)
    np.testing.assert_allclose(f, f_ref, rtol=1e-15, atol=0)
    np.testing.assert_allclose(g, g_ref, rtol=1e-15, atol=0)


def test_cv_matrices_batched_dt():
    f, g, q = _cv(jnp.asarray(DTS), 2.0)
    assert q.shape == (3, 4, 4)
    assert f.shape == (3, 4, 4) and g.shape == (3, 4, 2)
    for k, dt in enumerate(DTS):
        f_ref, g_ref = _textbook_fg(dt)
        np.testing.assert_allclose(f[k], f_ref, rtol=1e-15)
        np.testing.assert_allclose(g[k], g_ref, rtol=1e-15)
        np.testing.assert_allclose(q[k], 4.0 * g_ref @ g_ref.T, rtol=1e-14)


@pytest.mark.parametrize("dt", DTS)
def test_cv_process_noise(dt):
    sigma = 50.0
    q = np.asarray(_cv(dt, sigma)[2])
    _, g = _textbook_fg(dt)
    np.testing.assert_allclose(q, g @ np.diag([sigma**2, sigma**2]) @ g.T, rtol=1e-14)
    block = sigma**2 * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])
    closed = np.zeros((4, 4))
    closed[:2, :2] = block
    closed[2:, 2:] = block
    np.testing.assert_allclose(q, closed, rtol=1e-14, atol=0)


def test_cv_step_noise_free_is_constant_velocity():
    x = jnp.array([200e3, 200.0, 180e3, -1000.0])
    keys = jax.random.split(jax.random.PRNGKey(0), N_SAMPLES)
    out = np.asarray(_cv_samples(x, keys, 2.0, 0.0))
    np.testing.assert_allclose(out, np.broadcast_to([200e3 + 400.0, 200.0, 180e3 - 2000.0, -1000.0],
                                                    out.shape), rtol=1e-15)


def test_cv_step_statistics():
    dt, sigma = 1.0, 50.0
    x0 = np.array([200e3, 200.0, 180e3, -1000.0])
    keys = jax.random.split(jax.random.PRNGKey(42), N_SAMPLES)
    xs = np.asarray(_cv_samples(jnp.asarray(x0), keys, dt, sigma))
    f, g = _textbook_fg(dt)
    q = g @ g.T * sigma**2
    r = xs - f @ x0  # = G w
    n = len(r)
    # mean: zero within 5 standard errors
    se_mean = np.sqrt(np.diag(q) / n)
    assert np.all(np.abs(r.mean(0)) < 5 * se_mean), (r.mean(0), se_mean)
    # covariance: each entry within 5 standard errors of Q (Gaussian: var(ŝ_ij) = (q_ii q_jj + q_ij²)/n)
    c = np.cov(r, rowvar=False)
    se_cov = np.sqrt((np.outer(np.diag(q), np.diag(q)) + q**2) / n)
    assert np.all(np.abs(c - q) < 5 * se_cov), (c, q)
    # diagonal within 5 % (well above the ≈1 % sampling error) — a wrong σ or a √ slip fails
    np.testing.assert_allclose(np.diag(c), np.diag(q), rtol=0.05)
    # the noise enters only through G: position noise = dt/2 × velocity noise, exactly
    np.testing.assert_allclose(r[:, 0], 0.5 * dt * r[:, 1], rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(r[:, 2], 0.5 * dt * r[:, 3], rtol=1e-9, atol=1e-6)
    # x and y accelerations independent
    assert abs(np.corrcoef(r[:, 1], r[:, 3])[0, 1]) < 5 / math.sqrt(n)


# --------------------------------------------------------------------------- range–bearing

QUADRANT_OFFSETS = [(3.0, 4.0), (-3.0, 4.0), (-3.0, -4.0), (3.0, -4.0),
                    (7.0, 0.0), (0.0, 7.0), (-7.0, 0.0), (0.0, -7.0), (1e5, -2.5e4)]
SENSOR = np.array([1500.0, -2000.0])
_rb = jax.jit(range_bearing)  # used with x (9, 4) and sensor (2,) or (9, 2) only
_jac = jax.jit(jax.jacfwd(range_bearing, argnums=(0, 1)))


def test_range_bearing_all_quadrants():
    xs = np.array([[SENSOR[0] + dx, 11.0, SENSOR[1] + dy, -3.0] for dx, dy in QUADRANT_OFFSETS])
    got = np.asarray(_rb(jnp.asarray(xs), jnp.asarray(SENSOR)))
    assert got.shape == (len(xs), 2)
    for k in range(len(xs)):
        x, y = xs[k, 0] - SENSOR[0], xs[k, 2] - SENSOR[1]
        assert math.isclose(got[k, 0], math.hypot(x, y), rel_tol=1e-14)
        assert math.isclose(got[k, 1], math.atan2(y, x), rel_tol=1e-12, abs_tol=1e-15)
    # explicit quadrant signs: bearings in (0, π/2), (π/2, π), (−π, −π/2), (−π/2, 0)
    b = got[:4, 1]
    assert 0 < b[0] < np.pi / 2 and np.pi / 2 < b[1] < np.pi
    assert -np.pi < b[2] < -np.pi / 2 and -np.pi / 2 < b[3] < 0
    assert got[6, 1] == pytest.approx(np.pi)  # target straight to −x: bearing π
    assert got[7, 1] == pytest.approx(-np.pi / 2)


def test_range_bearing_batched_sensors():
    rng = np.random.default_rng(0)
    xs = rng.normal(size=(9, 4)) * 1e3
    ss = rng.normal(size=(9, 2)) * 1e3
    got = np.asarray(_rb(jnp.asarray(xs), jnp.asarray(ss)))
    for k in range(9):
        dx, dy = xs[k, 0] - ss[k, 0], xs[k, 2] - ss[k, 1]
        np.testing.assert_allclose(got[k], [math.hypot(dx, dy), math.atan2(dy, dx)], rtol=1e-13)


def _analytic_jacobian(x, s):
    """∂h/∂[x, ẋ, y, ẏ]: range row [dx/r, 0, dy/r, 0], bearing row [−dy/r², 0, dx/r², 0]."""
    dx, dy = x[0] - s[0], x[2] - s[1]
    r2 = dx * dx + dy * dy
    r = math.sqrt(r2)
    return np.array([[dx / r, 0.0, dy / r, 0.0], [-dy / r2, 0.0, dx / r2, 0.0]])


def _central_fd(x, h):
    """Central differences of the code's range_bearing (one batched call: ±h on each of 4 axes)."""
    pts = np.repeat(x[None], 9, 0)
    for j in range(4):
        pts[2 * j, j] += h
        pts[2 * j + 1, j] -= h
    z = np.asarray(_rb(jnp.asarray(pts), jnp.asarray(SENSOR)))
    d = z[0:8:2] - z[1:8:2]
    d[:, 1] = np.angle(np.exp(1j * d[:, 1]))  # bearing differences across the ±π seam
    return (d / (2 * h)).T


@pytest.mark.parametrize("dx, dy", QUADRANT_OFFSETS[:4] + [(-5e4, 1e3), (-5e4, -1e3), (2e4, 0.0)])
def test_range_bearing_jacobian(dx, dy):
    x = np.array([SENSOR[0] + dx, 13.0, SENSOR[1] + dy, -4.0])
    jx, js = (np.asarray(j) for j in _jac(jnp.asarray(x), jnp.asarray(SENSOR)))
    ref = _analytic_jacobian(x, SENSOR)
    r = math.hypot(dx, dy)
    np.testing.assert_allclose(jx, ref, rtol=1e-12, atol=1e-15 / r)
    fd = _central_fd(x, 1e-4 * r)
    np.testing.assert_allclose(jx, fd, rtol=1e-6, atol=1e-9 / r)
    # w.r.t. the sensor position: the negated position columns
    np.testing.assert_allclose(js, -ref[:, [0, 2]], rtol=1e-12, atol=1e-15 / r)


ON_SENSOR_X = jnp.array([10.0, 1.0, -20.0, 2.0])
ON_SENSOR_S = jnp.array([10.0, -20.0])


def test_range_bearing_jacobian_finite_on_sensor():
    jx, js = (np.asarray(j) for j in _jac(ON_SENSOR_X, ON_SENSOR_S))
    assert np.all(np.isfinite(jx)) and np.all(np.isfinite(js)), (jx, js)


def test_range_bearing_value_and_range_row_finite_on_sensor():
    z = np.asarray(_rb(jnp.broadcast_to(ON_SENSOR_X, (9, 4)), ON_SENSOR_S))
    assert np.all(z[:, 0] == 0.0) and np.all(np.isfinite(z[:, 1]))
    jx, js = (np.asarray(j) for j in _jac(ON_SENSOR_X, ON_SENSOR_S))
    assert np.all(np.isfinite(jx[0])) and np.all(np.isfinite(js[0]))  # safe_norm: range row finite


# --------------------------------------------------------------------------- measurements

_meas = jax.jit(jax.vmap(measure_range_bearing, in_axes=(0, 0, 0, None, None, 0, 0)))


def _measure(key, xs, sensors, sigma_r, sigma_b, max_range, valid):
    m = len(xs)
    keys = jax.random.split(key, m)
    return np.asarray(_meas(keys, jnp.asarray(xs, float), jnp.asarray(sensors, float), sigma_r, sigma_b,
                            jnp.broadcast_to(jnp.asarray(max_range, float), (m,)),
                            jnp.broadcast_to(jnp.asarray(valid), (m,))))


def test_measure_gating_and_validity():
    # six cases, cycled over N_SAMPLES rows (one shared compilation with the statistics tests)
    x = np.array([3000.0, 0.0, 4000.0, 0.0])  # range exactly 5000 from the origin
    radius = np.resize([5000.0 + 1e-6, 5000.0 - 1e-6, 100.0, 1e9, 1e9, 5000.0 + 1e-6], N_SAMPLES)
    valid = np.resize([True, True, True, False, True, False], N_SAMPLES)
    case = np.resize(np.arange(6), N_SAMPLES)
    z = _measure(jax.random.PRNGKey(1), np.tile(x, (N_SAMPLES, 1)), np.zeros((N_SAMPLES, 2)),
                 10.0, 0.017, radius, valid)
    assert z.shape == (N_SAMPLES, 2)
    ok = np.isin(case, [0, 4])  # in range and valid: finite, close to the clean value
    assert np.all(np.isfinite(z[ok]))
    assert np.all(np.abs(z[ok, 0] - 5000.0) < 6 * 10.0)
    assert np.all(np.abs(z[ok, 1] - math.atan2(4, 3)) < 6 * 0.017)
    assert np.all(np.isnan(z[np.isin(case, [1, 2])]))  # beyond the sensing radius
    assert np.all(np.isnan(z[np.isin(case, [3, 5])]))  # not valid (agent not alive)


def _sample_measurements(x, sensor, sigma_r, sigma_b):
    return _measure(jax.random.PRNGKey(7), np.tile(x, (N_SAMPLES, 1)), np.tile(sensor, (N_SAMPLES, 1)),
                    sigma_r, sigma_b, 1e9, True)


def test_measure_noise_statistics():
    sensor = np.array([100.0, -50.0])
    x = np.array([100.0 + 30e3, 0.0, -50.0 + 40e3, 0.0])
    sigma_r, sigma_b = 10.0, 0.017
    z = _sample_measurements(x, sensor, sigma_r, sigma_b)
    assert np.all(np.isfinite(z))
    er = z[:, 0] - 50e3
    eb = z[:, 1] - math.atan2(40e3, 30e3)
    n = len(z)
    assert abs(er.mean()) < 5 * sigma_r / math.sqrt(n)
    assert abs(eb.mean()) < 5 * sigma_b / math.sqrt(n)
    # std within 5 standard errors (≈ σ/√(2n)) — and well away from e.g. σ² or 2σ
    assert abs(er.std() - sigma_r) < 5 * sigma_r / math.sqrt(2 * n)
    assert abs(eb.std() - sigma_b) < 5 * sigma_b / math.sqrt(2 * n)
    assert abs(np.corrcoef(er, eb)[0, 1]) < 5 / math.sqrt(n)
    assert len(np.unique(er)) == n  # every key gives its own draw


def test_measure_bearing_wrapped_at_seam():
    """A target at bearing ≈ π: noisy bearings cross the seam and must be wrapped."""
    sensor = np.array([0.0, 0.0])
    true_b = math.pi - 0.01
    x = np.array([1e4 * math.cos(true_b), 0.0, 1e4 * math.sin(true_b), 0.0])
    sigma_b = 0.1
    z = _sample_measurements(x, sensor, 5.0, sigma_b)
    b = z[:, 1]
    assert np.all(b > -np.pi) and np.all(b <= np.pi)
    assert np.mean(b < 0) > 0.2  # a good fraction crossed to the −π side (≈ 46 %)
    err = np.angle(np.exp(1j * (b - true_b)))
    assert abs(err.mean()) < 5 * sigma_b / math.sqrt(len(b))
    assert abs(err.std() - sigma_b) < 5 * sigma_b / math.sqrt(2 * len(b))


# --------------------------------------------------------------------------- unicycle UAV

DEG = math.pi / 180.0
N_STEPS = 200
BATCH = 64  # every simulation below is padded to this batch: one compilation for all of them


def _limits(v_min=100.0, v_max=300.0, a_min=-5.0, a_max=5.0, turn=10 * DEG):
    return UnicycleLimits(*(jnp.asarray(v, float) for v in (v_min, v_max, a_min, a_max, turn)))


@jax.jit
def _simulate(state, heading_cmd, accel_cmd, alpha, limits, dt):
    def body(s, _):
        s = unicycle_step(s, heading_cmd, accel_cmd, alpha, limits, dt)
        return s, s

    return jax.lax.scan(body, state, None, length=N_STEPS)[1]


def _run(states, cmds, accels, alpha, limits, dt):
    """N_STEPS steps of unicycle_step for m ≤ BATCH UAVs; returns the trajectory (N_STEPS, m, 4)
    (row 0 is the state after ONE step)."""
    states = np.atleast_2d(np.asarray(states, float))
    m = len(states)
    pad = lambda a, shape: np.resize(np.broadcast_to(np.asarray(a, float), shape), (BATCH,) + shape[1:])
    traj = _simulate(jnp.asarray(pad(states, (m, 4))), jnp.asarray(pad(cmds, (m,))),
                     jnp.asarray(pad(accels, (m,))), float(alpha), limits, float(dt))
    return np.asarray(traj)[:, :m]


def test_straight_flight_exact():
    phis = np.array([0.0, 0.3, -2.0, math.pi, 1.5, -0.7])
    v, dt = 250.0, 1.7
    state = np.stack([np.full(6, 1e3), np.full(6, -2e3), np.full(6, v), phis], -1)
    out = _run(state, phis, 0.0, 1.0, _limits(), dt)[0]
    np.testing.assert_allclose(out[:, 0], 1e3 + v * dt * np.cos(phis), rtol=1e-14, atol=1e-10)
    np.testing.assert_allclose(out[:, 1], -2e3 + v * dt * np.sin(phis), rtol=1e-14, atol=1e-10)
    np.testing.assert_allclose(out[:, 2], v, rtol=1e-15)
    np.testing.assert_allclose(out[:, 3], phis, rtol=0, atol=1e-15)
    # constant acceleration in a straight line: the path is quadratic in t, integrated exactly
    a = 2.0
    out = _run(state, phis, a, 1.0, _limits(), dt)[0]
    s = v * dt + 0.5 * a * dt * dt
    np.testing.assert_allclose(out[:, 0], 1e3 + s * np.cos(phis), rtol=1e-13, atol=1e-9)
    np.testing.assert_allclose(out[:, 1], -2e3 + s * np.sin(phis), rtol=1e-13, atol=1e-9)
    np.testing.assert_allclose(out[:, 2], v + a * dt, rtol=1e-14)


def _heading_steps(phi0, traj):
    phi = np.concatenate([np.asarray(phi0)[None], traj[:, :, 3]])
    return np.angle(np.exp(1j * np.diff(phi, axis=0)))  # per-step heading change, on the circle


@pytest.mark.parametrize("alpha, dt", [(0.5, 1.0), (2.0, 1.0), (5.0, 0.5), (50.0, 0.1)])
def test_turn_rate_never_exceeds_limit(alpha, dt):
    rng = np.random.default_rng(3)
    phi = rng.uniform(-np.pi, np.pi, BATCH)
    cmd = rng.uniform(-np.pi, np.pi, BATCH)
    state = np.stack([np.zeros(BATCH), np.zeros(BATCH), np.full(BATCH, 200.0), phi], -1)
    dphi = _heading_steps(phi, _run(state, cmd, 0.0, alpha, _limits(turn=10 * DEG), dt))
    assert np.max(np.abs(dphi)) <= 10 * DEG * dt * (1 + 1e-12), np.max(np.abs(dphi))
    # and the limit is actually reached when far from the command (the clip is active)
    assert np.max(np.abs(dphi)) > 0.99 * 10 * DEG * dt


def test_shortest_turn_and_convergence():
    alpha, dt = 20.0, 0.1  # a "large" gain (α·dt = 2; see also the α·dt > 2.8 test below)
    cases = [(170.0, -170.0, +1), (-170.0, 170.0, -1), (10.0, -10.0, -1), (-135.0, 135.0, -1),
             (90.0, -91.0, +1), (0.0, 179.0, +1)]
    start = np.array([c[0] for c in cases]) * DEG
    cmd = np.array([c[1] for c in cases]) * DEG
    sign = np.array([c[2] for c in cases])
    state = np.stack([np.zeros(6), np.zeros(6), np.full(6, 200.0), start], -1)
    traj = _run(state, cmd, 0.0, alpha, _limits(), dt)
    expected = np.array([math.remainder(c - s, 2 * math.pi) for s, c in zip(start, cmd)])
    assert np.all(np.sign(expected) == sign)  # the case table is right: shortest signed turn
    dphi = _heading_steps(start, traj)
    assert np.all(sign * dphi >= -1e-10), "turned the wrong way at some step"
    np.testing.assert_allclose(np.sum(dphi, 0), expected, atol=1e-9)  # total turn = shortest turn
    np.testing.assert_allclose(np.angle(np.exp(1j * (traj[-1, :, 3] - cmd))), 0.0, atol=1e-9)
    # 170° → −170° passes through 180°: the unwrapped heading goes beyond π
    assert np.max(start[0] + np.cumsum(dphi[:, 0])) > np.pi
    assert np.all(traj[:, :, 3] > -np.pi) and np.all(traj[:, :, 3] <= np.pi)  # stored heading wrapped


def test_heading_command_reached_steady_state():
    # the configured autopilot (configs/sun2011.toml: α_φ = 1/s, 10°/s, 1 s steps)
    cmd = np.array([60.0, -120.0, 179.0]) * DEG
    start = np.array([-30.0, 100.0, -179.0]) * DEG
    state = np.stack([np.zeros(3), np.zeros(3), np.full(3, 800.0), start], -1)
    traj = _run(state, cmd, 0.0, 1.0, _limits(800.0, 800.0, 0.0, 0.0), 1.0)
    np.testing.assert_allclose(np.angle(np.exp(1j * (traj[-1, :, 3] - cmd))), 0.0, atol=1e-9)
    # once there, it flies straight along the command
    step = traj[-1, :, :2] - traj[-2, :, :2]
    np.testing.assert_allclose(step, 800.0 * np.stack([np.cos(cmd), np.sin(cmd)], -1), rtol=1e-9, atol=1e-6)


@pytest.mark.parametrize("alpha", [3.0, 5.0, 50.0])
def test_heading_command_reached_large_gain_unit_step(alpha):
    state = np.array([[0.0, 0.0, 200.0, 0.05]])
    traj = _run(state, 0.0, 0.0, alpha, _limits(), 1.0)
    assert abs(traj[-1, 0, 3]) < 1e-6, traj[-1, 0, 3]


def test_dt_zero_changes_nothing():
    rng = np.random.default_rng(5)
    m = 16
    state = np.stack([rng.normal(size=m) * 1e3, rng.normal(size=m) * 1e3, rng.uniform(100, 300, m),
                      rng.uniform(-np.pi, np.pi, m)], -1)
    out = _run(state, rng.uniform(-3, 3, m), rng.uniform(-9, 9, m), 3.0, _limits(), 0.0)
    np.testing.assert_array_equal(out[0], state)
    np.testing.assert_array_equal(out[-1], state)


def test_speed_stays_within_limits():
    lim = _limits(v_min=100.0, v_max=300.0, a_min=-5.0, a_max=5.0)
    v0 = np.array([150.0, 290.0, 120.0])
    state = np.stack([np.zeros(3), np.zeros(3), v0, np.array([0.0, 1.0, -1.0])], -1)
    for accel, target in [(100.0, 300.0), (-100.0, 100.0), (3.0, 300.0), (-3.0, 100.0)]:
        traj = _run(state, [0.5, -0.5, 2.0], accel, 1.0, lim, 0.7)
        v = np.concatenate([v0[None], traj[:, :, 2]])
        assert np.all(v >= 100.0) and np.all(v <= 300.0)
        np.testing.assert_allclose(v[-1], target)  # the limit is reached and held
        # the acceleration itself is clipped to [a_min, a_max]
        dv = np.diff(v, axis=0)
        assert np.all(np.abs(dv) <= min(abs(accel), 5.0) * 0.7 * (1 + 1e-12))
        assert np.all(np.sign(accel) * dv >= 0)


@pytest.mark.parametrize("dt", [0.1, 0.05])
def test_step_matches_solve_ivp(dt):
    """No limit active: one step equals the ODE solution (Sun et al. 2011 eq. 3) to ~1e-6."""
    alpha, accel, cmd = 0.5, 1.0, 0.15
    s0 = np.array([1e3, -500.0, 200.0, 0.1])
    lim = _limits(v_min=50.0, v_max=400.0, a_min=-5.0, a_max=5.0, turn=1.0)
    assert alpha * abs(cmd - s0[3]) < 1.0 and 50.0 < s0[2] + accel * dt < 400.0

    def rhs(_, s):
        return [s[2] * math.cos(s[3]), s[2] * math.sin(s[3]), accel, alpha * (cmd - s[3])]

    sol = solve_ivp(rhs, (0.0, dt), s0, method="DOP853", rtol=1e-12, atol=1e-12)
    assert sol.success
    ref = sol.y[:, -1]
    out = _run(s0, cmd, accel, alpha, lim, dt)[0, 0]
    np.testing.assert_allclose(out - s0, ref - s0, rtol=1e-6, atol=0)
    # the heading increment also matches the first-order closed form (φc − φ0)(1 − e^{−α dt})
    np.testing.assert_allclose(out[3] - s0[3], (cmd - s0[3]) * (1 - math.exp(-alpha * dt)), rtol=1e-6)


def _clipped_rhs(alpha, cmd, accel, turn):
    """Sun et al. 2011 eq. 3 with the eq. 4 turn-rate limit and the shortest-turn heading error."""

    def rhs(_, s):
        rate = min(max(alpha * math.remainder(cmd - s[3], 2 * math.pi), -turn), turn)
        return [s[2] * math.cos(s[3]), s[2] * math.sin(s[3]), accel, rate]

    return rhs


@pytest.mark.parametrize("alpha, dt, phi0, cmd, accel", [
    (1.0, 1.0, 0.0, 1.0, 0.0),      # turn-rate limit active over the whole step
    (1.0, 1.0, 0.0, 0.2, 2.0),      # limit active, then the exponential approach, in one step
    (5.0, 1.0, 3.0, -3.0, 0.0),     # large gain, shortest turn across the ±π seam
    (50.0, 2.0, -0.3, 0.1, -1.0),   # very large gain: saturated, then practically on the command
])
def test_step_matches_solve_ivp_with_turn_limit(alpha, dt, phi0, cmd, accel):
    turn = 10 * DEG
    s0 = np.array([1e3, -500.0, 200.0, phi0])
    sol = solve_ivp(_clipped_rhs(alpha, cmd, accel, turn), (0.0, dt), s0, method="DOP853",
                    rtol=1e-12, atol=1e-12, max_step=dt / 400)
    assert sol.success
    ref = sol.y[:, -1]
    out = _run(s0, cmd, accel, alpha, _limits(v_min=50.0, v_max=400.0, turn=turn), dt)[0, 0]
    np.testing.assert_allclose(np.angle(np.exp(1j * (out[3] - ref[3]))), 0.0, atol=1e-8)
    np.testing.assert_allclose(out[2], ref[2], rtol=1e-12)
    # position: within 1e-4 of the distance flown (the heading rate has a kink inside the step)
    np.testing.assert_allclose(out[:2], ref[:2], rtol=0, atol=1e-4 * 200.0 * dt)


def test_speed_limit_reached_inside_the_step():
    """Straight flight accelerating into v_max mid-step: distance = ∫ min(v0 + a t, v_max) dt."""
    v0, a, v_max = np.array([395.0, 398.0, 300.0]), 5.0, 400.0
    dt = 2.0
    state = np.stack([np.zeros(3), np.zeros(3), v0, np.zeros(3)], -1)
    out = _run(state, 0.0, a, 1.0, _limits(v_min=50.0, v_max=v_max), dt)[0]
    t1 = np.minimum((v_max - v0) / a, dt)
    dist = v0 * t1 + 0.5 * a * t1**2 + v_max * (dt - t1)
    np.testing.assert_allclose(out[:, 2], np.minimum(v0 + a * dt, v_max), rtol=1e-14)
    np.testing.assert_allclose(out[:, 0], dist, rtol=1e-4)
    np.testing.assert_allclose(out[:, 1], 0.0, atol=1e-9)


def _step_jacobian(state, cmd, alpha, limits, dt):
    """jacfwd-equivalent of one step w.r.t. [state, heading_cmd] (4 × 5), as a jit(vmap(jvp))
    around a fixed point (the cheapest form to compile)."""

    def tangent(ds, dc):
        return jax.jvp(lambda s, c: unicycle_step(s, c, 0.0, alpha, limits, dt),
                       (jnp.asarray(state), jnp.asarray(cmd)), (ds, dc))[1]

    eye = jnp.eye(5)
    return np.asarray(jax.jit(jax.vmap(tangent))(eye[:, :4], eye[:, 4])).T


def _step_fd(state, cmd, alpha, limits, dt):
    """Central differences of one step w.r.t. the state (4 columns) and the heading command,
    evaluated as one batch of 10 perturbed UAVs."""
    h = np.array([1e-3, 1e-3, 1e-3, 1e-6, 1e-6])
    states, cmds = np.tile(state, (10, 1)), np.full(10, cmd)
    for j in range(5):
        for sgn, row in ((1.0, 2 * j), (-1.0, 2 * j + 1)):
            if j < 4:
                states[row, j] += sgn * h[j]
            else:
                cmds[row] += sgn * h[j]
    out = _run(states, cmds, 0.0, alpha, limits, dt)[0]
    return ((out[0::2] - out[1::2]) / (2 * h[:, None])).T


@pytest.mark.parametrize("err", [0.05, 0.0])
def test_step_gradient_matches_finite_differences(err):
    """Gradient-based planning differentiates the step w.r.t. the heading command: jacfwd must
    match central differences and, for the heading, the closed form of the linear regime."""
    alpha, dt, cmd = 1.0, 1.0, 0.4
    lim = _limits(v_min=100.0, v_max=1000.0)
    state = np.array([1e3, 2e3, 800.0, cmd - err])
    jac = _step_jacobian(state, cmd, alpha, lim, dt)
    assert jac.shape == (4, 5)
    fd = _step_fd(state, cmd, alpha, lim, dt)
    decay = math.exp(-alpha * dt)
    np.testing.assert_allclose(jac[3, 3], decay, rtol=1e-9)       # ∂φ'/∂φ
    np.testing.assert_allclose(jac[3, 4], 1.0 - decay, rtol=1e-9)  # ∂φ'/∂φᶜ
    np.testing.assert_allclose(jac, fd, rtol=1e-6, atol=1e-5)


def test_zero_turn_rate_limit_is_finite():
    """A platform that cannot turn (turn_rate_max = 0) flies straight, whatever the command."""
    state = np.array([[0.0, 0.0, 200.0, 0.3], [0.0, 0.0, 200.0, 0.3]])
    out = _run(state, [0.3, 1.0], 0.0, 1.0, _limits(turn=0.0), 1.0)[0]
    np.testing.assert_allclose(out[:, 3], 0.3, rtol=1e-15)
    np.testing.assert_allclose(out[:, :2], np.tile([200.0 * math.cos(0.3), 200.0 * math.sin(0.3)], (2, 1)),
                               rtol=1e-12)


def test_ct_matrix_turns_velocity_and_tends_to_cv():
    from mcjax.tracking.models.motion import ct_matrix, cv_matrices

    x = np.array([100.0, 5.0, -50.0, 2.0])
    for omega in (0.1, -0.05, 0.3):
        F = np.asarray(ct_matrix(2.0, omega, jnp.float64))
        y = F @ x
        # speed kept, velocity rotated by ωT
        np.testing.assert_allclose(np.hypot(y[1], y[3]), np.hypot(x[1], x[3]), rtol=1e-12)
        ang = np.arctan2(y[3], y[1]) - np.arctan2(x[3], x[1])
        np.testing.assert_allclose(np.angle(np.exp(1j * ang)), omega * 2.0, atol=1e-12)
        # the position moves along the arc: chord = 2 v sin(ωT/2)/ω
        chord = np.hypot(y[0] - x[0], y[2] - x[2])
        np.testing.assert_allclose(chord, 2 * np.hypot(x[1], x[3]) * abs(np.sin(omega) / omega), rtol=1e-12)
    F_cv, _ = cv_matrices(2.0, jnp.float64)
    np.testing.assert_allclose(np.asarray(ct_matrix(2.0, 1e-9, jnp.float64)), np.asarray(F_cv), atol=1e-8)
    # continuous across the Taylor-branch switch at |ωT| = 1e-4
    np.testing.assert_allclose(np.asarray(ct_matrix(2.0, 0.4999999e-4, jnp.float64)),
                               np.asarray(ct_matrix(2.0, 0.5000001e-4, jnp.float64)), atol=1e-10)
    g = jax.grad(lambda w: jnp.sum(ct_matrix(2.0, w, jnp.float64) @ jnp.asarray(x)))(0.0)
    assert np.isfinite(float(g))


def test_markov_modes_follow_the_transition_matrix():
    from mcjax.tracking.models.motion import markov_modes

    P = np.array([[0.9, 0.1], [0.3, 0.7]])
    m = np.asarray(markov_modes(jax.random.PRNGKey(0), P, 0, 20000))
    assert m[0] == 0
    counts = np.zeros((2, 2))
    np.add.at(counts, (m[:-1], m[1:]), 1)
    est = counts / counts.sum(1, keepdims=True)
    np.testing.assert_allclose(est, P, atol=0.02)
