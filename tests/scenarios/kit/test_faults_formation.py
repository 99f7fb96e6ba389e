"""Faults in the two formation scenarios with a comm graph — Chen & Lu 2013 (wind estimation
in a UAV formation, prior-consensus KF with a formation term) and Lou, Cui & Li 2013 (flocking
with a Kalman-consensus filter) — checked against facts that do not come from the fault code:
a comm graph without links, a filter that never exchanges (each agent's own Kalman filter),
the prediction-only estimate written out by hand, a NaN that must not travel, and the CLI's
exit code."""

import functools
from pathlib import Path
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from click.testing import CliRunner

from mcjax.cli import main
from mcjax.scenarios import chen2013 as wf
from mcjax.scenarios import lou2013 as fl
from mcjax.study import build_spec, run_sweep

ROOT = Path(__file__).resolve().parents[3]
SEEDS, STEPS = 2, 30
#: The error outputs every filter has (kit.error_items).
ERRORS = ("rmse", "mean_error", "final_error", "max_error", "diverged", "nonfinite")
#: Chen & Lu 2013's per-axis errors of the report agent and its formation and path statistics.
WIND_OUTPUTS = ("wind_mean_x", "wind_mean_y", "wind_max_x", "wind_max_y", "raw_mean_x", "raw_max_y",
                "formation_error_final", "path_error_mean", "join_step", "capped_steps", "max_air_step")
#: Lou et al. 2013's flock statistics (the control's graph, the energy of eq. 15, the distances).
FLOCK_OUTPUTS = ("lambda2_min", "lambda2_mean", "edges_added", "edges_removed", "final_edges", "min_distance",
                 "final_min_distance", "energy_start", "energy_end", "energy_max_rise", "final_speed_mismatch",
                 "substeps_mean")


def _sweep(name, zipped, config=None, params=None, seeds=SEEDS, steps=STEPS):
    spec = build_spec({"base": str(ROOT / "configs" / f"{name}.toml"),
                       "config": {"faults": "on", "n_steps": steps, **(config or {})},
                       "params": params or {}, "zip": zipped}, ROOT, seeds=seeds)
    return run_sweep(spec)


@functools.cache
def _jitted(scenario, cfg):
    """``scenario``'s init, step, reduce and timeseries for ``cfg``, each jitted once, the Params,
    keys and records their arguments: the tests that drive one Config by hand (with whatever
    Params) share the compiled functions, and a jitted init or reduce compiles faster than it
    runs op by op (flocking: about 1 s against 4 s each)."""
    return SimpleNamespace(init=jax.jit(lambda p, k: scenario.init(cfg, p, k)),
                           step=jax.jit(lambda p, s, k: scenario.step(cfg, p, s, k)),
                           reduce=jax.jit(lambda r, p: scenario.reduce(cfg, r, p)),
                           timeseries=jax.jit(lambda r, p: scenario.timeseries(cfg, r, p)))


def _point(df, p, kind=None):
    rows = df[df.point_id == p]
    if kind is not None:
        rows = rows[rows["filter"] == kind]
    rows = rows.sort_values(["seed_index", "filter"])
    assert len(rows) > 0
    return rows


# --------------------------------------------------------------------------- Chen & Lu 2013


def test_wind_formation_every_link_lost_is_a_graph_without_links():
    """link_loss = 1 gives exactly the filter errors, Table 1's errors and the flight of the
    same runs with a comm radius (1 m) under which no two UAVs (kilometres apart) are linked: no
    message, prior or formation term arrives either way (one program for both points). And the
    kcf that exchanges nothing is each UAV's own Kalman filter (eq. 9 with no neighbour: the
    consensus and formation sums are empty)."""
    df = _sweep("chen2013", {"link_loss": [1.0, 0.0], "comm_radius": [1e5, 1.0]})
    lost, empty = _point(df, 0), _point(df, 1)
    assert (empty.lambda2_mean == 0).all() and (lost.lambda2_mean == 0).all()
    for c in ERRORS + WIND_OUTPUTS:
        np.testing.assert_array_equal(lost[c].to_numpy(), empty[c].to_numpy(), err_msg=c)
    assert (lost.links_lost == 1.0).all() and (lost.fault_disconnected_steps == STEPS).all()
    kcf, local = _point(df, 0, "kcf"), _point(df, 0, "local")
    for c in ("rmse", "mean_error", "final_error", "max_error", "wind_mean_x", "wind_max_y"):
        np.testing.assert_allclose(kcf[c].to_numpy(), local[c].to_numpy(), rtol=1e-12, err_msg=c)


def test_wind_formation_every_sensor_dropped_keeps_the_prior():
    """sensor_dropout = 1: no UAV ever measures the wind, so every filter keeps its prior
    mean, zero wind (the random walk of eq. 1 predicts it unchanged), and its error is the wind
    speed at every step — for the kcf too once eq. 12's formation term is off (eta = 0); with
    it on the local and centralised filters still are. No measurement error is reported."""
    df = _sweep("chen2013", {"sensor_dropout": [1.0, 1.0], "eta": [0.0, 0.01]})
    speed = 40.0  # configs/chen2013.toml
    for p, kinds in ((0, ("kcf", "local", "cif")), (1, ("local", "cif"))):
        for kind in kinds:
            rows = _point(df, p, kind)
            for c in ("mean_error", "final_error", "max_error", "rmse"):
                np.testing.assert_allclose(rows[c].to_numpy(), speed, rtol=1e-12, err_msg=f"{p} {kind} {c}")
    assert (df.dropout_steps == 3 * STEPS).all()
    assert df.raw_mean_x.isna().all() and df.raw_max_y.isna().all()
    assert not np.allclose(_point(df, 1, "kcf").mean_error, speed)  # the formation term moved it


def _poison(state, k):
    """``state`` with agent k lost to faults and its per-agent filter states NaN."""
    filters = tuple(jax.tree.map(lambda a: a.at[k].set(jnp.nan), f) if f.x.ndim == 2 else f for f in state.filters)
    return state._replace(filters=filters, faults=state.faults._replace(alive=state.faults.alive.at[k].set(False)))


@pytest.mark.parametrize("k", [0, 1])
def test_wind_formation_a_lost_uavs_nan_state_reaches_no_one(k):
    """UAV k (1: the report agent) is lost at step 5 with its kcf and local states NaN: every
    other UAV's estimate, position and the centre filter stay finite, the lost UAV stays where
    it was and links to no one, and it leaves the error and formation statistics."""
    cfg = wf.Config(faults="on", n_steps=30)
    params = wf.default_params(cfg)
    key = jax.random.PRNGKey(7)
    fns = _jitted(wf, cfg)  # compiled once for both cases of k
    state = fns.init(params, key)

    def step(s, t):
        return fns.step(params, s, jax.random.fold_in(key, t))

    for t in range(5):
        state, _ = step(state, t)
    state = _poison(state, k)
    where = np.asarray(state.positions[k])
    records = []
    for t in range(5, 30):
        state, rec = step(state, t)
        records.append(rec)
        others = np.arange(cfg.n_agents) != k
        assert np.isfinite(np.asarray(rec.error)[:, others]).all()
        assert np.isfinite(np.asarray(state.positions)).all() and np.isfinite(np.asarray(state.centre.x)).all()
        for kind, f in zip(cfg.filters, state.filters):
            if kind != "cif":
                assert np.isfinite(np.asarray(f.x)[others]).all() and np.isnan(np.asarray(f.x)[k]).all()
    np.testing.assert_array_equal(np.asarray(state.positions[k]), where)
    stacked = jax.tree.map(lambda *a: jnp.stack(a), *records)
    out = fns.reduce(stacked, params)
    assert np.isfinite(np.asarray(out["rmse"])).all() and int(out["agents_lost"]) == 1
    assert np.isfinite(np.asarray(out["formation_error_final"]))
    assert np.asarray(out["links_lost"]) > 0
    series = fns.timeseries(stacked, params)
    assert np.asarray(series["error_mean"]).shape == (25, len(cfg.filters))
    assert np.isfinite(np.asarray(series["error_mean"])).all() and (np.asarray(series["agents_alive"]) == 2).all()


# --------------------------------------------------------------------------- Lou et al. 2013


def test_flocking_lost_links_drop_the_kcf_exchange_not_the_potential():
    """The flocking control's graph is sensed, not sent: with the target as the control's
    reference (so the flight does not depend on the estimates), link_loss = 1 flies exactly
    the flock of link_loss = 0 (same graph, energy, distances). And with every message lost the
    KCF of Alg. 1 is each type-I node's own Kalman filter (no neighbour's information, no
    consensus term) — Lou et al.'s Fig. 2 baseline, run beside it."""
    df = _sweep("lou2013", {"link_loss": [1.0, 0.0]}, config={"control_reference": "truth", "n_agents": 10})
    lost, kept = _point(df, 0), _point(df, 1)
    for c in FLOCK_OUTPUTS:
        np.testing.assert_array_equal(lost[c].to_numpy(), kept[c].to_numpy(), err_msg=c)
    assert (lost.links_lost == 1.0).all() and (kept.links_lost == 0.0).all()
    kcf, local = _point(df, 0, "kcf"), _point(df, 0, "local")
    for c in ("rmse", "mean_error", "final_error", "max_error"):
        np.testing.assert_allclose(kcf[c].to_numpy(), local[c].to_numpy(), rtol=1e-12, err_msg=c)
    assert not np.allclose(_point(df, 1, "kcf").rmse, _point(df, 1, "local").rmse)  # messages do matter


#: The Config of the two flocking tests that drive init/step by hand (one compiled init, step, reduce: _jitted).
FLOCK_CFG = fl.Config(faults="on", n_agents=8, n_steps=40)


@pytest.mark.xdist_group("test_faults_formation_flock")  # one worker compiles FLOCK_CFG's functions once
def test_flocking_every_sensor_dropped_is_the_prediction():
    """sensor_dropout = 1: no node ever updates from a measurement. The filters start at the
    true target state (0, v, 0, v) on y = sin x and only predict at constant velocity, so after
    step k every type-I node's estimate is at (v t, v t), t = k dt, and its error is exactly
    |v t − sin(v t)| (Lou et al. 2013 §3's path), for the KCF and the local filter alike."""
    steps = 40
    cfg = FLOCK_CFG
    params = fl.default_params(cfg)._replace(sensor_dropout=np.float64(1.0))
    key = jax.random.PRNGKey(2)
    fns = _jitted(fl, cfg)
    state, records = fns.init(params, key), []
    for t in range(steps):
        state, rec = fns.step(params, state, jax.random.fold_in(key, t))
        records.append(rec)
    records = jax.tree.map(lambda *a: jnp.stack(a), *records)
    t = np.arange(steps) * params.dt
    v = params.target_speed
    want = np.abs(v * t - np.sin(v * t))
    err = np.asarray(records.error)                        # (T, F, n)
    m = int(params.n_sensing)
    for f in range(len(cfg.filters)):
        for i in range(m):
            np.testing.assert_allclose(err[:, f, i], want, rtol=1e-9, atol=1e-12)
    out = fns.reduce(records, params)
    assert int(out["dropout_steps"]) == m * steps


@pytest.mark.xdist_group("test_faults_formation_flock")  # one worker compiles FLOCK_CFG's functions once
def test_flocking_a_lost_nodes_nan_state_reaches_no_one():
    """Node 1 (type I) is lost at step 5 with its filter states NaN: every other node's
    estimate and the whole flock stay finite, the lost node stays where it was, has no link,
    and leaves the error statistics (which stay finite)."""
    cfg = FLOCK_CFG
    n, k = cfg.n_agents, 1
    params = fl.default_params(cfg)
    key = jax.random.PRNGKey(4)
    fns = _jitted(fl, cfg)
    state = fns.init(params, key)

    def step(s, t):
        return fns.step(params, s, jax.random.fold_in(key, t))

    for t in range(5):
        state, _ = step(state, t)
    state = _poison(state, k)
    where = np.asarray(state.flock.q[k])
    records = []
    others = np.arange(n) != k
    for t in range(5, 30):
        state, rec = step(state, t)
        records.append(rec)
        for f in state.filters:
            assert np.isfinite(np.asarray(f.x)[others]).all() and np.isnan(np.asarray(f.x)[k]).all()
        assert np.isfinite(np.asarray(state.flock.q)).all() and np.isfinite(np.asarray(state.flock.p)).all()
        assert np.asarray(state.adj)[k].sum() == 0 and np.isfinite(np.asarray(rec.energy))
    np.testing.assert_array_equal(np.asarray(state.flock.q[k]), where)
    stacked = jax.tree.map(lambda *a: jnp.stack(a), *records)
    out = fns.reduce(stacked, params)
    assert np.isfinite(np.asarray(out["rmse"])).all() and int(out["agents_lost"]) == 1
    series = fns.timeseries(stacked, params)
    assert np.asarray(series["error_mean"]).shape == (25, len(cfg.filters))
    assert np.isfinite(np.asarray(series["error_max"])).all() and (np.asarray(series["agents_alive"]) == n - 1).all()


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("base, n", [("chen2013", 3), ("lou2013", 20)])
@pytest.mark.parametrize("lines, config, field", [
    ("link_loss = 1.5", 'faults = "on"\n', "link_loss"),
    ("sensor_dropout = -0.1", 'faults = "on"\n', "sensor_dropout"),
    ("min_alive = {n_plus_1}", 'faults = "on"\n', "min_alive"),
    ("link_loss = 0.2", "", "link_loss"),  # faults off
])
def test_bad_fault_input_exits_2_with_one_line_naming_the_field(tmp_path, base, n, lines, config, field):
    spec = tmp_path / "s.toml"
    spec.write_text(f'base = "{ROOT / "configs"}/{base}.toml"\nseeds = 2\n[config]\n{config}[params]\n'
                    f'{lines.format(n_plus_1=n + 1)}\n')
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out)])
    assert r.exit_code == 2, r.output
    text = r.output.strip()
    assert len(text.splitlines()) == 1 and field in text, text
    assert not out.exists()
