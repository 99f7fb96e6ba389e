"""The leader–follower scenario (Sun et al. 2011) wired correctly: records checked against
independent computations from the recorded positions, measurements and graph."""


import numpy as np
import pytest

from mcjax import engine
from mcjax.scenarios import sun2011 as lf

from benchmarks.peers import numpy_peer

CFG = lf.Config(n_steps=60, warmup_steps=5)


@pytest.fixture(scope="module")
def records():
    params = lf.default_params(CFG)
    p, k = engine.chunk_inputs(engine.stack_points([params]), 4, 0, 0, 4, 4)
    rec = engine.compiled(lf.SCENARIO, CFG, records=True)(p, k)
    return params, {name: np.asarray(v) for name, v in rec._asdict().items()}


@pytest.mark.xdist_group("test_leader_follower")  # one worker builds the module fixture once
def test_initial_geometry_is_the_papers(records):
    params, rec = records
    km = 1e3
    np.testing.assert_allclose(rec["positions"][0, 0],
                               np.array([[20, 150], [80, 150], [130, 200], [130, 100], [180, 150]]) * km)
    np.testing.assert_allclose(rec["target"][0, 0], [200 * km, 200.0, 180 * km, -1000.0])
    # UAVs fly at 800 m/s: a step's chord is at most 800 m (less while turning), and 800 m
    # once the autopilot has reached the heading command
    step = np.linalg.norm(np.diff(rec["positions"][0], axis=0), axis=-1)
    assert np.all(step <= 800.0 + 1e-6) and step[0].min() < 799.0
    np.testing.assert_allclose(step[-10:], 800.0, rtol=1e-9)
    heading = np.arctan2(*np.diff(rec["positions"][0, -2:], axis=0)[0].T[::-1])
    np.testing.assert_allclose(heading, params.heading_cmd, atol=1e-9)


@pytest.mark.xdist_group("test_leader_follower")  # one worker builds the module fixture once
def test_graph_records_match_numpy(records):
    _, rec = records
    pos, adj = rec["positions"], rec["adjacency"]
    dist = np.linalg.norm(pos[..., :, None, :] - pos[..., None, :, :], axis=-1)
    expected = (dist <= 100e3) & ~np.eye(5, dtype=bool)
    np.testing.assert_array_equal(adj, expected.astype(float))
    for t in (0, 30, 59):
        e = expected[0, t].astype(float)
        lam = np.linalg.eigvalsh(np.diag(e.sum(-1)) - e)[1]
        np.testing.assert_allclose(rec["lambda2"][0, t], lam, atol=1e-9)
    np.testing.assert_array_equal(rec["degrees"], expected.sum(-1))


@pytest.mark.xdist_group("test_leader_follower")  # one worker builds the module fixture once
def test_measurements_gated_by_sensing_range(records):
    _, rec = records
    d = rec["target"][..., None, [0, 2]] - rec["positions"]
    rng = np.linalg.norm(d, axis=-1)
    seen = np.isfinite(rec["measurements"][..., 0])
    np.testing.assert_array_equal(seen, rng <= 120e3)
    np.testing.assert_array_equal(rec["n_seeing"], seen.sum(-1))
    resid = rec["measurements"][..., 0][seen] - rng[seen]
    assert abs(resid.std() - 10.0) < 1.5  # σ_r = 10 m


@pytest.mark.xdist_group("test_leader_follower")  # one worker builds the module fixture once
@pytest.mark.parametrize("kind", ["cif", "modified_icf", "kcf"])
def test_scenario_filters_equal_numpy_peer_on_recorded_data(records, kind):
    params, rec = records
    F, Q = numpy_peer.cv_matrices(1.0, 50.0)
    args = (rec["measurements"][1], rec["positions"][1], rec["adjacency"][1], rec["target"][1, 0],
            np.diag(params.p0_diag), F, Q, np.diag([10.0**2, 0.017**2]))
    xr, _ = numpy_peer.run_filter_numpy(kind, *args)
    err = np.hypot(xr[..., 0] - rec["target"][1, :, None, 0], xr[..., 2] - rec["target"][1, :, None, 2])
    f = CFG.filters.index(kind)
    np.testing.assert_allclose(rec["error"][1, :, f], err, rtol=1e-7, atol=1e-5)


def test_cif_beats_local_and_summaries_consistent():
    params = lf.default_params(CFG)
    outs = list(engine.run_chunks(lf.SCENARIO, CFG, engine.stack_points([params]), 16, chunk_size=16))
    s = outs[0][3]
    f = {k: i for i, k in enumerate(CFG.filters)}
    assert np.median(s["rmse"][:, f["cif"]]) < np.median(s["rmse"][:, f["local"]])
    assert np.all(s["rmse"] >= s["mean_error"] - 1e-9)  # RMS >= mean
    assert np.all((s["max_error"] > 1000.0) <= s["diverged"])  # max above threshold => diverged


def test_dead_agent_is_masked():
    params = lf.default_params(CFG, alive=[1, 1, 1, 0, 1])
    # 4 seeds: the records program of the module fixture (one run would be another compile)
    p, k = engine.chunk_inputs(engine.stack_points([params]), 4, 0, 0, 4, 4)
    rec = engine.compiled(lf.SCENARIO, CFG, records=True)(p, k)
    assert np.all(np.isnan(np.asarray(rec.measurements)[:, :, 3]))
    assert np.all(np.asarray(rec.adjacency)[:, :, 3, :] == 0)


def test_config_validation_names_the_field():
    with pytest.raises(ValueError, match=r"filters must be a non-empty list .*\(unknown: 'ukf'\)"):
        lf.Config(filters=("cif", "ukf"))
    with pytest.raises(ValueError, match="consensus_weights|weights must be one of"):
        lf.Config(consensus_weights="uniform")
    with pytest.raises(ValueError, match="unknown Params field"):
        lf.default_params(CFG, comm_range=1.0)
