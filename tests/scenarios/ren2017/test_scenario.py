"""The multi-UUV IMM scenario (Ren & Lv 2017) against filterpy, the CT geometry and the Markov chain."""

import dataclasses
import functools
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from filterpy.kalman import IMMEstimator, MerweScaledSigmaPoints, UnscentedKalmanFilter

from mcjax import engine
from mcjax.cli import main
from mcjax.scenarios import ren2017 as S
from mcjax.study import load_config_file
from mcjax.tracking.filters.imm import combine
from mcjax.tracking.models.motion import ct_matrix, cv_matrices, cv_process_noise

CONFIG = str((Path(__file__).parents[3] / "configs" / "ren2017.toml").resolve())
#: The Config of the tests that drive init/step by hand: one compiled step for all of them (the
#: Params are its arguments). The IMM and the CV UKF; 30 consensus iterations, which the
#: complete-graph test needs (with no links, as in the filterpy test, iterating changes nothing).
CFG = S.Config(n_steps=60, filters=("imm", "cv"), consensus_steps=30)


@functools.cache
def _step(cfg):
    return jax.jit(lambda p, s, k: S.step(cfg, p, s, k))


@functools.cache
def _init(cfg):
    return jax.jit(lambda p, k: S.init(cfg, p, k))


#: Each filter's combined estimate per UUV, compiled (not run op by op at every step).
_combined = jax.jit(lambda f: jax.vmap(combine)(f)[0])


def simulate(cfg, params, seed=0, steps=None):
    """Drive init/step by hand for ``steps`` steps (default cfg.n_steps); returns the records and
    every step's combined estimates per filter, (T, F, n, 4)."""
    step = _step(cfg)
    key = engine.run_key(0, seed)
    state = _init(cfg)(params, key)
    recs, ests = [], []
    for t in range(cfg.n_steps if steps is None else steps):
        state, rec = step(params, state, jax.random.fold_in(key, t))
        recs.append(rec)
        ests.append([_combined(f) for f in state.filters])
    recs = jax.tree.map(lambda *xs: np.stack(xs), *recs)
    return recs, np.asarray(ests)


class RegeneratingUKF(UnscentedKalmanFilter):
    """filterpy's UKF, but the update draws fresh sigma points from the predicted (x̄, P̄)
    (filterpy reuses the propagated ones; docs/equations.md and our UKF redraw)."""

    def update(self, z, **kw):
        self.sigmas_f = self.points_fn.sigma_points(self.x, self.P)
        super().update(z, **kw)


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def filterpy_ukf(F, Q, R, sensor, x0, P0):
    def hx(x):
        d = np.array([x[0] - sensor[0], x[2] - sensor[1]])
        return np.array([np.hypot(*d), np.arctan2(d[1], d[0])])

    def z_mean(sigmas, wm):  # bearings averaged about the central point, as our UT does
        r = sigmas - sigmas[0]
        r[:, 1] = _wrap(r[:, 1])
        m = sigmas[0] + wm @ r
        m[1] = _wrap(m[1])
        return m

    def residual(a, b):
        d = a - b
        d[1] = _wrap(d[1])
        return d

    f = RegeneratingUKF(4, 2, 1.0, hx, lambda x, dt: F @ x, MerweScaledSigmaPoints(4, alpha=1.0, beta=2.0, kappa=0.0),
                        z_mean_fn=z_mean, residual_z=residual)
    f.x, f.P, f.Q, f.R = x0.copy(), P0.copy(), Q, R
    return f


@pytest.mark.xdist_group("test_uuv_imm_step")  # one worker compiles _step(CFG) once
def test_isolated_uuv_filters_match_filterpy_ukf_and_imm():
    """With no communication (comm radius 0) each UUV's "cv" filter is a UKF and its "imm"
    filter an IMM of a CV and a CT UKF on its own measurements: the same as filterpy's
    UnscentedKalmanFilter and IMMEstimator fed those measurements. Ours updates in
    information form with the pseudo-measurement H̃ = (P̄⁻¹P_xz)ᵀ, which equals the moment
    form up to the UT's linearisation residual P_zz − H̃P̄H̃ᵀ = O(σ²/r²) (a few 1e-3 m here)."""
    cfg = CFG
    p = S.default_params(cfg, comm_radius=0.0, ct_start=20, ct_stop=40)
    recs, est = simulate(cfg, p)
    F_cv = np.asarray(cv_matrices(1.0, jnp.float64)[0])
    F_ct = np.asarray(ct_matrix(1.0, float(p.turn_rate), jnp.float64))
    Q = np.asarray(cv_process_noise(1.0, float(p.sigma_accel), jnp.float64))
    R = np.diag([float(p.sigma_range) ** 2, float(p.sigma_bearing) ** 2])
    x0, P0 = np.asarray(p.target_x0), np.diag(p.p0_diag)
    worst_cv = worst_imm = worst_mu = 0.0
    for i in (0, 3):  # bearings near ±π from UUV1, near 0 from UUV4
        sensor = np.asarray(p.uuv_positions[i])
        cv = filterpy_ukf(F_cv, Q, R, sensor, x0, P0)
        imm = IMMEstimator([filterpy_ukf(F_cv, Q, R, sensor, x0, P0), filterpy_ukf(F_ct, Q, R, sensor, x0, P0)],
                           np.asarray(p.mu0), np.asarray(p.imm_transition))
        for t in range(cfg.n_steps):
            z = recs.measurements[t, i]
            if t > 0:  # step 0 updates the prior without predicting (docs/equations.md)
                cv.predict()
                imm.predict()
            cv.update(z)
            imm.update(z)
            worst_cv = max(worst_cv, np.max(np.abs(est[t, 1, i] - cv.x)))
            worst_imm = max(worst_imm, np.max(np.abs(est[t, 0, i] - imm.x)))
            worst_mu = max(worst_mu, abs(float(recs.mu_ct[t, i]) - imm.mu[1]))
    assert worst_cv < 0.02 and worst_imm < 0.02, (worst_cv, worst_imm)
    assert worst_mu < 0.01, worst_mu
    # and the comparison has teeth: the estimates move by metres over the run
    assert np.ptp(est[:, 0, 0, 0]) > 100


@pytest.mark.xdist_group("test_uuv_imm_step")  # one worker compiles _step(CFG) once
def test_true_target_follows_the_schedule_and_the_ct_geometry():
    """Noise-free truth: straight at constant speed in CV; in CT the speed is kept and the
    heading turns by exactly ω·dt per step (Bar-Shalom et al. §11.7)."""
    p = S.default_params(CFG, target_sigma_accel=0.0, ct_start=10, ct_stop=25, turn_rate=0.1)
    recs, _ = simulate(CFG, p, steps=40)
    mode = recs.mode
    np.testing.assert_array_equal(mode, (np.arange(40) >= 10) & (np.arange(40) < 25))
    v = recs.target[:, [1, 3]]
    np.testing.assert_allclose(np.hypot(v[:, 0], v[:, 1]), np.hypot(5.0, 5.0), rtol=1e-12)
    heading = np.unwrap(np.arctan2(v[:, 1], v[:, 0]))
    np.testing.assert_allclose(np.diff(heading), np.where(mode[1:] == 1, 0.1, 0.0), atol=1e-12)
    # position advances by the chord of the arc in CT, by v·dt in CV
    step = np.hypot(np.diff(recs.target[:, 0]), np.diff(recs.target[:, 2]))
    chord = 2 * np.hypot(5.0, 5.0) / 0.1 * np.sin(0.1 / 2)
    np.testing.assert_allclose(step, np.where(mode[1:] == 1, chord, np.hypot(5.0, 5.0)), rtol=1e-10)


def test_markov_schedule_has_the_chain_statistics():
    """Over many runs the drawn modes switch with the target_transition frequencies."""
    # two UUVs and the CV filter: the target's chain depends on neither, and the program is small
    cfg = S.Config(n_steps=60, n_agents=2, filters=("cv",), schedule="markov")
    P = np.array([[0.9, 0.1], [0.3, 0.7]])
    p = engine.stack_points([S.default_params(cfg, target_transition=P)])
    params, keys = engine.chunk_inputs(p, 300, 0, 0, 300, 300)
    recs = engine.compiled(S.SCENARIO, cfg, records=True)(params, keys)
    m = np.asarray(recs.mode)
    assert np.all(m[:, 0] == 0)  # starts in CV
    prev, nxt = m[:, :-1].ravel(), m[:, 1:].ravel()
    for l in (0, 1):
        freq = np.mean(nxt[prev == l] == 1)
        n = np.sum(prev == l)
        assert abs(freq - P[l, 1]) < 4 * np.sqrt(P[l, 1] * (1 - P[l, 1]) / n), (l, freq, n)


@pytest.mark.xdist_group("test_uuv_imm_step")  # one worker compiles _step(CFG) once
def test_consensus_agrees_on_a_complete_graph():
    """Comm radius above the hexagon's diameter links every pair; with many consensus
    iterations every UUV holds the same estimate (the consensus invariant), and sharing
    measurements beats tracking alone."""
    steps, turn = 30, dict(ct_start=10, ct_stop=20)  # 30 steps, the turn in the middle third
    recs, est = simulate(CFG, S.default_params(CFG, comm_radius=1000.0, **turn), steps=steps)
    assert np.all(recs.lambda2 > 5.999)  # complete graph of 6: λ2 = 6
    est = est[:, :1]  # the IMM (CFG.filters[0])
    spread = np.max(np.abs(est - est[:, :, :1]))
    assert spread < 1e-6, spread
    _, alone = simulate(CFG, S.default_params(CFG, comm_radius=0.0, **turn), steps=steps)
    alone = alone[:, :1]
    assert np.max(np.abs(alone - alone[:, :, :1])) > 0.1


#: The steps of the IMM test's 32 runs and of the sweep test's 4 points x 8 seeds, both of
#: ren2017.toml's Config with timeseries: one compiled program.
SWEEP_STEPS = 75


@pytest.mark.xdist_group("test_uuv_imm_sweep")  # one worker compiles their program once
def test_imm_beats_both_single_models_and_mismatch_costs_during_the_manoeuvre():
    """Ren & Lv 2017's qualitative claims over 32 runs (the benchmark shows them over 1,000).
    (The Config, the 32-run batch and the timeseries flag of the sweep test below: one program.)"""
    scenario, cfg, params = load_config_file(CONFIG)
    cfg = dataclasses.replace(cfg, n_steps=SWEEP_STEPS)
    p = engine.stack_points([scenario.default_params(cfg, **{**params, "ct_start": 25, "ct_stop": 50})])
    out = next(engine.run_chunks(S.SCENARIO, cfg, p, 32, timeseries=True))[3][0]
    imm, cv, ct = (cfg.filters.index(f) for f in ("imm", "cv", "ct"))
    for i in range(1, 7):
        m = out[f"uuv{i}_mean_error"].mean(0)
        assert m[imm] < m[cv] and m[imm] < m[ct], (i, m)
    e_ct, e_cv = out["error_ct"].mean(0), out["error_cv"].mean(0)
    assert e_ct[cv] > e_ct[ct] and e_cv[ct] > e_cv[cv]
    assert np.all(out["mode_accuracy"] > 0.7)


@pytest.mark.parametrize("sigma", [100.0, 1e4])
@pytest.mark.xdist_group("test_uuv_imm_step")  # one worker compiles _step(CFG) once
def test_mode_probabilities_stay_valid_for_a_far_outlier(sigma):
    """A measurement ``sigma`` σ off in range at every UUV at once: the IMM's mode
    probabilities stay finite, in [0, 1] and sum to 1 (log-space likelihoods)."""
    p = S.default_params(CFG, ct_start=1, ct_stop=3)  # a turn in steps 1-2 (the defaults of 5 steps)
    state = _init(CFG)(p, jax.random.PRNGKey(0))
    step = _step(CFG)
    for t in range(3):
        state, _ = step(p, state, jax.random.PRNGKey(t))
    # push the IMM's belief far off: every UUV's estimate shifted by sigma·σ_r
    f = state.filters[0]
    shifted = f._replace(x=f.x.at[..., 0].add(sigma * float(p.sigma_range)))
    state, rec = step(p, state._replace(filters=(shifted, *state.filters[1:])), jax.random.PRNGKey(9))
    mu = np.asarray(state.filters[0].mu)
    assert np.all(np.isfinite(mu)) and np.all((mu >= 0) & (mu <= 1))
    np.testing.assert_allclose(mu.sum(-1), 1.0, atol=1e-12)
    assert np.all(np.isfinite(rec.error))


@pytest.mark.xdist_group("test_uuv_imm_sweep")  # one worker compiles their program once
def test_sweep_over_comm_radius_and_turn_rate(tmp_path):
    """The scenario runs through the sweep CLI: hive dataset with points × seeds × filters rows,
    timeseries with the true mode and the IMM's CT probability."""
    spec = tmp_path / "spec.toml"
    spec.write_text(f'base = "{CONFIG}"\nseeds = 8\nchunk_size = 4\ntimeseries = true\n'
                    f'[config]\nn_steps = {SWEEP_STEPS}\n[params]\nct_start = 4\nct_stop = 8\n'
                    '[grid]\ncomm_radius = [0.0, 450.0]\nturn_rate = [0.02, 0.1]\n')
    out = tmp_path / "o"
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out)])
    assert r.exit_code == 0, r.output
    df = pd.read_parquet(out / "runs")
    assert len(df) == 4 * 8 * 3 and set(df["filter"]) == {"imm", "cv", "ct"}
    assert {"uuv6_max_error", "error_ct", "mode_accuracy"} <= set(df.columns)
    assert np.all(df["ct_steps"] == 4)
    ts = pd.read_parquet(out / "timeseries")
    assert len(ts) == 4 * 8 * SWEEP_STEPS * 3 and set(ts["mode"]) == {0, 1}
    assert ts["mu_ct"].between(0, 1).all()
    r = CliRunner().invoke(main, ["report", str(out), "--no-plots"])
    assert r.exit_code == 0 and "turn_rate" in r.output


@pytest.mark.parametrize("body, message", [
    ("[params]\nimm_transition = [[0.9, 0.2], [0.1, 0.9]]\n", "params.imm_transition: must be a 2x2 matrix"),
    ("[params]\nct_start = 50\nct_stop = 40\n", "params.ct_stop: must be a step >= ct_start"),
    ("[params]\nmu0 = [0.5, 0.7]\n", "params.mu0: must be two probabilities [CV, CT] that sum to 1"),
    ("[config]\nschedule = \"random\"\n", "config.schedule: must be one of fixed, markov"),
])
def test_bad_uuv_spec_exit_2(tmp_path, body, message):
    spec = tmp_path / "spec.toml"
    spec.write_text(f'base = "{CONFIG}"\n' + body)
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(tmp_path / "o")])
    assert r.exit_code == 2, r.output
    assert message in r.output and not (tmp_path / "o").exists()


def test_run_uses_the_configs_seed_count():
    """`mcjax run` without --seeds runs the config's `seeds` (the paper's 50 runs). (One filter, the
    CV UKF: a small program; the IMM runs through the CLI in the sweep test above.)"""
    r = CliRunner().invoke(main, ["run", CONFIG, "--set", "config.n_steps=8", "--set", "config.warmup_steps=1",
                                  "--set", 'config.filters=["cv"]'])
    assert r.exit_code == 0, r.output
    header = next(line.split() for line in r.output.splitlines() if line.split()[:2] == ["filter", "n"])
    rows = [dict(zip(header, line.split())) for line in r.output.splitlines()
            if line.split()[:1] in (["imm"], ["cv"], ["ct"])]
    assert [row["filter"] for row in rows] == ["cv"] and rows[0]["n"] == "50"
