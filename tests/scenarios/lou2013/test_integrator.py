"""The flock's error-controlled integrator (Lou, Cui & Li 2013; mcjax/scenarios/lou2013/dynamics.py):
the Dormand–Prince 5(4) pair's coefficients against its order conditions, the cubic Hermite extremes
against dense sampling, one 0.1 s step against scipy's DOP853 from states of the paper's set-up
(transient and steady), and the link margin and the smallest distance of a lone pair against
their values from energy conservation (the turning points fall inside a sub-step).

Small sizes, float64; about 16 s of CPU.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from mcjax.scenarios import lou2013 as fl
from mcjax.scenarios.lou2013 import dynamics as dyn

jax.config.update("jax_enable_x64", True)


def test_dormand_prince_coefficients_meet_the_order_conditions():
    """Rows sum to the nodes; the 5th-order weights meet the quadrature conditions Σ b c^k =
    1/(k+1), k ≤ 4, and Σ b a c = 1/6 … the 4th-order weights (5th minus the error weights) up
    to k ≤ 3 but not the 5th-order one (the estimate is not zero)."""
    c = np.array(dyn._DP_C)
    A = np.zeros((7, 7))
    for i, row in enumerate(dyn._DP_A):
        A[i, :len(row)] = row
    np.testing.assert_allclose(A.sum(1), c, atol=1e-15)
    b5 = A[6]
    b4 = b5 - np.array(dyn._DP_E)
    for k in range(5):
        assert abs(b5 @ c**k - 1 / (k + 1)) < 1e-14
    for k in range(4):
        assert abs(b4 @ c**k - 1 / (k + 1)) < 1e-14
    assert abs(b4 @ c**4 - 1 / 5) > 1e-4
    assert abs(b5 @ (A @ c) - 1 / 6) < 1e-14 and abs(b5 @ (A @ c**2) - 1 / 12) < 1e-14


def test_dopri5_substep_is_fifth_order_and_its_estimate_fourth():
    """On ẏ = −y (every leaf of a flock state) the step's error against e^{−h} falls ~2⁶ and its
    estimate ~2⁵ when h halves."""
    f = lambda s, t: jax.tree.map(lambda y: -y, s)  # noqa: E731
    s0 = dyn.FlockState(jnp.ones((2, 2)), 2.0 * jnp.ones((2, 2)), jnp.zeros((2, 2)))
    errs, ests = [], []
    for h in (0.2, 0.1):
        new, _, est = dyn.dopri5_substep(f, s0, f(s0, 0.0), 0.0, h)
        errs.append(abs(float(new.p[0, 0]) - 2.0 * math.exp(-h)))
        ests.append(abs(float(est.p[0, 0])))
    assert 60 < errs[0] / errs[1] < 72
    assert 28 < ests[0] / ests[1] < 36


def test_hermite_extremes_are_those_of_the_sampled_cubic():
    rng = np.random.default_rng(0)
    r0, r1 = rng.uniform(0.5, 3, 200), rng.uniform(0.5, 3, 200)
    v0, v1 = rng.uniform(-20, 20, 200), rng.uniform(-20, 20, 200)
    h = rng.uniform(0.01, 0.3, 200)
    extremes = jax.jit(dyn.hermite_extremes)  # one program per shape (op by op costs more)
    lo, hi = (np.asarray(x) for x in extremes(*(jnp.asarray(a) for a in (r0, v0, r1, v1, h))))
    s = np.linspace(0, 1, 20001)[:, None]
    cubic = ((2 * s**3 - 3 * s**2 + 1) * r0 + (s**3 - 2 * s**2 + s) * h * v0 + (-2 * s**3 + 3 * s**2) * r1
             + (s**3 - s**2) * h * v1)
    np.testing.assert_allclose(lo, cubic.min(0), atol=1e-6)
    np.testing.assert_allclose(hi, cubic.max(0), atol=1e-6)
    assert np.all(lo <= cubic.min(0) + 1e-12) and np.all(hi >= cubic.max(0) - 1e-12)
    # a quadratic r(t) = 1 − 4 t + 10 t² (its own Hermite cubic): the minimum 0.6 at t = 0.2
    lo, hi = extremes(*(jnp.asarray(a) for a in (1.0, -4.0, 1.0 - 4.0 * 0.5 + 10 * 0.25, -4.0 + 20 * 0.5, 0.5)))
    assert abs(float(lo) - 0.6) < 1e-14 and abs(float(hi) - 1.5) < 1e-14


CFG = fl.Config(n_agents=20, n_steps=12, filters=("kcf",), warmup_steps=0, divergence_threshold=5.0,
                dtype="float64")


@pytest.fixture(scope="module")
def paper_states():
    """The flock, graph and KCF estimate (after the step's update) at steps 0, 1 and 11 of seed 0
    of the paper's set-up (the config's integrator), and the flock at the next step."""
    p = fl.default_params(CFG)
    key = jax.random.PRNGKey(0)
    state = jax.jit(lambda k: fl.init(CFG, p, k))(key)
    step = jax.jit(lambda s, k: fl.step(CFG, p, s, k))
    out = {}
    for t in range(CFG.n_steps):
        nxt, _ = step(state, jax.random.fold_in(key, t))
        if t in (0, 1, 11):
            out[t] = (state.flock, state.adj, nxt.filters[0].x, nxt.flock)
        state = nxt
    return p, out


@jax.jit
def _rhs(t, y, adj, h, rq0, rp0, g):
    """The flock's derivative on a flat vector (one program for every state of the test)."""
    n = adj.shape[0]
    s = dyn.FlockState(y[:2 * n].reshape(n, 2), y[2 * n:4 * n].reshape(n, 2), y[4 * n:].reshape(n, n))
    d = dyn.derivative(s, adj, h, rq0 + t * rp0, rp0, g)
    return jnp.concatenate([d.q.ravel(), d.p.ravel(), d.b.ravel()])


def _dop853(p, flock, adj, est, h, g):
    n = flock.q.shape[0]
    rq0, rp0 = est[:, jnp.array([0, 2])], est[:, jnp.array([1, 3])]
    y0 = np.concatenate([np.asarray(x).ravel() for x in (flock.q, flock.p, flock.b)])
    sol = solve_ivp(lambda t, y: np.asarray(_rhs(t, y, adj, h, rq0, rp0, g)), (0.0, float(p.dt)), y0,
                    method="DOP853", rtol=1e-11, atol=1e-12)
    y = sol.y[:, -1]
    return y[:2 * n].reshape(n, 2), y[2 * n:4 * n].reshape(n, 2), y[4 * n:].reshape(n, n)


@jax.jit
def _adaptive(flock, adj, h, est, g, dt):
    """The scenario's integrator over one step (the config's), following the KCF's estimate
    ``est`` as the reference (one program for every state of the test)."""
    rq0, rp0 = est[:, jnp.array([0, 2])], est[:, jnp.array([1, 3])]
    return dyn.dopri5_adaptive(flock, adj, h, lambda tau: (rq0 + tau * rp0, rp0), g, dt, CFG.max_substeps,
                               CFG.tolerance)


def test_one_step_is_within_the_tolerance_of_dop853_in_the_transient_and_steady_flight(paper_states):
    """Steps 0 and 1 (the flock contracts: pairs close at ~10 m/s) and 11: the step the scenario
    took (re-integrated here: the same state to rounding) against DOP853 at rtol 1e-11, within
    the config's tolerance in position (m), velocity (m/s) and the gains (1/s); the RK4
    sub-steps used before miss it by far in the transient."""
    p, states = paper_states
    h = fl.sensing_mask(CFG, p, jnp.float64)
    g = dyn.Gains(p.c1, p.c2, p.k, p.R)
    for t, (flock, adj, est, nxt) in states.items():
        s, margin, dmin, k, capped = _adaptive(flock, adj, h, est, g, p.dt)
        assert not bool(capped) and float(margin) > 0 and float(dmin) > 0
        np.testing.assert_allclose(np.asarray(s.q), np.asarray(nxt.q), atol=1e-9)
        q, v, b = _dop853(p, flock, adj, est, h, g)
        errors = [np.max(np.abs(np.asarray(x) - y)) for x, y in ((s.q, q), (s.p, v), (s.b, b))]
        assert max(errors) <= CFG.tolerance, (t, errors)
        if t == 0:
            rq0, rp0 = est[:, jnp.array([0, 2])], est[:, jnp.array([1, 3])]
            ref = lambda tau: (rq0 + tau * rp0, rp0)  # noqa: E731
            old = jax.jit(lambda: dyn.rk4_adaptive(flock, adj, h, ref, g, p.dt, 200, 1.0)[0])()
            assert np.max(np.abs(np.asarray(old.p) - v)) > 100 * CFG.tolerance


def _pair(r0, v, R=8.4):
    """Two type-II nodes r0 apart on the x axis, separating at v (closing if v < 0), linked, k = 0
    (no alignment): r̈ = −2ψ′(r), so ½ ṙ² + 2ψ(r) is conserved."""
    s = dyn.FlockState(jnp.array([[0.0, 0.0], [r0, 0.0]]), jnp.array([[-v / 2, 0.0], [v / 2, 0.0]]),
                       jnp.zeros((2, 2)))
    adj = jnp.array([[0.0, 1.0], [1.0, 0.0]])
    g = dyn.Gains(jnp.asarray(1.0), jnp.asarray(2.0), jnp.asarray(0.0), jnp.asarray(R))
    zero = jnp.zeros((2, 2))
    return s, adj, g, lambda tau: (zero, zero)


@jax.jit
def _pair_step(s, adj, g, max_substeps=1000):
    """One 0.1 s step of a lone pair (no reference, no sensing) at tolerance 1e-6, started with
    a sub-step of the whole 0.1 s: one program for the three pairs below (their states and the
    number of sub-steps allowed are its arguments)."""
    zero = jnp.zeros((2, 2), s.q.dtype)
    return dyn.dopri5_adaptive(s, adj, jnp.zeros(2), lambda tau: (zero, zero), g, 0.1, max_substeps, 1e-6,
                               first_step=jnp.asarray(0.1))


@pytest.mark.parametrize("r0, v, which", [(7.6, 6.0, "margin"), (1.0, -12.0, "distance")])
def test_a_pair_turning_inside_a_substep_is_caught_at_its_turning_point(r0, v, which):
    """A pair flying apart towards R (or together towards 0) turns where ψ(r*) = ψ(r0) + v²/4
    (energy). The integrator, started with a sub-step of the whole 0.1 s, reports R − r* (or r*)
    to 1e-6: the closing-speed cap keeps it from stepping over R, and the turn, inside a
    sub-step, is found by the Hermite interpolant."""
    R = 8.4
    s, adj, g, _ = _pair(r0, v, R)
    psi = lambda r: 1 / r**2 + r**2 / (R - r)  # noqa: E731
    level = psi(r0) + v**2 / 4
    r_star = brentq(lambda r: psi(r) - level, r0, R - 1e-12) if which == "margin" else \
        brentq(lambda r: psi(r) - level, 1e-3, r0)
    out, margin, dmin, k, capped = _pair_step(s, adj, g)
    assert not bool(capped)
    got = float(margin) if which == "margin" else float(dmin)
    want = R - r_star if which == "margin" else r_star
    assert abs(got - want) < 1e-6, (got, want)
    # the turn happened within the step, and the pair is back inside (R − r) or apart again
    r_end = float(jnp.linalg.norm(out.q[1] - out.q[0]))
    assert (R - r_end > got) if which == "margin" else (r_end > got)
    e_end = 0.5 * float(jnp.sum((out.p[1] - out.p[0]) ** 2)) + 2 * psi(r_end)
    assert abs(e_end - (0.5 * v**2 + 2 * psi(r0))) < 1e-4 * e_end  # energy conserved to the tolerance


def test_a_capped_step_that_breaks_a_link_is_flagged():
    """The same pair flying apart at 60 m/s with one sub-step allowed: the step is capped, its
    one sub-step (the whole 0.1 s) carries the pair past R, and the margin says so (≤ 0 or NaN)."""
    s, adj, g, _ = _pair(7.6, 60.0)
    # the one allowed sub-step takes the whole step whatever its first size (the last one
    # allowed takes the time left), so the pairs' program above serves
    out, margin, dmin, k, capped = _pair_step(s, adj, g, 1)
    assert bool(capped) and int(k) == 1
    assert not float(margin) > 0


def test_tolerance_and_integrator_are_config_fields_with_their_checks():
    assert fl.Config().integrator == "dopri5" and fl.Config().tolerance == 1e-6
    for bad in (0.0, -1e-6, math.inf):
        with pytest.raises(ValueError, match="tolerance"):
            fl.Config(tolerance=bad)
    with pytest.raises(ValueError, match="integrator"):
        fl.Config(integrator="euler")
