"""Consistency and the error floor inside a scenario (Sun et al. 2011's leader–follower team, open loop,
small sizes): each agent's NIS against a numpy computation from the equations, a correctly specified
centralised filter consistent and one with the paper's inflated process noise under-confident, and the
centralised and local filters' errors never below their floors (the bound starts from the true initial
state the filters are given)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mcjax.analysis.statistics import chi2_band, floor_multiple
from mcjax.engine import simulate
from mcjax.scenarios import sun2011 as lf
from mcjax.scenarios.kit import consistency
from mcjax.tracking.filters.gaussian import Gaussian
from mcjax.tracking.models.motion import cv_matrices, cv_process_noise
from mcjax.tracking.models.sensors import range_bearing

pytestmark = pytest.mark.xdist_group("consistency_scenarios")  # one worker builds the module's fixtures once

RUNS, STEPS = 120, 30


def _batch(cfg, n, **params):
    p = lf.default_params(cfg)._replace(**{k: jnp.asarray(v) for k, v in params.items()})
    P = jax.tree.map(lambda a: jnp.broadcast_to(jnp.asarray(a), (n,) + jnp.shape(a)), p)
    return P, jax.random.split(jax.random.PRNGKey(7), n)


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def test_predicted_nis_equals_numpy_from_the_equations():
    """ν = z − h(F x), S = H (F P Fᵀ + Q) Hᵀ + R with the analytic range–bearing Jacobian; the
    bearing's innovation wrapped; NaN where no measurement."""
    rng = np.random.default_rng(3)
    n = 4
    x = np.column_stack([rng.normal(0, 5e3, n), rng.normal(200, 20, n), rng.normal(0, 5e3, n), rng.normal(0, 20, n)])
    A = rng.normal(size=(n, 4, 4))
    P = A @ A.transpose(0, 2, 1) * 100 + np.eye(4) * 50
    sensors = rng.normal(0, 4e4, (n, 2))
    z = np.column_stack([rng.uniform(1e4, 6e4, n), rng.uniform(-np.pi, np.pi, n)])
    z[2] = np.nan
    F, _ = cv_matrices(1.0, jnp.float64)
    F, Q = np.asarray(F), np.asarray(cv_process_noise(1.0, 5.0, jnp.float64))
    R = np.diag([100.0**2, 0.01**2])
    got = np.asarray(consistency.predicted_nis(Gaussian(jnp.asarray(x), jnp.asarray(P), None), jnp.asarray(F),
                                               jnp.asarray(Q), range_bearing, jnp.asarray(sensors), jnp.asarray(z),
                                               jnp.asarray(np.linalg.inv(R)), jnp.array([False, True])))
    for i in range(n):
        if i == 2:
            assert np.isnan(got[i])
            continue
        xb, Pb = F @ x[i], F @ P[i] @ F.T + Q
        dx, dy = xb[0] - sensors[i, 0], xb[2] - sensors[i, 1]
        r = np.hypot(dx, dy)
        H = np.array([[dx / r, 0, dy / r, 0], [-dy / r**2, 0, dx / r**2, 0]])
        nu = z[i] - np.array([r, np.arctan2(dy, dx)])
        nu[1] = _wrap(nu[1])
        S = H @ Pb @ H.T + R
        assert got[i] == pytest.approx(nu @ np.linalg.solve(S, nu), rel=1e-9)


CFG = lf.Config(n_steps=STEPS, warmup_steps=5, planner="none", filters=("cif", "local"), bound="on",
                consistency="on")


@pytest.fixture(scope="module")
def runs():
    cfg = CFG
    out = {}
    for name, sigma in (("matched", 5.0), ("paper", 50.0)):  # the truth's 5 m/s²; the paper's filters assume 50
        P, keys = _batch(cfg, RUNS, sigma_accel=sigma)
        out[name] = {k: np.asarray(v) for k, v in simulate(lf.SCENARIO, cfg, P, keys).items()}
    return out


def test_a_correctly_specified_centralised_filter_is_consistent_and_the_papers_under_confident(runs):
    """The cif with the truth's process noise: its ANEES (4 dof) and ANIS (2 dof) over the runs inside
    their bands; with the paper's ten-times larger acceleration noise both below (the test can fail)."""
    nees, nis = chi2_band(4, RUNS), chi2_band(2, RUNS)
    m = runs["matched"]
    assert nees.low <= m["anees"][:, 0].mean() <= nees.high
    assert nis.low <= m["anis"][:, 0].mean() <= nis.high
    p = runs["paper"]
    assert p["anees"][:, 0].mean() < nees.low and p["anis"][:, 0].mean() < nis.low


def test_the_centralised_filter_is_not_below_the_floor_and_a_local_one_not_below_its_own(runs):
    for case in runs.values():
        assert floor_multiple(case["rmse"][:, 0], case["pcrb_rmse"]).high >= 1.0
        assert floor_multiple(case["rmse"][:, 1], case["pcrb_local_rmse"]).high >= 1.0
        assert np.all(case["pcrb_local_rmse"] >= case["pcrb_rmse"])


def test_the_floor_falls_with_a_longer_sensing_range():
    """The same seeds (the same target and UAV paths in open loop): with a 60 km radar every step's bound is at
    least the 150 km one's, and above it where the shorter radar misses the target (the same program as above)."""
    series = {}
    for radius in (60e3, 150e3):
        P, keys = _batch(CFG, 8, sensing_radius=radius)
        series[radius] = np.asarray(simulate(lf.SCENARIO, CFG, P, keys, timeseries=True)[1]["pcrb_error"])
    assert np.all(series[60e3] >= series[150e3] * (1 - 1e-12))
    assert np.any(series[60e3] > series[150e3] * 1.01)
