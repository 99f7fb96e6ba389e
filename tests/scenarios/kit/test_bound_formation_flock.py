"""The posterior Cramér–Rao bound and the NEES / NIS outputs of Chen & Lu 2013 (``wind_formation``) and
Lou, Cui & Li 2013 (``flocking``): off, no new output (the golden rows hold the values); the wind's
bound is the closed form J_k = J0 + (measurements so far)·I/σ² and falls with a smaller noise; the
uniform noise is refused; the centralised filter's mean squared error over 200 runs is not below
the bound, and its NEES is |e|²/p_k of the Kalman recursion written here; the flock's team bound is
the centralised Kalman filter's covariance of the type-I measurements and falls with more type-I
nodes, while its local bound, averaged over the type-I nodes only, does not move."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mcjax import runtime
from mcjax.analysis.statistics import chi2_band, mean_ci
from mcjax.engine import compiled
from mcjax.scenarios import chen2013 as WF
from mcjax.scenarios import lou2013 as FL

NEW = {"pcrb_rmse", "pcrb_local_rmse", "anees", "anis"}
NEW_SERIES = {"pcrb_error", "pcrb_local_error", "nees", "nis"}


def _batch(S, cfg, columns: dict, keys):
    """One compiled batch: the default Params with ``columns`` (name: per-run values) replaced."""
    runtime.configure()   # 64-bit before the Params become arrays
    n = len(keys)
    p = S.default_params(cfg)
    P = jax.tree.map(lambda a: jnp.broadcast_to(jnp.asarray(a), (n,) + jnp.shape(a)), p)
    P = P._replace(**{k: jnp.asarray(v, jnp.dtype(cfg.dtype)) for k, v in columns.items()})
    out, ts = compiled(S.SCENARIO, cfg, timeseries=True)(P, keys)
    return {k: np.asarray(v) for k, v in out.items()}, {k: np.asarray(v) for k, v in ts.items()}


@pytest.mark.parametrize("S", [WF, FL], ids=["wind_formation", "flocking"])
def test_off_adds_no_output_and_no_state(S):
    extra = {"wind_noise": "gaussian"} if S is WF else {}
    off = S.Config(**extra)
    on = S.Config(bound="on", consistency="on", **extra)
    assert off.bound == "off" and off.consistency == "off"
    assert not (NEW & set(S.outputs(off))) and not (NEW_SERIES & set(S.timeseries_outputs(off)))
    assert NEW <= set(S.outputs(on)) and NEW_SERIES <= set(S.timeseries_outputs(on))
    assert S.outputs(on)["pcrb_rmse"].unit == ("m/s" if S is WF else "m")
    p = S.default_params(off)
    key = jax.random.PRNGKey(0)
    state, rec = jax.eval_shape(lambda: S.step(off, p, S.init(off, p, key), key))
    assert state.bound is None and rec.bound is None and rec.nees is None and rec.nis is None


def test_uniform_wind_noise_refuses_the_bound():
    with pytest.raises(ValueError, match=r"^bound must be 'off' when wind_noise = 'uniform'.*"
                                         r"bound = 'on' needs wind_noise = 'gaussian'; got bound = 'on', "
                                         r"wind_noise = 'uniform'$"):
        WF.Config(bound="on")
    WF.Config(consistency="on")   # NEES / NIS are defined (approximately chi-square)
    WF.Config(bound="on", wind_noise="gaussian")


WIND_RUNS, WIND_STEPS, SIGMA_Q = 200, 30, 1e-3
NOISES = (10.0, 5.0)


@pytest.fixture(scope="module")
def wind():
    """200 runs of the Gaussian wind (noise 10 m/s, a near-constant filter model) and 4 at 5 m/s."""
    cfg = WF.Config(n_steps=WIND_STEPS, wind_noise="gaussian", bound="on", consistency="on", dtype="float64",
                    filters=("cif", "local"))
    noise = np.r_[np.full(WIND_RUNS, NOISES[0]), np.full(4, NOISES[1])]
    keys = jax.random.split(jax.random.PRNGKey(7), len(noise))
    return cfg, noise, *_batch(WF, cfg, {"noise_scale": noise, "sigma_wind_process": np.full(len(noise), SIGMA_Q)},
                               keys)


@pytest.mark.xdist_group("bound_formation_flock_wind")  # one worker builds the module fixture once
def test_wind_bound_is_the_closed_form_and_falls_with_a_smaller_noise(wind):
    cfg, noise, out, ts = wind
    p = WF.default_params(cfg)
    k = np.arange(1, WIND_STEPS + 1)
    for sigma in NOISES:
        rows = noise == sigma
        J = 1.0 / p.sigma_wind_prior**2 + k * cfg.n_agents / sigma**2   # per axis: J0 + taken · 1/σ²
        np.testing.assert_allclose(ts["pcrb_error"][rows], np.broadcast_to(np.sqrt(2.0 / J), (rows.sum(), len(k))),
                                   rtol=1e-9)
        np.testing.assert_allclose(ts["pcrb_local_error"][rows],
                                   np.broadcast_to(np.sqrt(2.0 / (1.0 / p.sigma_wind_prior**2 + k / sigma**2)),
                                                   (rows.sum(), len(k))), rtol=1e-9)
    small, large = noise == NOISES[1], noise == NOISES[0]
    assert out["pcrb_rmse"][small].max() < out["pcrb_rmse"][large].min()
    assert np.all(out["pcrb_local_rmse"] > out["pcrb_rmse"])


@pytest.mark.xdist_group("bound_formation_flock_wind")
def test_wind_cif_is_not_below_the_bound_and_its_nees_is_the_kalman_recursions(wind):
    cfg, noise, out, ts = wind
    p = WF.default_params(cfg)
    rows = noise == NOISES[0]
    cif, local = cfg.filters.index("cif"), cfg.filters.index("local")
    # the mean squared error over 200 runs is not below the floor; the cif nearly reaches it
    for f, floor in ((cif, "pcrb_rmse"), (local, "pcrb_local_rmse")):
        m = mean_ci(out["rmse"][rows, f] ** 2)
        assert m.high >= np.mean(out[floor][rows] ** 2), (f, m)
    assert mean_ci(out["rmse"][rows, cif] ** 2).mean < 1.1 * np.mean(out["pcrb_rmse"][rows] ** 2)
    # the cif's covariance is p_k I (the scalar Kalman recursion), so its NEES is |e|² / p_k
    pk, P = [], p.sigma_wind_prior**2
    for t in range(WIND_STEPS):
        P = P if t == 0 else P + SIGMA_Q**2
        P = 1.0 / (1.0 / P + cfg.n_agents / NOISES[0] ** 2)
        pk.append(P)
    err = ts["error_mean"][rows][:, :, cif]   # the cif's error, the same for every UAV
    np.testing.assert_allclose(ts["nees"][rows][:, :, cif], err**2 / np.asarray(pk), rtol=1e-9)
    # correctly specified (a near-constant model): the last step's NEES and every step's NIS, over the
    # runs, inside the 99 % chi-square band of 2 dof
    band = chi2_band(2, int(rows.sum()), 0.99)
    for f in (cif, local):
        assert band.low < ts["nees"][rows][:, -1, f].mean() < band.high, f
        assert band.low < ts["nis"][rows][:, -1, f].mean() < band.high, f
    assert np.all(np.abs(out["anees"][rows].mean(0) - 2.0) < 0.3), out["anees"][rows].mean(0)


FLOCK_STEPS, SENSING = 12, (2, 3, 6)


@pytest.fixture(scope="module")
def flock():
    """One flock of 6 nodes (the same draws) with 2, 3 and 6 type-I nodes."""
    cfg = FL.Config(n_agents=6, n_steps=FLOCK_STEPS, warmup_steps=2, integrator="rk4", bound="on",
                    consistency="on", dtype="float64")
    keys = jnp.stack([jax.random.PRNGKey(3)] * len(SENSING))
    return cfg, *_batch(FL, cfg, {"n_sensing": np.asarray(SENSING, float)}, keys)


def _kalman_position_variance(P0, F, Q, H, R, steps):
    """The Kalman filter's P_xx + P_yy per step (numpy, covariance form: P0 may be 0; no prediction at
    step 0)."""
    P, out = P0, []
    for t in range(steps):
        if t > 0:
            P = F @ P @ F.T + Q
        P = P - P @ H.T @ np.linalg.solve(H @ P @ H.T + R, H @ P)
        out.append(P[0, 0] + P[2, 2])
    return np.asarray(out)


def test_flock_bound_is_the_centralised_kalman_filters_and_falls_with_more_type_one_nodes(flock):
    cfg, out, ts = flock
    p = FL.default_params(cfg)
    dt, q, s = float(p.dt), float(p.sigma_accel) ** 2, float(p.sigma_meas)
    F = np.array([[1, dt, 0, 0], [0, 1, 0, 0], [0, 0, 1, dt], [0, 0, 0, 1.0]])
    Q1 = q * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])
    Q = np.kron(np.eye(2), Q1)
    H1 = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
    P0 = np.zeros((4, 4))  # the filters start at the true target: the bound from a known state
    for row, m in enumerate(SENSING):
        H, R = np.vstack([H1] * m), s**2 * np.eye(2 * m)
        np.testing.assert_allclose(ts["pcrb_error"][row] ** 2, _kalman_position_variance(P0, F, Q, H, R, FLOCK_STEPS),
                                   rtol=1e-9)
        # the local bound: one type-I node's own filter, whatever the number of type-I nodes
        np.testing.assert_allclose(ts["pcrb_local_error"][row] ** 2,
                                   _kalman_position_variance(P0, F, Q, H1, s**2 * np.eye(2), FLOCK_STEPS), rtol=1e-9)
    team = ts["pcrb_error"]
    assert np.all(np.diff(team, axis=0) <= 1e-12) and np.all(np.diff(team, axis=0)[:, 1:] < 0)
    assert np.all(np.diff(out["pcrb_rmse"]) < 0)
    np.testing.assert_allclose(out["pcrb_local_rmse"], out["pcrb_local_rmse"][0], rtol=1e-12)
    assert np.all(np.isfinite(out["anees"])) and np.all(np.isfinite(out["anis"]))
    assert np.all(np.isfinite(ts["nis"])) and np.all(out["anees"] > 0)
