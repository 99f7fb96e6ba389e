"""Chen & Hao 2022 (urban_bearing) against independent references: filterpy's IMM-EKF, the
closed-form det FIM of bearings, a brute-force numpy grid planner written from eqs. 1 and
13–20, and the closed loop's invariants recomputed in numpy / shapely."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely
from click.testing import CliRunner
from filterpy.kalman import ExtendedKalmanFilter, IMMEstimator

from mcjax import engine
from mcjax.cli import main
from mcjax.contract import FAST_COMPILE
from mcjax.scenarios import chen2022 as S
from mcjax.scenarios import kit
from mcjax.scenarios.chen2022 import environment as env
from mcjax.scenarios.chen2022 import score as urban
from mcjax.tracking.filters.imm import IMMState, imm_step
from mcjax.tracking.models.platforms import braking_climb, fixed_wing_step

DEG = np.pi / 180.0
CONFIG = str((Path(__file__).parents[3] / "configs" / "chen2022.toml").resolve())
WEIGHTS = [(0.2, 0.5, -0.3), (0.2, 0.0, 0.0)]
#: The first building layout (configs/chen2022_wide_prior.toml), [x_lo, y_lo, x_hi, y_hi, height]: the
#: planner and closed-loop states below are placed by hand around its tall building.
BOXES = np.array([[4750.0, 5050.0, 4850.0, 5150.0, 200.0], [5100.0, 4800.0, 5250.0, 4900.0, 100.0]])


def jit(fun, **kw):
    """``jax.jit`` with the scenarios' XLA options (:data:`mcjax.contract.FAST_COMPILE`: XLA's older
    CPU fusion code generator, which compiles with much less CPU time; the engine compiles the
    scenarios' programs so). What these tests check does not depend on the code generator."""
    return jax.jit(fun, compiler_options=dict(FAST_COMPILE), **kw)


def wrap(a):
    """To (−π, π]."""
    return np.pi - np.mod(np.pi - np.asarray(a, float), 2 * np.pi)


def np_inside(p):
    """Closed box membership of points (..., 3) in any default building (eq. 3), numpy."""
    q = np.asarray(p)[..., None, :]
    lo = np.concatenate([BOXES[:, 0:2], np.zeros((len(BOXES), 1))], 1)
    hi = np.concatenate([BOXES[:, 2:4], BOXES[:, 4:5]], 1)
    return np.any(np.all((q >= lo) & (q <= hi), -1), -1)


def eq1(s, theta, omega, v, dt):
    """Chen & Hao 2022 eq. 1, one step, numpy."""
    x, y, z, psi = s
    return np.array([x + v * dt * np.cos(psi) * np.cos(theta), y + v * dt * np.sin(psi) * np.cos(theta),
                     z + v * dt * np.sin(theta), psi + dt * omega])


def np_h(target, uav):
    """The azimuth's Jacobian of eq. 15 w.r.t. the target, numpy."""
    dx, dy = target[0] - uav[0], target[1] - uav[1]
    g2 = dx * dx + dy * dy
    return np.array([-dy / g2, dx / g2])


# --------------------------------------------------------------------------- 1. IMM-EKF vs filterpy


class BiasedAzimuthEKF(ExtendedKalmanFilter):
    """filterpy's EKF on a static 2-D target, measuring the azimuth from ``self.uav`` biased by
    ``bias`` (eqs. 2, 11–12), hand-written Jacobian, innovation wrapped to (−π, π]. A missing
    measurement (None) leaves the predicted state and gives every mode the same likelihood."""

    def __init__(self, bias, sigma, q, x0, P0):
        super().__init__(dim_x=2, dim_z=1)
        self.bias = bias
        self.x, self.P = x0.copy(), P0.copy()
        self.F, self.Q, self.R = np.eye(2), q * q * np.eye(2), np.array([[sigma * sigma]])
        self.uav = None

    def hx(self, x):
        return np.array([np.arctan2(x[1] - self.uav[1], x[0] - self.uav[0]) + self.bias])

    def jacobian(self, x):
        return np_h(x, self.uav)[None, :]

    def update(self, z):
        if z is None:
            super().update(None, self.jacobian, self.hx)
            self._log_likelihood, self._likelihood = 0.0, 1.0  # equal for every mode: mu = cbar
            return
        super().update(z, self.jacobian, self.hx, residual=lambda a, b: wrap(a - b))


_imm_jit = jit(lambda st, tr, bias, sigma, z, uav, q: imm_step(st, tr, S.mode_filter, (bias, sigma), z, uav, q))


@pytest.mark.parametrize("transition", [
    [[0.9, 0.05, 0.05], [0.05, 0.9, 0.05], [0.05, 0.05, 0.9]],
    [[0.85, 0.1, 0.05], [0.2, 0.7, 0.1], [0.3, 0.1, 0.6]],     # not symmetric: catches P(j|l) vs P(l|j)
], ids=["paper", "asymmetric"])
def test_imm_ekf_matches_filterpy(transition):
    """30 steps of the 3-mode IMM-EKF (LOS, NLOS+, NLOS−) from a moving UAV whose bearings
    to the target cross ±π, with NLOS-biased and missing measurements: μ, combined x and P
    equal filterpy's IMMEstimator of biased EKFs (predict = mix + F = I, Q = q² I; update)."""
    M = np.asarray(transition)
    bias = np.array([0.0, 20 * DEG, -20 * DEG])
    sigma = np.array([0.2 * DEG, 1.0 * DEG, 1.0 * DEG])
    q, mu0 = 1.5, np.array([0.8, 0.1, 0.1])
    target = np.array([4000.0, 4000.0])
    x0, P0 = target + np.array([400.0, -300.0]), 500.0**2 * np.eye(2)
    n = 30
    uavs = np.stack([np.full(n, 6500.0), np.linspace(2800.0, 5200.0, n), np.full(n, 200.0), np.zeros(n)], 1)
    mode = np.zeros(n, int)
    mode[[6, 7, 8, 22]] = 1
    mode[[13, 14, 25]] = 2
    missing = np.zeros(n, bool)
    missing[[3, 4, 11, 19, 27]] = True
    rng = np.random.default_rng(7)
    truth = np.arctan2(target[1] - uavs[:, 1], target[0] - uavs[:, 0])
    zs = wrap(truth + bias[mode] + sigma[mode] * rng.standard_normal(n))
    assert np.any(zs > 3.0) and np.any(zs < -3.0)  # the bearings do cross ±π

    filters = [BiasedAzimuthEKF(b, s, q, x0, P0) for b, s in zip(bias, sigma)]
    ref = IMMEstimator(filters, mu0, M)
    state = IMMState(jnp.asarray(mu0), jnp.broadcast_to(jnp.asarray(x0), (3, 2)), jnp.broadcast_to(jnp.asarray(P0), (3, 2, 2)))
    errs = dict(mu=0.0, x=0.0, P=0.0)
    xs, mus, prev_mu = [], [], mu0
    for t in range(n):
        for f in filters:
            f.uav = uavs[t]
        ref.predict(0)  # mix, then each EKF predicts (F = I, Q); u = 0: the EKF has no control input
        ref.update(None if missing[t] else zs[t])
        z = np.nan if missing[t] else zs[t]
        state, (x, P) = _imm_jit(state, jnp.asarray(M), jnp.asarray(bias), jnp.asarray(sigma), jnp.asarray(z),
                                 jnp.asarray(uavs[t]), jnp.asarray(q))
        errs["mu"] = max(errs["mu"], np.max(np.abs(np.asarray(state.mu) - ref.mu)))
        errs["x"] = max(errs["x"], np.max(np.abs(np.asarray(x) - ref.x)) / np.linalg.norm(ref.x))
        errs["P"] = max(errs["P"], np.max(np.abs(np.asarray(P) - ref.P)) / np.max(np.abs(ref.P)))
        if missing[t]:  # no measurement: μ is the predicted c̄ = μ_prev @ M
            np.testing.assert_allclose(np.asarray(state.mu), prev_mu @ M, atol=1e-12)
        prev_mu = np.asarray(state.mu)
        xs.append(ref.x.copy())
        mus.append(ref.mu.copy())
    assert errs["mu"] < 1e-8 and errs["x"] < 1e-8 and errs["P"] < 1e-8, errs
    # the comparison has teeth: the estimate moves by far more than the tolerance, and every
    # measured step's most probable mode is the one that drew the measurement
    assert np.ptp(np.asarray(xs)[:, 0]) > 50.0
    measured = ~missing
    np.testing.assert_array_equal(np.argmax(np.asarray(mus), 1)[measured], mode[measured])


# --------------------------------------------------------------------------- 2. FIM


def test_accumulated_fim_det_has_the_closed_form():
    """Σ_k H_kᵀH_k/σ² over K bearings (eqs. 13–15, Φ = I, FIM_0 = 0) has the Cauchy–Binet
    determinant σ⁻⁴ Σ_{k<l} sin²(β_k − β_l)/(g_k² g_l²); one increment is the numpy HᵀH/σ²."""
    rng = np.random.default_rng(3)
    target = np.array([1200.0, -300.0])
    uavs = np.concatenate([rng.uniform(-3000, 3000, (9, 2)), rng.uniform(50, 400, (9, 1))], 1)
    sigma = 0.7 * DEG
    info = jit(urban.bearing_information)
    fim = np.zeros((2, 2))
    for u in uavs:
        fim = fim + np.asarray(info(jnp.asarray(target), jnp.asarray(u), sigma))
    d = target - uavs[:, :2]
    beta, g = np.arctan2(d[:, 1], d[:, 0]), np.hypot(d[:, 0], d[:, 1])
    closed = sum(np.sin(beta[k] - beta[m]) ** 2 / (g[k] ** 2 * g[m] ** 2)
                 for k in range(len(uavs)) for m in range(k + 1, len(uavs))) / sigma**4
    np.testing.assert_allclose(urban.det2(jnp.asarray(fim)), closed, rtol=1e-10)
    np.testing.assert_allclose(np.linalg.det(fim), closed, rtol=1e-10)
    # one increment against eq. 15 in numpy
    h = np_h(target, uavs[0])
    np.testing.assert_allclose(np.asarray(info(jnp.asarray(target), jnp.asarray(uavs[0]), sigma)),
                               np.outer(h, h) / sigma**2, rtol=1e-12)
    # batched: several targets and noises at once
    tg = rng.uniform(-2000, 2000, (4, 2))
    sg = np.array([0.2, 1.0, 1.0, 3.0]) * DEG
    batch = np.asarray(urban.bearing_information(jnp.asarray(tg), jnp.asarray(uavs[:4]), jnp.asarray(sg)))
    for i in range(4):
        h = np_h(tg[i], uavs[i])
        np.testing.assert_allclose(batch[i], np.outer(h, h) / sg[i] ** 2, rtol=1e-12)
    # the scores: det and log det against numpy
    spd = fim + np.diag([1e-6, 3e-6])
    np.testing.assert_allclose(urban.fim_score(jnp.asarray(spd), "det"), np.linalg.det(spd), rtol=1e-10)
    np.testing.assert_allclose(urban.fim_score(jnp.asarray(spd), "logdet"), np.log(np.linalg.det(spd)), rtol=1e-12)
    # one bearing alone carries no information across it: det of one increment is 0
    assert abs(float(urban.det2(info(jnp.asarray(target), jnp.asarray(uavs[0]), sigma)))) < 1e-12 * np.max(np.abs(fim))


# --------------------------------------------------------------------------- 3. grid planner


CFG = S.Config()
P64 = kit.cast(S.default_params(CFG, buildings=BOXES), jnp.float64)
_plan_jit = jit(lambda p, uav, prev, belief: S.plan_command(CFG, p, S.buildings_of(p), uav, prev, belief,
                                                             jax.random.PRNGKey(0)))


def np_axis(prev, bound, rate, dt, step):
    """The paper's sampling of one command axis (Alg. 1, lines 3–5): from max(−bound, prev −
    rate Δt) to min(bound, prev + rate Δt) by ``step``, the last value the upper end."""
    lo, hi = max(-bound, prev - rate * dt), min(bound, prev + rate * dt)
    vals, k = [], 0
    while lo + k * step < hi - 1e-12:
        vals.append(lo + k * step)
        k += 1
    return vals + [hi], lo, hi


def np_brake(theta, v, dt, delta):
    """Height still gained (lost) after a step at θ when levelling off at the rate limit:
    V Δt Σ_{j≥1} sin(max(|θ| − j δ, 0)) · sign θ."""
    total, j = 0.0, 1
    while abs(theta) - j * delta > 0:
        total += np.sin(abs(theta) - j * delta)
        j += 1
    return np.sign(theta) * v * dt * total


@jit
def _indicators(emitter, pos):
    """Shadow (eqs. 7–8) and reflection-region (eqs. 9–10) membership of points (..., 3):
    the environment's own geometry (tested in tests/scenarios/chen2022/test_environment.py)."""
    b = S.buildings_of(P64)
    return (env.in_shadow(b, emitter, pos),
            jnp.any(env.reflections(b, emitter, pos, check_legs=False).valid, axis=(-2, -1)))


def np_terms(cfg, p, uav, prev, belief):
    """Every candidate of the paper's grid (the previous command first) with its J_FIM, J_T,
    J_NLOS and admissibility, from eq. 1 tracks and eqs. 13–19 in numpy."""
    dt, n, v = cfg.dt, cfg.horizon, float(p.speed)
    thetas, tlo, thi = np_axis(prev[0], float(p.theta_max), cfg.theta_rate_max, dt, cfg.theta_step)
    omegas, _, _ = np_axis(prev[1], float(p.omega_max), cfg.omega_rate_max, dt, cfg.omega_step)
    thetas = thetas + [min(max(0.0, tlo), thi)]          # the level-off θ
    cands = np.array([tuple(prev)] + [(th, om) for th in thetas for om in omegas])
    xy, mode_xy, mu, fim, sig = (np.asarray(a) for a in belief[:5])
    tracks = []
    for th, om in cands:
        s, tr = np.asarray(uav, float), []
        for _ in range(n):
            s = eq1(s, th, om, v, dt)
            tr.append(s)
        tracks.append(np.asarray(tr))
    pos = np.asarray(tracks)[..., :3]                     # (C, n, 3)
    shadow, nlos = (np.asarray(a) for a in _indicators(jnp.array([xy[0], xy[1], 0.0]), jnp.asarray(pos)))
    blocked = np_inside(pos) | shadow
    j_t = np.where(blocked.any(1), blocked.argmax(1), n)  # steps before the first blocked one
    j_nlos = nlos.sum(1)
    j_fim = np.zeros(len(cands))
    for c in range(len(cands)):
        for f in range(len(mu)):
            F = fim[f].copy()
            for s in pos[c]:
                h = np_h(mode_xy[f], s)
                F += np.outer(h, h) / sig[f] ** 2
            j_fim[c] += mu[f] * np.log(np.linalg.det(F))
    delta = cfg.theta_rate_max * dt
    z_end = np.array([uav[2] + v * dt * np.sin(th) + np_brake(th, v, dt, delta) for th in cands[:, 0]])
    ok = (z_end >= float(p.h_min)) & (z_end <= float(p.h_max)) & ~np_inside(pos).any(1)
    return cands, j_fim, j_t, j_nlos, ok


def np_choose(terms, weights):
    """argmax of J = c1 J_FIM + c2 J_T + c3 J_NLOS over the admissible candidates; ties go to
    the earliest (the previous command, then θ-major order); none admissible: the previous."""
    cands, j_fim, j_t, j_nlos, ok = terms
    j = np.where(ok, weights[0] * j_fim + weights[1] * j_t + weights[2] * j_nlos, -np.inf)
    return cands[int(np.argmax(j))]  # argmax: the first maximum; all −inf: index 0


def _planner_states():
    """UAV states near the buildings and far away, previous commands inside the bounds,
    random IMM beliefs (combined and per-mode estimates, μ, SPD FIMs). Four are placed by hand:
    flying at the tall building (some turns clear it, some do not); flying straight away from
    the believed emitter 420 m off — so the steepest θ, the shortest horizontal step, scores
    highest — near the floor descending and near the ceiling climbing, where only the braking
    climb rules out the steep θ that the next step's altitude alone would allow; and crossing
    the tall building's shadow wedge 400 m from the emitter (tracks go clear, shadowed, clear:
    J_T counts the steps before the first blocked one)."""
    rng = np.random.default_rng(11)
    tmax, wmax = float(P64.theta_max), float(P64.omega_max)
    hand = [([4400.0, 5120.0, 150.0, 0.0], [0.0, 0.0], 150.0),
            ([5300.0, 5300.0, 104.0, np.pi / 4], [-4.0 * DEG, 0.0], 10.0),
            ([4700.0, 4700.0, 396.0, 5 * np.pi / 4], [4.5 * DEG, 0.0], 10.0),
            ([4770.6, 5327.7, 150.0, 215.0 * DEG], [0.0, 0.0], 10.0)]
    states = []
    while len(states) < 10:
        if hand:
            uav, prev, spread = hand.pop(0)
        else:
            far = len(states) >= 8
            c = np.array([5000.0, 5000.0]) + (rng.uniform(-8000, -4000, 2) if far else rng.uniform(-500, 500, 2))
            uav = [c[0], c[1], rng.uniform(110.0, 390.0), rng.uniform(-np.pi, np.pi)]
            prev, spread = [rng.uniform(-tmax, tmax), rng.uniform(-wmax, wmax)], 150.0
            if np_inside(np.asarray(uav[:3])):
                continue
        xy = np.array([5000.0, 5000.0]) + rng.normal(0, spread, 2)
        a = rng.normal(size=(3, 2, 2)) * 1e-2
        fim = a @ np.swapaxes(a, 1, 2) + 1e-6 * np.eye(2)
        belief = urban.Belief(jnp.asarray(xy), jnp.asarray(xy + rng.normal(0, 2 * spread / 3, (3, 2))),
                              jnp.asarray(rng.dirichlet(np.ones(3))), jnp.asarray(fim),
                              jnp.asarray([float(P64.sigma_los), float(P64.sigma_nlos), float(P64.sigma_nlos)]))
        states.append((np.asarray(uav, float), np.asarray(prev, float), belief))
    return states


def test_grid_planner_is_the_brute_force_argmax():
    """plan_command's command = the argmax of a numpy brute force over the paper's candidate
    grid (eq. 1 tracks; eqs. 13–20 scores; no building on the track and the altitude band
    reachable), for every state and both weight vectors."""
    states = _planner_states()
    terms = [np_terms(CFG, P64, uav, prev, belief) for uav, prev, belief in states]
    chosen = {}
    for w in WEIGHTS:
        p = P64._replace(c1=jnp.float64(w[0]), c2=jnp.float64(w[1]), c3=jnp.float64(w[2]))
        for i, ((uav, prev, belief), t) in enumerate(zip(states, terms)):
            cmd, _, admissible = _plan_jit(p, jnp.asarray(uav), jnp.asarray(prev), belief)
            want = chosen[w, i] = np_choose(t, w)
            np.testing.assert_allclose(np.asarray(cmd), want, rtol=0, atol=1e-12, err_msg=f"state {i}, weights {w}")
            assert bool(admissible) == bool(np.any(t[4]))
    # teeth: some candidates are inadmissible (buildings, altitude), the planner does not just
    # hold the previous command, and the weights change the choice somewhere
    assert sum(int(np.sum(~t[4])) for t in terms) > 0
    assert sum(not np.allclose(chosen[w, i], s[1]) for w in WEIGHTS for i, s in enumerate(states)) > len(states)
    assert any(not np.allclose(chosen[WEIGHTS[0], i], chosen[WEIGHTS[1], i]) for i in range(len(states)))


# --------------------------------------------------------------------------- 4. candidates, eq. 1, braking


@pytest.mark.parametrize("prev_deg", [(4.5, 7.5), (0.0, 0.0), (-4.2, -8.0), (5.0, 6.3)])
def test_candidates_respect_bounds_rates_and_step(prev_deg):
    prev = np.asarray(prev_deg) * DEG
    lim = S.limits_of(CFG, P64)
    counts = urban.grid_counts(CFG.theta_rate_max, CFG.omega_rate_max, CFG.dt, CFG.theta_step, CFG.omega_step)
    assert counts == (5, 9)  # 2·(1°/s·2 s)/1° + 1 and 2·(1°/s²·2 s)/0.5° + 1
    c = np.asarray(urban.candidate_commands(jnp.asarray(prev), lim, CFG.dt, (CFG.theta_step, CFG.omega_step), counts))
    assert c.shape == ((counts[0] + 1) * counts[1], 2)
    tmax, wmax = float(P64.theta_max), float(P64.omega_max)
    rate = np.array([CFG.theta_rate_max, CFG.omega_rate_max]) * CFG.dt
    tol = 1e-15
    assert np.all(np.abs(c[:, 0]) <= tmax + tol) and np.all(np.abs(c[:, 1]) <= wmax + tol)
    assert np.all(np.abs(c - prev) <= rate + tol)
    grid = c.reshape(counts[0] + 1, counts[1], 2)
    # θ-major: θ constant along a row, ω the same in every row
    assert np.all(grid[..., 0] == grid[:, :1, 0]) and np.all(grid[..., 1] == grid[:1, :, 1])
    for axis, bound, step, values in ((0, tmax, CFG.theta_step, grid[:-1, 0, 0]),
                                      (1, wmax, CFG.omega_step, grid[0, :, 1])):
        want, lo, hi = np_axis(prev[axis], bound, rate[axis] / CFG.dt, CFG.dt, step)
        got = np.unique(values)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-15)
        assert abs(got[0] - lo) <= tol and abs(got[-1] - hi) <= tol       # the box's ends
        assert np.all(np.abs(np.diff(got)[:-1] - step) <= 1e-15) and np.diff(got)[-1] <= step + 1e-15
    # the extra θ row is the level-off command clip(0, lo, hi)
    _, tlo, thi = np_axis(prev[0], tmax, CFG.theta_rate_max, CFG.dt, CFG.theta_step)
    assert np.all(np.abs(grid[-1, :, 0] - min(max(0.0, tlo), thi)) <= tol)


def test_fixed_wing_step_is_eq_1():
    rng = np.random.default_rng(5)
    s = np.concatenate([rng.uniform(-5e3, 5e3, (6, 2)), rng.uniform(100, 400, (6, 1)), rng.uniform(-7, 7, (6, 1))], 1)
    th, om = rng.uniform(-0.1, 0.1, 6), rng.uniform(-0.15, 0.15, 6)
    got = np.asarray(fixed_wing_step(jnp.asarray(s), jnp.asarray(th), jnp.asarray(om), 25.0, 2.0))
    want = np.stack([eq1(s[i], th[i], om[i], 25.0, 2.0) for i in range(6)])
    np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-10)
    # ψ is not wrapped (the paper's ψ_{k+1} = ψ_k + Δt ω)
    assert float(fixed_wing_step(jnp.array([0.0, 0.0, 200.0, 3.1]), 0.0, 0.1, 25.0, 2.0)[3]) == pytest.approx(3.3)


@pytest.mark.parametrize("theta_deg", [0.0, 0.5, 2.0, 3.0, 4.3, 5.0, -1.7, -4.0, -5.0])
def test_braking_climb_is_a_simulated_level_off(theta_deg):
    """After a step at θ the UAV reduces |θ| by δ = θ̇_max Δt per step until level: the height
    it still gains (loses), summed step by step in numpy."""
    v, dt, delta = 25.0, 2.0, 2.0 * DEG
    theta = theta_deg * DEG
    th, z = abs(theta), 0.0
    while th > 0:
        th = max(th - delta, 0.0)
        z += v * dt * np.sin(th)
    got = float(braking_climb(jnp.float64(theta), v, dt, delta))
    assert got == pytest.approx(np.sign(theta) * z, rel=1e-12, abs=1e-12)
    if abs(theta_deg) > 2.0:
        assert abs(got) > 0.1  # not trivially zero


# --------------------------------------------------------------------------- 5. closed loop


N_SEEDS, N_STEPS = 4, 60
UAV0 = np.array([4300.0, 4700.0, 200.0, np.pi / 2])  # west of the emitter: the tall building's shadow is near


@pytest.fixture(scope="module")
def closed_loop():
    cfg = S.Config(n_steps=N_STEPS)
    points = [S.default_params(cfg, uav0=UAV0, buildings=BOXES, c1=c1, c2=c2, c3=c3) for c1, c2, c3 in
              ((0.2, 0.5, -0.3), (0.2, 0.5, 0.0), (0.2, 0.0, 0.0)) for _ in range(N_SEEDS)]
    params = engine.stack_points(points)
    keys = jax.vmap(lambda s: engine.run_key(0, s))(jnp.arange(len(points), dtype=jnp.uint32) % N_SEEDS)
    recs = engine.compiled(S.SCENARIO, cfg, records=True)(params, keys)
    return cfg, params, jax.tree.map(np.asarray, recs)


@pytest.mark.xdist_group("test_urban")  # one worker builds the module fixture once
def test_closed_loop_respects_the_limits_and_eq_1(closed_loop):
    cfg, params, r = closed_loop
    p = S.default_params(cfg)
    th, om = r.command[..., 0], r.command[..., 1]
    prev = np.concatenate([np.zeros_like(r.command[:, :1]), r.command[:, :-1]], 1)
    tol = 1e-12
    assert np.all(np.abs(th) <= p.theta_max + tol) and np.all(np.abs(om) <= p.omega_max + tol)
    assert np.all(np.abs(th - prev[..., 0]) <= cfg.theta_rate_max * cfg.dt + tol)
    assert np.all(np.abs(om - prev[..., 1]) <= cfg.omega_rate_max * cfg.dt + tol)
    z = r.uav[..., 2]
    assert np.all(z >= p.h_min - 1e-9) and np.all(z <= p.h_max + 1e-9)
    assert not np.any(np_inside(r.uav[..., :3]))
    # the path follows eq. 1 from the commands
    for run in range(r.uav.shape[0]):
        s = UAV0
        for t in range(N_STEPS):
            s = eq1(s, th[run, t], om[run, t], p.speed, cfg.dt)
            np.testing.assert_allclose(r.uav[run, t], s, rtol=0, atol=1e-8)
            s = r.uav[run, t]
    # teeth: the limits are reached, not vacuous — the rates and the turn bound are used in
    # full, the UAV flies down to near h_min and passes within 100 m of a building
    assert np.max(np.abs(th - prev[..., 0])) > 0.99 * cfg.theta_rate_max * cfg.dt
    assert np.max(np.abs(om)) > 0.99 * p.omega_max and np.min(z) < p.h_min + 20.0
    lo, hi = BOXES[:, None, None, 0:2], BOXES[:, None, None, 2:4]
    gap = np.maximum(np.maximum(lo - r.uav[..., :2], r.uav[..., :2] - hi), 0.0)
    assert np.min(np.hypot(gap[..., 0], gap[..., 1])) < 100.0
    # a held command is the previous one, and only after a step in the shadow
    held = r.held.astype(bool)
    assert not np.any(held[:, 0])
    assert np.all(r.shadow[:, :-1][held[:, 1:]])
    np.testing.assert_array_equal(r.command[held], prev[held])
    np.testing.assert_allclose(r.mu.sum(-1), 1.0, atol=1e-12)


@pytest.mark.xdist_group("test_urban")  # one worker builds the module fixture once
def test_closed_loop_shadow_flag_is_the_blocked_segment(closed_loop):
    """records.shadow = the segment emitter → UAV meets a building, recomputed with shapely:
    with the emitter on the ground the segment's height grows linearly, so it meets box j
    iff its part below height_j (t ≤ h_j / z_U) crosses the (closed) footprint."""
    cfg, params, r = closed_loop
    e = np.asarray(S.default_params(cfg).emitter)
    assert e[2] == 0.0
    pos = r.uav[..., :3].reshape(-1, 3)
    blocked = np.zeros(len(pos), bool)
    for x_lo, y_lo, x_hi, y_hi, h in BOXES:
        t = np.minimum(1.0, h / pos[:, 2])[:, None]
        ends = e[:2] + t * (pos[:, :2] - e[:2])
        lines = shapely.linestrings(np.stack([np.broadcast_to(e[:2], ends.shape), ends], 1))
        blocked |= shapely.intersects(lines, shapely.box(x_lo, y_lo, x_hi, y_hi))
    np.testing.assert_array_equal(r.shadow.reshape(-1), blocked)
    assert 0 < blocked.sum() < len(blocked)  # teeth: both cases occur


@pytest.mark.xdist_group("test_urban")  # one worker builds the module fixture once
def test_closed_loop_reduce_counts(closed_loop):
    cfg, params, r = closed_loop
    out = jit(jax.vmap(lambda rec, p: S.reduce(cfg, rec, p)))(S.Record(*r), params)
    assert np.all(np.asarray(out["building_steps"]) == 0)
    assert np.all(np.asarray(out["limit_violations"]) == 0)
    np.testing.assert_array_equal(np.asarray(out["shadow_steps"]), r.shadow.sum(1))
    np.testing.assert_array_equal(np.asarray(out["held_steps"]), r.held.sum(1))


# --------------------------------------------------------------------------- 6. bad input


BAD = {
    "degenerate box": ("buildings", {"buildings": [[10.0, 0.0, 5.0, 20.0, 50.0]]}),
    "zero-height box": ("buildings", {"buildings": [[0.0, 0.0, 10.0, 20.0, 0.0]]}),
    "emitter inside": ("emitter", {"emitter": [5000.0, 4700.0, 0.0]}),   # the tall building of the default layout
    "start inside": ("uav0", {"uav0": [5000.0, 4700.0, 150.0, 0.0]}),
    "h_min >= h_max": ("h_min", {"h_min": 500.0}),
    "transition row": ("imm_transition", {"imm_transition": [[0.5, 0.4, 0.0], [0.05, 0.9, 0.05], [0.05, 0.05, 0.9]]}),
}


@pytest.mark.parametrize("case", list(BAD))
def test_check_params_names_the_field(case):
    field, values = BAD[case]
    bad = S.check_params(CFG, values)
    assert bad and bad[0][0] == field, bad
    assert all(isinstance(a, str) and a and "\n" not in a for _, a in bad)
    assert S.check_params(CFG, {}) == []  # the defaults pass


def test_config_and_param_table_reject_bad_values():
    for field, value in (("theta_step", 0.0), ("omega_step", -1.0)):
        with pytest.raises(ValueError, match=field):
            S.Config(**{field: value})
    assert S.Params.TABLE["R2"].problem(1.5) is not None
    assert S.Params.TABLE["R2"].problem(0.5) is None


def _toml(v):
    return repr(v).replace("'", '"')


def _cli_spec(tmp_path, config="", params=""):
    spec = tmp_path / "spec.toml"
    spec.write_text(f'base = "{CONFIG}"\nseeds = 2\n[config]\nn_steps = 5\nwarmup_steps = 1\n{config}'
                    f'[params]\n{params}')
    return spec


def test_cli_spec_without_bad_input_validates(tmp_path):
    """The control for the cases below: the same small spec, clean, passes validation."""
    from mcjax.study import load_spec

    spec = load_spec(_cli_spec(tmp_path))
    assert spec.scenario is S.SCENARIO and spec.config.n_steps == 5 and spec.n_runs == 2


@pytest.mark.parametrize("case", list(BAD) + ["R2", "theta_step"])
def test_cli_rejects_bad_input_exit_2_nothing_written(tmp_path, case):
    """One line, ``error: <where>.<field>: …``, exit code 2, nothing written."""
    if case == "R2":
        spec, where = _cli_spec(tmp_path, params="R2 = 1.5\n"), "params.R2: must be in [0, 1]"
    elif case == "theta_step":
        spec, where = _cli_spec(tmp_path, config="theta_step = 0.0\n"), "config.theta_step: must be > 0"
    else:
        field, values = BAD[case]
        spec = _cli_spec(tmp_path, params="".join(f"{k} = {_toml(v)}\n" for k, v in values.items()))
        where = f"params.{field}: must be "
    out = tmp_path / "o"
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out)])
    assert r.exit_code == 2, r.output
    lines = [line for line in r.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: " + where), r.output
    assert not out.exists()


# --------------------------------------------------------------------------- found bugs


def _largest_array(closed_jaxpr) -> int:
    biggest = 0

    def walk(j):
        nonlocal biggest
        for e in j.eqns:
            for v in e.outvars:
                biggest = max(biggest, int(np.prod(getattr(v.aval, "shape", ()))))
            for val in e.params.values():
                for sub in (val if isinstance(val, (tuple, list)) else (val,)):
                    if hasattr(sub, "eqns"):
                        walk(sub)
                    elif hasattr(sub, "jaxpr") and hasattr(sub.jaxpr, "eqns"):
                        walk(sub.jaxpr)

    walk(closed_jaxpr.jaxpr)
    return biggest


def _plan_jaxpr(cfg):
    p = kit.cast(S.default_params(cfg), jnp.float64)
    belief = urban.Belief(jnp.array([5000.0, 5000.0]), jnp.full((3, 2), 5000.0), jnp.array([0.8, 0.1, 0.1]),
                          jnp.broadcast_to(1e-6 * jnp.eye(2), (3, 2, 2)), jnp.array([0.2, 1.0, 1.0]) * DEG)
    return jax.make_jaxpr(lambda uav, prev: S.plan_command(cfg, p, S.buildings_of(p), uav, prev, belief,
                                                           jax.random.PRNGKey(0)))(
        jnp.array([0.0, 0.0, 200.0, 0.0]), jnp.zeros(2))


def test_default_planner_program_stays_grid_sized():
    """The control for the next test: with the paper's rates the planner's largest array is
    a few thousand numbers (55 candidates × 10 steps × walls)."""
    assert 100 < _largest_array(_plan_jaxpr(CFG)) < 10**5


def test_zero_theta_rate_is_rejected_or_planned_in_bounded_memory():
    """|θ̇| ≤ 0 is refused by Config, naming the field; a tiny rate is planned with arrays of
    the grid's size (the braking climb is summed in closed form, not term by term)."""
    with pytest.raises(ValueError, match="theta_rate_max must be > 0"):
        S.Config(theta_rate_max=0.0)
    assert _largest_array(_plan_jaxpr(S.Config(theta_rate_max=1e-9))) < 10**5


def test_gradient_planner_falls_back_to_an_admissible_grid_command():
    """Heading straight at the 200 m building 300 m ahead, the previous command (straight and
    level) and the level-off one both meet it within the horizon. A gradient planner that
    cannot move (one Adam step of 1e-9) would return that inadmissible command; the scenario
    must fly the grid's best admissible one instead, whose track clears every box (numpy)."""
    cfg = S.Config(planner="gradient", plan_iterations=1, plan_learning_rate=1e-9)
    p = kit.cast(S.default_params(cfg, buildings=BOXES), jnp.float64)
    b = S.buildings_of(p)
    uav = jnp.array([4450.0, 5100.0, 150.0, 0.0])
    belief = urban.Belief(jnp.array([5000.0, 5000.0]), jnp.full((3, 2), 5000.0), jnp.array([0.8, 0.1, 0.1]),
                          jnp.broadcast_to(1e-6 * jnp.eye(2), (3, 2, 2)), jnp.array([0.2, 1.0, 1.0]) * DEG)
    straight = urban.predicted_track(uav, jnp.zeros(2), p.speed, cfg.dt, cfg.horizon)
    assert bool(jnp.any(env.inside(b, straight[:, :3])))  # the previous command is inadmissible
    command, score, ok = jit(lambda u: S.plan_command(cfg, p, b, u, jnp.zeros(2), belief,
                                                      jax.random.PRNGKey(0)))(uav)
    assert bool(ok) and np.isfinite(float(score))
    track = np.asarray(urban.predicted_track(uav, command, p.speed, cfg.dt, cfg.horizon))
    boxes = np.asarray(p.buildings)
    inside = ((track[:, None, 0] >= boxes[:, 0]) & (track[:, None, 0] <= boxes[:, 2])
              & (track[:, None, 1] >= boxes[:, 1]) & (track[:, None, 1] <= boxes[:, 3])
              & (track[:, None, 2] <= boxes[:, 4]))
    assert not inside.any()
    assert np.all(np.abs(np.asarray(command)) <= np.array([2.0, 2.0]) * DEG + 1e-12)  # within the rate box
