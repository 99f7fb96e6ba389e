"""The closed loop of Sun et al. 2011 §4 in the leader–follower scenario: one program for a batch of
mixed horizons and weights, plan cadence τ_r, limits respected, validation."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mcjax import engine
from mcjax.contract import FAST_COMPILE
from mcjax.scenarios import sun2011 as lf

# One filter (the leader's): a smaller program. The paper's config in closed loop, with its Table 1
# claims, runs in benchmarks/claims/sun2011.toml (mcjax check; 1,000 runs per case).
CFG = lf.Config(planner="gradient", filters=("modified_icf",), n_steps=24, warmup_steps=4,
                plan_iterations=3)


def jit(fun, **kw):
    """``jax.jit`` with the scenarios' XLA options (:data:`mcjax.contract.FAST_COMPILE`: XLA's older
    CPU fusion code generator, which compiles with much less CPU time; the engine compiles the
    scenarios' programs so). What these tests check does not depend on the code generator."""
    return jax.jit(fun, compiler_options=dict(FAST_COMPILE), **kw)


def batch(cfg, points, seeds):
    params = engine.stack_points([lf.default_params(cfg, **p) for p in points])
    keys = jax.vmap(lambda s: engine.run_key(0, s))(jnp.asarray(seeds, jnp.uint32))
    return params, keys


@pytest.fixture(scope="module")
def mixed():
    fn = engine.compiled(lf.SCENARIO, CFG, records=True)
    mixed_points = [dict(horizon=3, replan_every=3, alpha_I=0.0),
                    dict(horizon=5, replan_every=3, alpha_I=1000.0),
                    dict(horizon=8, replan_every=2, alpha_I=300.0)]
    a = fn(*batch(CFG, mixed_points, [0, 1, 2]))
    b = fn(*batch(CFG, [mixed_points[1]] * 3, [5, 1, 7]))
    return fn, jax.tree.map(np.asarray, a), jax.tree.map(np.asarray, b)


@pytest.mark.xdist_group("test_closed_loop")  # one worker builds the module fixture once
def test_mixed_horizons_share_one_program(mixed):
    fn, a, b = mixed
    assert fn._cache_size() == 1  # t_r = 3, 5, 8 and three α_I in one compiled program
    # the t_r = 5 run (lane 1, seed 1) is the same inside the mixed batch and among its equals
    for name in ("positions", "error", "plan_cost", "lambda2"):
        np.testing.assert_array_equal(getattr(a, name)[1], getattr(b, name)[1])
    # and the runs really differ with the horizon / weights
    assert not np.array_equal(a.positions[0], a.positions[1])


@pytest.mark.xdist_group("test_closed_loop")  # one worker builds the module fixture once
def test_replans_every_tau_r_and_respects_the_turn_rate(mixed):
    _, a, _ = mixed
    # the plan in force changes exactly at steps 0, τ_r, 2τ_r, ... (its exact cost is recorded)
    for lane, tau in ((0, 3), (2, 2)):
        changes = np.flatnonzero(np.diff(a.plan_cost[lane]) != 0) + 1
        assert set(changes) <= set(range(0, CFG.n_steps, tau)) and len(changes) >= CFG.n_steps // tau - 2
    # headings never turn faster than the eq. 4 limit (10°/s): the chord direction changes by
    # at most the turn over two consecutive 1-s steps
    d = np.diff(a.positions, axis=1)
    ang = np.arctan2(d[..., 1], d[..., 0])
    turn = np.abs(np.angle(np.exp(1j * np.diff(ang, axis=1))))
    assert np.all(turn <= np.deg2rad(10.0) + 1e-9)
    assert np.all(np.isfinite(a.error)) and np.all(np.isfinite(a.plan_cost))


def test_a_sampled_planner_closes_the_loop():
    """Random shooting in the loop (the loop calls every kind through one ``solve``; the kinds
    themselves are tested in test_planning)."""
    cfg = lf.Config(planner="random", filters=("modified_icf",), n_steps=12, warmup_steps=2,
                    plan_iterations=2, plan_samples=16)
    out = engine.compiled(lf.SCENARIO, cfg)(*batch(cfg, [{}] * 2, [0, 1]))
    assert np.all(np.isfinite(np.asarray(out["plan_cost_mean"])))
    assert np.all(np.asarray(out["plan_cost_mean"]) > 0)


def test_config_and_param_validation():
    with pytest.raises(ValueError, match="filters must include 'modified_icf'"):
        lf.Config(planner="gradient", filters=("cif",))
    with pytest.raises(ValueError, match="planner must be one of none, gradient, random, cem"):
        lf.Config(planner="mpc")
    cfg = lf.Config(max_horizon=6)
    assert lf.check_params(cfg, {"horizon": 8}) == [("horizon", "an integer in [1, max_horizon = 6]")]
    assert lf.check_params(cfg, {"horizon": 4, "replan_every": 5}) == [("replan_every", "an integer in [1, horizon]")]
    assert lf.check_params(cfg, {"horizon": [3, 5], "replan_every": 3}) == []


@pytest.mark.xdist_group("test_closed_loop")  # one worker builds the module fixture once
def test_fixed_plan_period_plans_only_when_due_and_gives_the_same_bits(mixed):
    """``plan_period = τ_r``: the planner sits in a ``lax.cond`` on the step alone, skipped on
    the other steps — the same records as the every-step program with ``replan_every = τ_r``
    (a t_r = 5, τ_r = 3 batch), and a replan_every that differs from it is rejected."""
    _, a, b = mixed
    cfg = lf.Config(**{**{k: getattr(CFG, k) for k in CFG.SETTINGS}, "plan_period": 3})
    fast = engine.compiled(lf.SCENARIO, cfg, records=True)
    inputs = batch(cfg, [dict(horizon=5, replan_every=3, alpha_I=1000.0)] * 3, [5, 1, 7])
    # the program's own trace (the call below reuses it: make_jaxpr would trace the loop again)
    jaxpr = str(fast.trace(*inputs).jaxpr)
    assert "cond[" in jaxpr  # a real branch, not a select over both sides
    c = jax.tree.map(np.asarray, fast(*inputs))
    for name in ("positions", "error", "plan_cost", "lambda2"):
        np.testing.assert_array_equal(getattr(c, name), getattr(b, name), err_msg=name)
    assert lf.check_params(cfg, {"replan_every": 2}) == [
        ("replan_every", "equal to config.plan_period = 3 (set plan_period = 0 to vary it)")]
    assert lf.check_params(cfg, {"replan_every": 3}) == []


@pytest.mark.xdist_group("test_closed_loop")
def test_float32_planner_flies_the_float64_plans_and_keeps_the_filters_positive_definite(mixed):
    """``plan_dtype = "float32"``: the leader's problem is solved in float32, in coordinates
    relative to its target estimate, and everything else stays float64. Against the float64
    planner (the module's batch ``b``, same seeds): the UAVs fly the same paths to a metre
    (the plans agree to float32 rounding), and the leader's information matrix — the filter
    state the planner reads — is symmetric positive definite at every step (checked by its
    eigenvalues, not assumed)."""
    _, _, b = mixed
    cfg = dataclasses.replace(CFG, plan_dtype="float32")
    params, keys = batch(cfg, [dict(horizon=5, replan_every=3, alpha_I=1000.0)] * 3, [5, 1, 7])
    k = cfg.filters.index("modified_icf")

    def run(p, key):
        state = lf.init(cfg, p, key)

        def body(s, t):
            s, rec = lf.step(cfg, p, s, jax.random.fold_in(key, t))
            return s, (rec, lf.per_agent("modified_icf", s.filters[k], cfg.n_agents).Y)

        return jax.lax.scan(body, state, jnp.arange(cfg.n_steps))[1]

    recs, Y = jit(jax.vmap(run))(params, keys)
    assert np.asarray(recs.plan_cost).dtype == np.float64
    assert np.all(np.isfinite(np.asarray(recs.plan_cost)))
    gap = np.abs(np.asarray(recs.positions) - b.positions)
    assert np.max(gap) < 1.0, np.max(gap)  # metres
    Y = np.asarray(Y)
    np.testing.assert_allclose(Y, np.swapaxes(Y, -1, -2), rtol=1e-9, atol=0)
    assert np.all(np.linalg.eigvalsh(Y)[..., 0] > 0.0)
