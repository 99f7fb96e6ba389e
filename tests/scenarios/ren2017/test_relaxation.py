"""Ren & Lv 2017's relaxation switch (uuv_imm.Temperatures): the tune loss's forward-mode gradient
against central differences, the smooth system approaching the exact one as the temperatures
shrink, the summary of a smooth record, and the consensus IMM-UKF's smooth inputs against its
exact filter (gates of 1 and of 0). Small sizes, float64."""

import jax
import jax.numpy as jnp
import numpy as np

from mcjax import engine
from mcjax.contract.relaxation import smooth_params
from mcjax.scenarios.ren2017 import Config, SCENARIO, Temperatures, mode_hits
from mcjax.tracking import graph
from mcjax.tracking.filters.consensus_imm import consensus_imm_ukf_step
from mcjax.tracking.filters.gaussian import Unscented
from mcjax.tracking.filters.imm import IMMState
from mcjax.tracking.models.sensors import range_bearing
from mcjax.tune import Loss, run_loss

#: Both switches in play: the sonar's range (450 m) cuts some UUVs in and out as the target
#: moves (their ranges run from ~180 m to ~620 m), and a 420 m comm radius gives the ring links a
#: 20 m margin (soft weight sigmoid(2) = 0.88 at the default 10 m).
GATED = dict(sensing_radius=450.0, comm_radius=420.0)


def _batch(params, runs):
    """``runs`` copies of ``params`` (strongly typed, so every test's batch fits one program)."""
    return jax.tree.map(lambda a: jnp.broadcast_to(jnp.asarray(np.asarray(a)), (runs,) + np.shape(a)), params)


def _keys(base_seed, runs):
    return jnp.asarray(engine.run_keys(base_seed, np.arange(runs)))


#: One set-up for the two tests of whole runs (so they share two compiled programs): 16 steps,
#: the IMM, the fault model compiled in (its rates are Params: 0 unless a test draws faults).
CFG = Config(n_steps=16, filters=("imm",), warmup_steps=4, faults="on")


def _one_smooth_run(params, key, temperatures):
    """One run of the smooth system: its records and their summary."""
    r = engine.run_records(SCENARIO, CFG, params, key, temperatures)
    return r, SCENARIO.reduce(CFG, r, params)


_smooth_runs = jax.jit(jax.vmap(_one_smooth_run, in_axes=(0, 0, None)))


def _runs(params, keys, temperatures):
    """(exact outputs, smooth records, smooth outputs) of 3 runs of :data:`CFG`."""
    return (engine.compiled(SCENARIO, CFG)(params, keys), *_smooth_runs(params, keys, temperatures))


def test_the_tuned_params_have_a_smooth_path_and_the_mode_jumps_do_not():
    names = smooth_params(SCENARIO, Config())
    assert {"sigma_accel", "model_turn_rate_error", "comm_radius", "sensing_radius"} <= set(names)
    assert not {"ct_start", "ct_stop", "link_loss", "sensor_dropout"} & set(names)


def test_loss_gradient_matches_central_differences_at_three_random_points():
    """d(mean training loss over 3 runs of 8 steps)/d(Params), forward mode as mcjax tune does,
    against central differences, for the two tuned Params (sigma_accel, model_turn_rate_error)
    and the two radii whose only path is the temperatures (the soft gate and links).

    The step h: a scan over h/scale = 1e-2 … 1e-6 (scale = the value; 0.02 rad/s for the turn
    rate error) at these points, with runs of 10 steps (2026-12-03), gave relative differences falling as h² down to
    ≤ 3e-6 at 1e-4 (the radii's curvature is set by the 10 m temperature: h = 0.04 m there), then
    rising again as rounding takes over (up to 1e-5 at 1e-6 for a small sigma_accel). So
    h/scale = 1e-4, in the middle of the plateau, and 1e-4 relative is asked for."""
    cfg = Config(n_steps=8, filters=("imm",), warmup_steps=2)
    base = jax.tree.map(jnp.asarray, SCENARIO.default_params(cfg)._replace(**GATED))
    loss = Loss("imm", 100.0, 1.0, 20.0, 2.0, 100.0, 2)
    keys = _keys(1, 3)
    names = ("sigma_accel", "model_turn_rate_error", "sensing_radius", "comm_radius")

    def f(x):
        p = base._replace(**{n: x[i] for i, n in enumerate(names)})
        one = lambda k: run_loss(SCENARIO, cfg, loss, Temperatures(), cfg.n_steps, p, k, 0, False)[0]  # noqa: E731
        return jnp.mean(jax.vmap(one)(keys))

    def value_twice(x):  # the closed loop traced once: its value is both the output and the aux
        v = f(x)
        return v, v

    both = jax.jit(jax.jacfwd(value_twice, has_aux=True))  # (gradient, value): one program
    value = lambda x: both(x)[1]  # noqa: E731
    rng = np.random.default_rng(2017)
    for _ in range(3):  # inside the tune spec's bounds; radii around the gated set-up
        x = np.array([np.exp(rng.uniform(np.log(0.005), np.log(0.5))), rng.uniform(-0.02, 0.02),
                      rng.uniform(420.0, 480.0), rng.uniform(400.0, 440.0)])
        ad = np.asarray(both(jnp.asarray(x))[0])
        assert np.all(ad != 0.0)  # every Param acts on the loss, the radii through the temperatures
        for i in range(len(names)):
            h = 1e-4 * (0.02 if names[i] == "model_turn_rate_error" else abs(x[i]))
            e = np.zeros(len(names))
            e[i] = h
            fd = (float(value(jnp.asarray(x + e))) - float(value(jnp.asarray(x - e)))) / (2 * h)
            assert abs(fd - ad[i]) <= 1e-4 * abs(ad[i]), (names[i], x, fd, ad[i])


def test_smooth_system_approaches_the_exact_one_as_the_temperatures_shrink():
    """At temperatures T, T/10, T/100 (T = 100 m for the gate and links, 0.05 for the mode
    indicator) the gap between the smooth and the exact summaries shrinks at every level. Why
    it must: every soft weight differs from its 0/1 switch by sigmoid(−|margin|/T), which falls
    with T for every margin, and the filters are continuous in these weights; the UUVs do not
    move, so no margin of the links is near 0 (20 m here, and the gate's margins cross 0 only at
    isolated steps). At the smallest level the gap is below 1 % of the exact value."""
    params, keys = _batch(SCENARIO.default_params(CFG)._replace(**GATED), 3), _keys(0, 3)
    gaps = {k: [] for k in ("rmse", "mode_accuracy", "lambda2_mean")}
    for scale in (1.0, 0.1, 0.01):
        exact, _, out = _runs(params, keys, Temperatures(100.0 * scale, 100.0 * scale, 0.05 * scale))
        for k in gaps:
            gaps[k].append(float(np.max(np.abs(np.asarray(out[k]) - np.asarray(exact[k])))))
    for k, g in gaps.items():
        assert g[0] > g[1] > g[2] or g[0] > g[1] == g[2] == 0.0, (k, g)
        assert g[2] <= 0.01 * float(np.max(np.abs(np.asarray(exact[k])))), (k, g)
    assert gaps["rmse"][0] > 1e-3  # the largest temperature does change the system


def test_summary_reduces_the_smooth_record_with_the_exact_ones_finite_outputs():
    """With temperatures on, ``summary`` reduces the record (soft indicators are floats in [0, 1])
    and every output is finite exactly where the exact simulation's is, with faults drawn (lost
    links and sensor dropouts meet the soft links and gates)."""
    params = _batch(SCENARIO.default_params(CFG)._replace(**GATED, link_loss=0.3, sensor_dropout=0.2), 3)
    exact, records, smooth = _runs(params, _keys(3, 3), Temperatures())
    assert set(smooth) == set(exact)
    for k in exact:
        e, s = np.asarray(exact[k], np.float64), np.asarray(smooth[k], np.float64)
        assert s.shape == e.shape, k
        np.testing.assert_array_equal(np.isfinite(s), np.isfinite(e), err_msg=k)
    assert 0.0 <= float(jnp.min(records.mode_hit)) <= float(jnp.max(records.mode_hit)) <= 1.0
    assert float(jnp.sum(records.faults.links_lost)) > 0  # the faults did meet the soft links
    assert np.all((np.asarray(records.n_seeing) >= 0) & (np.asarray(records.n_seeing) <= CFG.n_agents))


def test_mode_hits_exact_soft_and_without_the_imm():
    """The likelier-mode indicator: exact 0/1, soft → exact as T → 0, and with no IMM (NaN
    probabilities) 0/1 exactly and NaN soft (``mode_accuracy`` is NaN either way)."""
    mu = jnp.asarray([0.1, 0.49, 0.51, 0.9, jnp.nan])
    turns = jnp.asarray([True, False, True, False, True])
    np.testing.assert_array_equal(np.asarray(mode_hits(mu, turns)), [0.0, 1.0, 1.0, 0.0, 0.0])
    soft = np.asarray(mode_hits(mu, turns, 1e-3))
    np.testing.assert_allclose(soft[:4], [0.0, 1.0, 1.0, 0.0], atol=1e-4)
    assert np.isnan(soft[4])
    p = 1.0 / (1.0 + np.exp(-(0.9 - 0.5) / 0.2))
    np.testing.assert_allclose(np.asarray(mode_hits(mu, turns, 0.2))[3], 1.0 - p, rtol=1e-14)


def _filter_inputs(n=4, seed=0):
    """One step's inputs of the consensus IMM-UKF: 4 nodes on a ring, two modes, random
    measurements of a target near the middle."""
    rng = np.random.default_rng(seed)
    sensors = jnp.asarray([[400.0, 0.0], [0.0, 400.0], [-400.0, 0.0], [0.0, -400.0]])
    x = jnp.asarray(rng.normal([0.0, 5.0, 0.0, 5.0], [10.0, 1.0, 10.0, 1.0], (n, 2, 4)))
    P = jnp.broadcast_to(jnp.diag(jnp.asarray([100.0, 1.0, 100.0, 1.0])), (n, 2, 4, 4))
    state = IMMState(jnp.full((n, 2), 0.5), x, P)
    truth = jnp.asarray([3.0, 5.0, -2.0, 5.0])
    R = jnp.diag(jnp.asarray([5.0, 1.5e-4]))
    z = jax.vmap(range_bearing, in_axes=(None, 0))(truth, sensors) + jnp.asarray(rng.normal(0, 1, (n, 2))) * jnp.sqrt(
        jnp.diag(R))
    F = jnp.stack([jnp.eye(4).at[0, 1].set(1.0).at[2, 3].set(1.0)] * 2)
    Q = jnp.stack([0.01 * jnp.eye(4)] * 2)
    transition = jnp.asarray([[0.9, 0.1], [0.1, 0.9]])
    adj = graph.adjacency(sensors, 600.0)
    return state, transition, F, Q, z, sensors, R, adj


@jax.jit
def _filter(inputs, z, gates=None, sizes=None):
    state, transition, F, Q, _, sensors, R, adj = inputs
    return consensus_imm_ukf_step(state, transition, F, Q, z, sensors, range_bearing, R, adj,
                                  steps=3, ut=Unscented(), angle_mask=jnp.array([False, True]), gates=gates,
                                  sizes=sizes)


def test_filter_gates_of_one_are_the_exact_filter_and_gates_of_zero_the_unmeasured_one():
    """The smooth inputs of the consensus IMM-UKF: every gate 1 with the exact component sizes
    is the exact filter bit for bit; a gate 0 on node 0 is node 0 without a measurement (NaN),
    to rounding — its information and its mode likelihood drop out."""
    inputs = _filter_inputs()
    n, adj, z = 4, inputs[-1], inputs[4]
    exact = _filter(inputs, z)
    ones = _filter(inputs, z, gates=jnp.ones(n), sizes=graph.component_sizes(adj))
    for a, b in zip(jax.tree.leaves(exact), jax.tree.leaves(ones)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    unmeasured = _filter(inputs, z.at[0].set(jnp.nan))
    gated = _filter(inputs, z, gates=jnp.ones(n).at[0].set(0.0), sizes=graph.component_sizes(adj))
    for a, b in zip(jax.tree.leaves(unmeasured), jax.tree.leaves(gated)):
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-12, atol=1e-12)
    changed = _filter(inputs, z, gates=jnp.ones(n).at[0].set(0.5), sizes=graph.component_sizes(adj))
    assert not np.allclose(np.asarray(changed[0].x), np.asarray(exact[0].x))


def test_soft_links_are_the_exact_links_up_to_the_sigmoid_of_their_margin():
    """Each soft link differs from its 0/1 link by sigmoid(−|margin|/T) exactly (the margins
    of the paper's hexagon computed here in numpy), and the Metropolis weights built from the
    soft links stay symmetric and doubly stochastic."""
    cfg = Config()
    p = SCENARIO.default_params(cfg)
    pos = np.asarray(p.uuv_positions)
    d = np.linalg.norm(pos[:, None] - pos[None], axis=-1)
    margin = 450.0 - d
    off = ~np.eye(6, dtype=bool)

    @jax.jit  # one small program for both temperatures (op by op costs more CPU)
    def links(T):
        soft = graph.soft_adjacency(jnp.asarray(pos), jnp.full(6, 450.0), T, jnp.ones(6, bool))
        return soft, graph.consensus_weights(soft, "metropolis")

    for T in (100.0, 10.0):
        soft, W = (np.asarray(a) for a in links(jnp.float64(T)))
        exact = (margin >= 0) & off
        np.testing.assert_allclose(np.abs(soft - exact)[off], 1.0 / (1.0 + np.exp(np.abs(margin[off]) / T)),
                                   rtol=1e-9, atol=1e-300)
        np.testing.assert_allclose(W, W.T, atol=1e-15)
        np.testing.assert_allclose(W.sum(0), 1.0, atol=1e-14)
        assert W.min() >= 0.0
