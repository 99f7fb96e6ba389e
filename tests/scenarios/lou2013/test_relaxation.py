"""The relaxation switch of Lou, Cui & Li 2013's flock (``flocking``, mcjax/scenarios/lou2013/relaxation.py).

Small sizes, float64. Three compiled programs of the flock (besides small ones of its pieces):
the tune loss and its forward-mode gradient on 6 nodes x 8 steps x 3 runs (vmapped over the
test's points); the exact and the smooth simulation (temperatures traced, so one program serves
every level) of 10 nodes x 40 steps x 4 runs.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mcjax import engine, tune
from mcjax.scenarios import lou2013 as fl
from mcjax.scenarios.lou2013 import dynamics as dyn
from mcjax.tracking import graph
from mcjax.tune.spec import Bound, Loss

jax.config.update("jax_enable_x64", True)

TUNED = ("c1", "c2", "k")
#: The bounds of sweeps/tune_lou2013.toml (log scale), from which the test points are drawn.
LOW, HIGH = np.array([0.05, 0.1, 0.01]), np.array([20.0, 40.0, 1.0])


# ------------------------------------------------------------------ the pieces, against independent references

def test_faded_potential_is_eq12_inside_zero_beyond_R_and_its_slope_is_its_derivative():
    R, w = 8.4, 0.05
    r = jnp.linspace(0.5, 9.0, 341)

    @jax.jit  # one small program (op by op, each operation compiles on its own: more CPU)
    def pieces(r):
        return (dyn.faded_potential(r, R, w), dyn.faded_potential_slope(r, R, w), dyn.potential(r, R),
                dyn.potential_slope(r, R), jax.vmap(jax.grad(lambda x: dyn.faded_potential(x, R, w)))(r))

    delta = np.array([1e-3, 1e-4])  # for the check at R below: the same program, two more points
    out = [np.asarray(a) for a in pieces(jnp.concatenate([r, R - delta]))]
    psi_w, slope, psi, psi_slope, auto = (a[:341] for a in out)
    near_psi, near_slope = out[0][341:], out[1][341:]
    far = np.asarray(R - r > 2.5 * w)
    np.testing.assert_array_equal(psi_w[far], psi[far])
    np.testing.assert_array_equal(slope[far], psi_slope[far])
    assert np.all(psi_w[np.asarray(r >= R)] == 0.0)
    # the slope is the derivative (autodiff of the value), and both tend to 0 at R from inside (C1 there)
    np.testing.assert_allclose(slope, auto, rtol=1e-10, atol=1e-10)
    # at R: ψ_w ≈ R² δ³ / w⁴ and ψ_w′ ≈ −3 R² δ² / w⁴ at δ = R − r → 0 (twice differentiable, 0 beyond)
    np.testing.assert_allclose(near_psi, R**2 * delta**3 / w**4, rtol=1e-3)
    np.testing.assert_allclose(near_slope, -3 * R**2 * delta**2 / w**4, rtol=1e-3)


def test_soft_forces_are_minus_the_gradient_of_the_weighted_faded_potential():
    rng = np.random.default_rng(3)
    q = jnp.asarray(rng.uniform(0, 9, (7, 2)))
    a = rng.uniform(0, 1, (7, 7))
    a = jnp.asarray(np.triu(a, 1) + np.triu(a, 1).T)
    R, w = 8.4, 0.3

    def potential(q):
        d = q[:, None, :] - q[None, :, :]
        r = jnp.sqrt(jnp.sum(d * d, -1) + jnp.eye(7))
        return 0.5 * jnp.sum(a * dyn.faded_potential(r, R, w))

    # one small program (op by op, each operation compiles on its own: more CPU)
    forces, grad = jax.jit(lambda q: (dyn.potential_forces(q, a, R, w), jax.grad(potential)(q)))(q)
    np.testing.assert_allclose(np.asarray(forces), -np.asarray(grad), rtol=1e-9, atol=1e-9)


def test_soft_hysteresis_tends_to_the_exact_rule_and_counts_to_the_exact_counts():
    rng = np.random.default_rng(5)
    q = jnp.asarray(rng.uniform(0, 12, (12, 2)))
    prev = (rng.uniform(size=(12, 12)) < 0.5).astype(float)
    prev = jnp.asarray(np.triu(prev, 1) + np.triu(prev, 1).T)
    exact = graph.hysteresis_adjacency(prev, q, 8.4, 0.4)
    d = np.asarray(graph.pairwise_distances(q))
    gap = np.min(np.abs(np.stack([d - 8.4, d - 8.0]))[:, ~np.eye(12, dtype=bool)])  # distance to a threshold
    errs = [float(jnp.max(jnp.abs(fl.soft_hysteresis(prev, q, 8.4, 0.4, T) - exact))) for T in (0.5, 0.1, 0.02)]
    assert errs[0] > errs[1] > errs[2]
    assert errs[2] <= 1.0 / (1.0 + np.exp(gap / 0.02)) * (1 + 1e-9)  # the sigmoid's tail at the nearest threshold
    soft = fl.soft_hysteresis(prev, q, 8.4, 0.4, 1e-4)
    added, removed = fl.soft_link_changes(prev, soft)
    assert round(float(added)) == int(np.sum((np.asarray(exact) > 0.5) & (np.asarray(prev) < 0.5)) // 2)
    assert round(float(removed)) == int(np.sum((np.asarray(exact) < 0.5) & (np.asarray(prev) > 0.5)) // 2)


def test_rough_params_are_refused_and_the_gains_can_be_differentiated():
    from mcjax.contract.relaxation import problem, smooth_params

    cfg = fl.Config()
    names = smooth_params(fl.SCENARIO, cfg)
    assert set(TUNED) <= set(names) and "R" in names
    for rough in ("substep_safety", "start_margin", "link_loss"):
        assert rough not in names and "no smooth path" in problem(fl.SCENARIO, cfg, rough)
    assert "n_sensing" not in names


# ------------------------------------------------------------------ (a) the tune loss's gradient

#: 6 nodes (3 sense), 8 steps of 0.1 s, the KCF, 3 runs of training seed base 1. The temperatures
#: are larger than the defaults (0.5 m, as ε = 0.4 m) so that the 6-node start's links are not
#: saturated and the loss moves with the gains by more than rounding; the derivative's
#: correctness does not depend on the temperature.
#: The integrator's tolerance 1e-9 m (the config's: 1e-6): forward mode differentiates the sub-steps
#: taken, not how their sizes move with the Params, which moves the loss by O(tolerance): at 1e-6
#: the central differences of k differed by 1.6e-4 of the derivative (2026-12-03).
GRAD_CFG = fl.Config(n_agents=6, n_steps=8, filters=("kcf",), warmup_steps=0, divergence_threshold=5.0,
                     dtype="float64", tolerance=1e-9)
GRAD_SMOOTHING = fl.Temperatures(links=0.5, barrier=0.5)


@pytest.fixture(scope="module")
def loss_and_grad():
    base = fl.default_params(GRAD_CFG)._replace(n_sensing=3.0)
    loss = Loss("kcf", 5.0, 1.0, 1.0, 0.1, 5.0, 0)
    bounds = [Bound(n, 0.0, 1.0, "linear", 0.0) for n in TUNED]
    keys = jax.vmap(lambda i: engine.run_key(1, i))(jnp.arange(3, dtype=jnp.uint32))  # tune.train_keys's

    def mean_loss(x):  # as mcjax/tune/loss.py: run_loss per run with the tuned Params set to x
        p = tune.params_at(bounds, base, x)
        value = jnp.mean(jax.vmap(lambda k: tune.run_loss(fl.SCENARIO, GRAD_CFG, loss, GRAD_SMOOTHING, 8, p, k,
                                                          0, False)[0])(keys))
        return value, value

    # vmapped over points: the test evaluates its 3 points and their 18 shifted copies in one call.
    # Running costs here as much as compiling (the integrator's sub-steps at tolerance 1e-9): one
    # point a call took ~1 s of CPU, 21 calls ~20 s; the 21 points in one call ~17 s (2026-12-03)
    f = jax.jit(jax.vmap(jax.jacfwd(mean_loss, has_aux=True)), compiler_options=engine.compiler_options(fl.SCENARIO))
    return lambda xs: tuple(np.asarray(v) for v in f(jnp.asarray(xs, jnp.float64)))


def test_tune_loss_gradient_matches_central_differences_at_three_random_points(loss_and_grad):
    """Forward mode (jax.jacfwd, as the tune) against central differences with the relative
    step h = 1e-3 x. A scan over h = 1e-2 … 1e-6 at these points (2026-12-03) gave relative
    differences up to 3.3e-4 at 1e-2 (the quotient's O(h²) error), ≤ 1.5e-6 at 1e-3 and up to
    7e-4 at 1e-6 (rounding: the loss is ~0.02 and its derivatives ~1e-7), so 1e-3 sits between
    the two errors, with both far below the 1e-4 asked."""
    rng = np.random.default_rng(2013)
    points = np.exp(rng.uniform(np.log(LOW), np.log(HIGH), (3, 3)))
    steps = [np.diag(1e-3 * x) for x in points]  # row i: h in the i-th gain
    # every point, then its copies x + h_i and x − h_i, evaluated in one call
    grads, values = loss_and_grad(np.concatenate([points] + [x + h for x, h in zip(points, steps)]
                                                 + [x - h for x, h in zip(points, steps)]))
    for p, x in enumerate(points):
        g, value = grads[p], values[p]
        assert np.isfinite(value) and np.all(np.abs(g) > 1e-9), (x, g)  # the gains move the loss
        for i in range(3):
            plus, minus = values[3 + 3 * p + i], values[12 + 3 * p + i]
            fd = (plus - minus) / (2 * steps[p][i, i])
            assert abs(fd - g[i]) <= 1e-4 * abs(g[i]), (TUNED[i], x, g[i], fd)


# ------------------------------------------------------------------ (b), (c) the smooth system against the exact one

SIM_CFG = fl.Config(n_agents=10, n_steps=40, filters=("kcf", "local"), warmup_steps=5, divergence_threshold=5.0,
                    dtype="float64")
LEVELS = (1.0, 0.5, 0.25)       # m, links and barrier alike; then the defaults (2 cm)


@pytest.fixture(scope="module")
def simulated():
    p = fl.default_params(SIM_CFG)
    P = jax.tree.map(lambda a: jnp.broadcast_to(jnp.asarray(a), (4,) + jnp.shape(a)), p)
    keys = jax.vmap(lambda i: engine.run_key(7, i))(jnp.arange(4, dtype=jnp.uint32))
    opts = engine.compiler_options(fl.SCENARIO)
    exact = jax.jit(lambda: engine.simulate(fl.SCENARIO, SIM_CFG, P, keys), compiler_options=opts)()
    smooth = jax.jit(lambda s: engine.simulate(fl.SCENARIO, SIM_CFG, P, keys, temperatures=s), compiler_options=opts)
    levels = {T: smooth(fl.Temperatures(jnp.float64(T), jnp.float64(T))) for T in LEVELS}
    levels["default"] = smooth(jax.tree.map(jnp.float64, fl.Temperatures()))
    return jax.tree.map(np.asarray, exact), {T: jax.tree.map(np.asarray, o) for T, o in levels.items()}


def test_smooth_errors_approach_the_exact_ones_as_the_temperatures_shrink(simulated):
    """The KCF's estimates depend on the flock only through the type-I nodes' links (the
    measurement does not depend on a node's position), and a soft link differs from the exact
    one by a sigmoid's tail ``exp(−m/T)`` at its distance m to its threshold: halving T squares
    that tail, so the gap in the error summary must shrink by a large factor at each level
    (measured 2026-12-03: 3e-5, 4e-7, 7e-10 m), and at the default 2 cm the two agree to
    rounding. The local filter reads no link: equal at every level."""
    exact, levels = simulated
    gaps = [np.max(np.abs(levels[T]["rmse"][:, 0] - exact["rmse"][:, 0])) for T in LEVELS]
    assert gaps[0] > 1e-7  # at 1 m the soft links do change the KCF
    assert gaps[1] < 0.1 * gaps[0] and gaps[2] < 0.1 * gaps[1]
    np.testing.assert_allclose(levels["default"]["rmse"], exact["rmse"], rtol=1e-12)
    for T in LEVELS:
        np.testing.assert_allclose(levels[T]["rmse"][:, 1], exact["rmse"][:, 1], rtol=1e-12)
    # the links and the flock's energy (eq. 15) approach too
    edges = [np.max(np.abs(levels[T]["final_edges"] - exact["final_edges"])) for T in LEVELS]
    assert edges[0] > edges[1] > edges[2] and edges[2] < 1e-6
    np.testing.assert_allclose(levels["default"]["final_edges"], exact["final_edges"], rtol=1e-12)
    np.testing.assert_allclose(levels["default"]["energy_end"], exact["energy_end"], rtol=1e-9)


def test_smooth_summary_is_complete_and_finite_where_the_exact_one_is(simulated):
    exact, levels = simulated
    for T, out in levels.items():
        assert set(out) == set(exact)
        for name, value in exact.items():
            assert out[name].shape == value.shape, name
            assert np.all(np.isfinite(out[name].astype(float))[np.isfinite(value.astype(float))]), (T, name)


def test_smooth_record_has_the_exact_records_structure_with_faults_and_late_messages():
    """Traced only (no compilation): with the fault model on and the KCF's messages one step
    late, the smooth step returns a record of the exact one's structure and shapes."""
    cfg = fl.Config(n_agents=5, n_steps=3, warmup_steps=0, filters=("kcf", "local"), faults="on", message_delay=1,
                    dtype="float64")
    p = fl.default_params(cfg)._replace(link_loss=0.3)
    key = engine.run_key(0, 0)
    state = jax.eval_shape(lambda: fl.init(cfg, p, engine.init_key(key)))
    shapes = [jax.eval_shape(lambda s, temperatures=sm: fl.step(cfg, p, s, key, temperatures), state)
              for sm in (None, fl.Temperatures())]
    assert jax.tree.structure(shapes[0]) == jax.tree.structure(shapes[1])
    assert [a.shape for a in jax.tree.leaves(shapes[0])] == [a.shape for a in jax.tree.leaves(shapes[1])]
