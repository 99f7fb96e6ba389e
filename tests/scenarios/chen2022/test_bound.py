"""Chen & Hao 2022 (urban_bearing) with bound = "on" and consistency = "on": the posterior
Cramér–Rao bound of the emitter, given the true mode sequence, and the filters' NEES / NIS.

One compiled program (40 steps, both filters) runs every case as blocks of one batch (Params only):
a straight flight (theta_max = omega_max = 0: the path does not depend on the estimate, so the bound
along it is a bound) from a start south-west of the emitter that crosses the tall building's shadow
(steps 3–7) and the low building's reflection region (steps 27–37); the same with halved bearing
noise; the same without reflections (R2 = 0: the EKF's model is then the truth's); and the paper's
closed loop. The bound is checked against a numpy recursion written from the equations on the
recorded path (the reflected bearing's Jacobian by central differences of a numpy summed field)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mcjax.engine.compilation import compiled
from mcjax.engine.keys import init_key
from mcjax.scenarios import chen2022 as ub
from mcjax.scenarios.chen2022 import environment as env
from mcjax.scenarios.chen2022.mode_filters import mixture_nis
from mcjax.scenarios.chen2022.step import filter_nees
from mcjax.scenarios.kit.consistency import predicted_nis
from mcjax.tracking.filters.gaussian import Gaussian
from mcjax.tracking.filters.imm import IMMState
from mcjax.tracking.models.sensors import azimuth

pytestmark = pytest.mark.xdist_group("urban_bound")  # one worker builds the module's fixtures once

BLOCK = 96
STRAIGHT = dict(theta_max=0.0, omega_max=0.0, uav0=np.array([4700.0, 4400.0, 200.0, 0.0]), prior_sigma=100.0)
BLOCKS = {  # name: Params changed from the defaults (the keys: the same in every block)
    "straight": STRAIGHT,
    "straight_sharper": dict(STRAIGHT, sigma_los=0.1 * ub.DEG, sigma_nlos=0.5 * ub.DEG),
    "straight_no_reflection": dict(STRAIGHT, R2=0.0),
    "closed_loop": dict(prior_sigma=100.0),
}


def _cfg(**kw):
    return ub.Config(n_steps=40, filters=("imm", "ekf"), dtype="float64", warmup_steps=10, **kw)


@pytest.fixture(scope="module")
def runs():
    jax.config.update("jax_enable_x64", True)
    cfg = _cfg(bound="on", consistency="on")
    base = ub.default_params(cfg)
    blocks = [base._replace(**{k: jnp.asarray(v, jnp.float64) for k, v in change.items()})
              for change in BLOCKS.values()]
    params = jax.tree.map(lambda *a: jnp.stack([jnp.broadcast_to(x, (BLOCK,) + jnp.shape(x)) for x in a]), *blocks)
    params = jax.tree.map(lambda a: a.reshape((-1,) + a.shape[2:]), params)
    keys = jnp.tile(jax.random.split(jax.random.PRNGKey(7), BLOCK), (len(BLOCKS), 1))
    out, ts = compiled(ub.SCENARIO, cfg, timeseries=True)(params, keys)
    P0 = jax.vmap(lambda p, k: ub.init(cfg, p, init_key(k)).filters[0].P[0])(params, keys)
    split = {}
    for i, name in enumerate(BLOCKS):
        sl = slice(i * BLOCK, (i + 1) * BLOCK)
        split[name] = dict(out={k: np.asarray(v[sl]) for k, v in out.items()},
                           ts={k: np.asarray(v[sl]) for k, v in ts.items()}, P0=np.asarray(P0[sl]),
                           params=jax.tree.map(lambda a: np.asarray(a[sl][0]), params))
    return cfg, split


# ------------------------------------------------------------------ numpy reference (from the equations)

def _np_bearing(emitter, uav, los, walls, boxes, R2):
    """The noise-free measured azimuth (eqs. 5–6): the direction of the field summed over the direct
    path (with line of sight) and the emitter's mirror image in every reflecting wall."""
    field = np.zeros(3)
    if los:
        d = emitter - uav
        field += d / (d @ d)
    for j, k in zip(*np.nonzero(walls)):
        image = emitter.copy()
        axis = 0 if k < 2 else 1
        c = boxes[j, axis] if k in (0, 2) else boxes[j, 2 + axis]
        image[axis] = 2.0 * c - emitter[axis]
        d = image - uav
        field += R2 * d / (d @ d)
    return np.arctan2(field[1], field[0])


def np_bound(P0, path, shadow, nlos, walls, p, eps=1e-3):
    """P_xx + P_yy per step of J_k = J_{k−1} + Σ ∇g ∇gᵀ / σ² (F = I, Q = 0), J_0 = P0⁻¹; ∇g by
    central differences of :func:`_np_bearing` at the true emitter, σ of the true mode."""
    J = np.linalg.inv(P0)
    out = []
    for t in range(len(path)):
        if not shadow[t]:
            sigma = p.sigma_nlos if nlos[t] else p.sigma_los
            g = np.zeros(2)
            for a in range(2):
                step = np.zeros(3)
                step[a] = eps
                g[a] = (_np_bearing(p.emitter + step, path[t], True, walls[t], p.buildings, p.R2)
                        - _np_bearing(p.emitter - step, path[t], True, walls[t], p.buildings, p.R2)) / (2 * eps)
            J = J + np.outer(g, g) / sigma**2
        out.append(np.trace(np.linalg.inv(J)))
    return np.array(out)


def _walls(p, path):
    """Which walls reflect at each point of ``path`` (T, 3) (the geometry's decision, no bound code)."""
    return np.asarray(env.reflections(ub.buildings_of(p), jnp.asarray(p.emitter), jnp.asarray(path)).valid)


def _path(ts, i):
    return np.stack([ts["x"][i], ts["y"][i], ts["z"][i]], -1)


def _ci(x):
    x = np.asarray(x, float)
    half = 1.96 * x.std(ddof=1) / np.sqrt(len(x))
    return x.mean() - half, x.mean() + half


# ------------------------------------------------------------------ tests

def test_off_declares_nothing_new_and_on_declares_the_floor_and_the_chi_square_outputs():
    new = {"pcrb_rmse", "pcrb_local_rmse", "anees", "anis"}
    assert not new & set(ub.SCENARIO.outputs(_cfg()))
    assert not {"pcrb_error", "pcrb_local_error", "nees", "nis"} & set(ub.timeseries_outputs(_cfg()))
    on = ub.SCENARIO.outputs(_cfg(bound="on", consistency="on"))
    assert new <= set(on) and on["pcrb_rmse"].role == "floor" and on["pcrb_rmse"].unit == "m"
    assert (on["anees"].role, on["anees"].dof, on["anis"].role, on["anis"].dof) == ("nees", 2, "nis", 1)
    # with both off the State and the Record carry nothing new (None)
    st = ub.init(_cfg(), ub.default_params(_cfg()), jax.random.PRNGKey(0))
    assert st.bound is None


def test_the_straight_path_meets_shadow_and_reflections_and_does_not_depend_on_the_run(runs):
    _, r = runs
    ts = r["straight"]["ts"]
    assert np.all(ts["y"] == 4400.0) and np.all(ts["z"] == 200.0)
    assert np.all(ts["shadow"][:, 3:8] == 1) and np.all(ts["nlos"][:, 27:38] == 1)
    assert np.all(ts["shadow"][:, 20:] == 0)


def test_the_bound_equals_a_numpy_recursion_on_the_recorded_path(runs):
    _, r = runs
    for name, runs_checked in (("straight", (0, 1)), ("closed_loop", (0,))):
        b = r[name]
        for i in runs_checked:
            path = _path(b["ts"], i)
            ref = np_bound(b["P0"][i], path, b["ts"]["shadow"][i] > 0, b["ts"]["nlos"][i] > 0, _walls(b["params"], path),
                           b["params"])
            np.testing.assert_allclose(b["ts"]["pcrb_error"][i] ** 2, ref, rtol=1e-6)
            assert b["out"]["pcrb_rmse"][i] == pytest.approx(np.sqrt(np.mean(ref[10:])), rel=1e-6)
    # a run of one UAV: the local bound is the team's
    np.testing.assert_array_equal(r["straight"]["ts"]["pcrb_local_error"], r["straight"]["ts"]["pcrb_error"])


def test_the_bound_falls_with_smaller_bearing_noise_at_every_step(runs):
    _, r = runs
    wide, sharp = r["straight"]["ts"]["pcrb_error"], r["straight_sharper"]["ts"]["pcrb_error"]
    assert np.all(sharp <= wide * (1 + 1e-12))
    assert np.all(sharp[:, 1:] < wide[:, 1:])
    # in the shadow nothing is added: the bound stays where it was
    np.testing.assert_allclose(wide[:, 4:8], wide[:, 3:4] * np.ones((1, 4)), rtol=1e-9)


def test_the_filters_mean_squared_error_is_not_below_the_bound(runs):
    """Open loop (the straight flight): the per-run bound is a bound; 96 runs, 95 % intervals."""
    _, r = runs
    for name in ("straight", "straight_no_reflection"):
        b = r[name]["out"]
        floor = _ci(b["pcrb_rmse"] ** 2)
        for f in range(2):
            mse = _ci(b["rmse"][:, f] ** 2)
            assert mse[1] >= floor[0], (name, f, mse, floor)


def test_closed_loop_filters_are_not_below_the_bound_of_the_mean_information(runs):
    """Closed loop: the path depends on the measurements, so the bound along each run's path is
    conditional, not a floor of the mean squared error in principle; the bound of the information
    averaged over the runs (Tichavský et al. 1998's expectation, by Monte Carlo) is. 96 runs, the
    run's mean squared error after warm-up, 95 % interval."""
    _, r = runs
    b = r["closed_loop"]
    ts, p = b["ts"], b["params"]
    Jbar = np.mean([_information(b["P0"][i], _path(ts, i), ts["shadow"][i] > 0, ts["nlos"][i] > 0, p)
                    for i in range(BLOCK)], axis=0)
    floor = np.mean([np.trace(np.linalg.inv(j)) for j in Jbar[10:]])  # after warm-up, as pcrb_rmse
    for f in range(2):
        lo, hi = _ci(b["out"]["rmse"][:, f] ** 2)
        assert hi >= floor, (f, hi, floor)
    # the paths hardly differ over the runs at this prior: the mean conditional bound is the same floor
    assert np.mean(b["out"]["pcrb_rmse"] ** 2) == pytest.approx(floor, rel=0.02)


def _information(P0, path, shadow, nlos, p):
    """J_k per step (T, 2, 2) of :func:`np_bound` for a path without reflections (asserted)."""
    J = np.linalg.inv(P0)
    out = []
    for t in range(len(path)):
        if not shadow[t]:
            assert not nlos[t]
            d = p.emitter[:2] - path[t, :2]
            g = np.array([-d[1], d[0]]) / (d @ d)
            J = J + np.outer(g, g) / p.sigma_los**2
        out.append(J)
    return np.array(out)


def test_anees_and_anis_of_a_correctly_specified_filter_are_near_their_dof(runs):
    """The paper's start, 40 steps (line of sight throughout, no reflection: asserted), a 100 m prior:
    the LOS EKF's model is the truth's and nearly linear at 7 km: ANEES near 2, ANIS near 1 (96 runs).
    (The straight flight past the buildings at 600 m is not: its NEES has a heavy tail.)"""
    _, r = runs
    assert not r["closed_loop"]["ts"]["shadow"].any() and not r["closed_loop"]["ts"]["nlos"].any()
    b = r["closed_loop"]["out"]
    ekf = 1
    # a run's NEES is correlated over its steps (a static emitter keeps its error), so a run's ANEES
    # scatters nearly as one chi-square draw: the 95 % interval of the mean over runs must meet
    # [0.85, 1.15] x dof (consistent within the EKF's linearisation), and its width stays below dof / 2
    for name, dof in (("anees", 2.0), ("anis", 1.0)):
        lo, hi = _ci(b[name][:, ekf])
        assert lo < 1.15 * dof and hi > 0.85 * dof and hi - lo < dof / 2, (name, lo, hi)


def test_nees_and_the_single_mode_nis_equal_their_definitions():
    jax.config.update("jax_enable_x64", True)
    rng = np.random.default_rng(0)
    A = rng.normal(size=(3, 2, 2))
    P = A @ A.transpose(0, 2, 1) + np.eye(2)
    x, mu, truth = rng.normal(size=(3, 2)), np.array([0.5, 0.3, 0.2]), np.array([0.3, -0.2])
    nees = np.asarray(filter_nees((IMMState(jnp.asarray(mu), jnp.asarray(x), jnp.asarray(P)),), jnp.asarray(truth)))
    xc = mu @ x
    Pc = sum(m * (Pi + np.outer(xi - xc, xi - xc)) for m, xi, Pi in zip(mu, x, P))
    e = xc - truth
    assert nees.shape == (1, 1) and nees[0, 0] == pytest.approx(e @ np.linalg.solve(Pc, e), rel=1e-12)
    # one mode (the EKF): the kit's NIS with F = I, Q = q² I
    uav, z, q, sigma = jnp.array([-800.0, 300.0, 200.0, 0.0]), jnp.asarray(0.2), 3.0, 0.01
    one = IMMState(jnp.ones(1), jnp.asarray(x[:1] * 100), jnp.asarray(P[:1] * 1e4))
    model = (jnp.zeros(1), jnp.full(1, sigma))
    got = mixture_nis(one, jnp.ones((1, 1)), model, z, uav, q)
    want = predicted_nis(Gaussian(one.x, one.P, None), jnp.eye(2), q**2 * jnp.eye(2),
                         lambda s, u: azimuth(s, u)[None], uav[None], z[None, None], jnp.full((1, 1), 1 / sigma**2),
                         jnp.array([True]))
    assert float(got) == pytest.approx(float(want[0]), rel=1e-10)
    assert np.isnan(float(mixture_nis(one, jnp.ones((1, 1)), model, jnp.asarray(jnp.nan), uav, q)))
