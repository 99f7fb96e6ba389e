"""The connectivity robustness R_I (Sun et al. 2011 eq. 15) on a maximum spanning tree, the O(n²)
path the leader–follower planner takes above 10 UAVs (``Config.robustness_paths``): the exact
value bit for bit equal to the all-pairs Floyd–Warshall one, the smooth surrogate within its
stated tolerance of it with gradients matching central differences, and the planning cost and
closed loop on it."""

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mcjax import engine
from mcjax.contract import FAST_COMPILE
from mcjax.scenarios.sun2011.horizon import Dynamics, Problem, horizon_cost, horizon_plan_cost
from mcjax.scenarios.sun2011.objectives import CostParams, TREE_ABOVE, resolve_paths
from mcjax.study import load_config_file
from mcjax.tracking import connectivity
from mcjax.tracking.planning import PlannerOptions, solve

# Every program of this file compiles with the scenarios' XLA options (FAST_COMPILE: XLA's older
# CPU fusion code generator, much less compile time; the engine compiles the scenarios' programs
# so) and the cheapest backend ones.
FAST = {"xla_backend_optimization_level": 0, "xla_llvm_disable_expensive_passes": True, **FAST_COMPILE}


def jit(fun):
    return jax.jit(fun, compiler_options=FAST)


exact_pairs = jit(connectivity.connectivity_robustness)
exact_tree = jit(connectivity.tree_connectivity_robustness)
smooth_tree = jit(connectivity.smooth_tree_connectivity_robustness)


def _cases(count, seed=0):
    """Random teams of 2–12 agents, per-agent ranges, some disconnected, some with agents not alive."""
    rng = np.random.default_rng(seed)
    for k in range(count):
        n = int(rng.integers(2, 13))
        pos = rng.uniform(0.0, 10.0, (n, 2))
        if k % 5 == 0:
            pos[1] = pos[0]  # coincident agents
        radius = rng.uniform(0.5, 5.0, n)
        alive = (rng.random(n) < 0.7) if k % 2 else np.ones(n, bool)
        yield pos, radius, alive


def test_tree_robustness_equals_all_pairs_bit_for_bit():
    """Exact R_I from the spanning tree == Floyd–Warshall's over every pair, with N_I = the other
    agents alive and paths through any agent (agents not alive: +inf)."""
    seen_negative = seen_dead = 0
    for pos, radius, alive in _cases(80):
        ref = np.asarray(exact_pairs(pos, radius, alive[:, None] & alive[None, :]))
        ref = np.where(alive, ref, np.inf)
        got = np.asarray(exact_tree(pos, radius, alive))
        np.testing.assert_array_equal(got, ref)
        seen_negative += np.any(np.isfinite(ref) & (ref < 0))
        seen_dead += np.any(~alive) and np.sum(alive) >= 2
    assert seen_negative > 5 and seen_dead > 5  # disconnected teams and teams with dead agents were tried


def test_tree_robustness_without_alive_is_every_agent():
    pos = np.random.default_rng(3).uniform(0, 10, (9, 2))
    np.testing.assert_array_equal(np.asarray(exact_tree(pos, 3.0)), np.asarray(exact_pairs(pos, 3.0)))


def test_smooth_tree_robustness_within_its_bound_below_the_exact_value():
    """½ softmin_T over the tree's links: in [R − ½ T log(n − 1), R], and → R as T → 0."""
    for T in (0.05, 0.5):
        for pos, radius, alive in _cases(60, seed=1):
            n = len(pos)
            ref = np.asarray(exact_tree(pos, radius, alive))
            got = np.asarray(smooth_tree(pos, radius, T, alive))
            np.testing.assert_array_equal(np.isfinite(got), np.isfinite(ref))
            fin = np.isfinite(ref)
            assert np.all(got[fin] <= ref[fin] + 1e-12)
            assert np.all(got[fin] >= ref[fin] - 0.5 * T * np.log(max(n - 1, 1)) - 1e-12)


def test_smooth_tree_robustness_gradient_matches_central_differences():
    rng = np.random.default_rng(4)
    pos = rng.uniform(0, 10, (8, 2))
    alive = np.array([1, 1, 0, 1, 1, 1, 0, 1], bool)
    radius = rng.uniform(2.0, 4.0, 8)

    def f(p):
        r = connectivity.smooth_tree_connectivity_robustness(p, radius, 0.5, alive)
        return jnp.sum(jnp.where(jnp.asarray(alive), r, 0.0) * jnp.arange(1.0, 9.0))

    h = 1e-6
    steps = h * np.eye(16).reshape(16, 8, 2)  # step e_(i, d) = h in entry (i, d), (i, d) row-major
    # one jitted program: the gradient at pos, and f at pos ± every step (32 eager calls of f
    # cost most of the test's time)
    g, up, down = jit(lambda p, e: (jax.grad(f)(p), jax.vmap(f)(p + e), jax.vmap(f)(p - e)))(
        jnp.asarray(pos), jnp.asarray(steps))
    g, up, down = np.asarray(g), np.asarray(up), np.asarray(down)
    assert np.all(np.isfinite(g)) and np.any(g != 0)
    for i in range(8):
        for d in range(2):
            fd = (float(up[2 * i + d]) - float(down[2 * i + d])) / (2 * h)
            assert abs(fd - g[i, d]) <= 1e-5 * max(1.0, abs(fd)), (i, d, fd, g[i, d])


def test_smooth_tree_gradient_finite_for_coincident_agents_and_lone_agent():
    pos = jnp.asarray([[0.0, 0.0], [0.0, 0.0], [3.0, 1.0]])
    # one jitted program (eager, the tree's many small operations cost most of the test's time)
    g, alone = jit(lambda p: (
        jax.grad(lambda q: jnp.sum(connectivity.smooth_tree_connectivity_robustness(q, 2.0, 0.3)))(p),
        connectivity.smooth_tree_connectivity_robustness(p, 2.0, 0.3, np.array([True, False, False]))))(pos)
    assert np.all(np.isfinite(np.asarray(g)))
    assert np.all(np.isinf(np.asarray(alone)))


def test_auto_takes_the_tree_only_above_ten_agents():
    assert TREE_ABOVE == 10
    assert resolve_paths("auto", 5) == resolve_paths("auto", 10) == "all_pairs"
    assert resolve_paths("auto", 11) == "spanning_tree"
    assert resolve_paths("all_pairs", 50) == "all_pairs" and resolve_paths("spanning_tree", 3) == "spanning_tree"
    with pytest.raises(ValueError, match="robustness_paths"):
        resolve_paths("tree", 5)


def _team(n, seed):
    rng = np.random.default_rng(seed)
    xy = np.stack([rng.uniform(20e3, 180e3, n), rng.uniform(60e3, 240e3, n)], -1)
    uavs = np.concatenate([xy, np.full((n, 1), 800.0), rng.uniform(-1, 1, (n, 1))], -1)
    Y = np.diag(1.0 / np.array([100.0, 10.0, 100.0, 10.0]) ** 2)
    problem = Problem(jnp.asarray(uavs), jnp.asarray([200e3, 200.0, 180e3, -1000.0]), jnp.asarray(Y))
    cost = CostParams(*(jnp.asarray(v, jnp.float64) for v in (
        1000.0, 1.0, 1e-4, 1e4, 1e3, 20e3, 5e3, 1e3, np.full(n, 120e3), np.full(n, 60e3), 10.0, 0.017,
        np.ones(n))))
    return problem, cost, jnp.asarray(rng.uniform(-1, 1, (5, n)))


def test_exact_planning_cost_is_the_same_on_both_paths():
    """The exact horizon cost (what every planner reports and keeps plans by) is the same to rounding."""
    dyn = Dynamics(1.0, 1.0, np.deg2rad(10.0), 5, 50.0)

    # one program per team size, both paths in it (the teams are arguments, not constants:
    # the two teams of twelve share it)
    @jit
    def both(problem, cost, v):
        return (horizon_cost(problem, v, dyn, cost, paths="all_pairs"),
                horizon_cost(problem, v, dyn, cost, paths="spanning_tree"))

    for n, seed in ((12, 0), (12, 1), (16, 2)):
        problem, cost, u = _team(n, seed)
        a, b = both(problem, cost, u)
        # R_I is bit-identical (above); the sums around it may round differently (XLA fuses them
        # in another order): one or two ulps
        np.testing.assert_allclose(float(b), float(a), rtol=1e-14)


def test_planner_on_the_tree_improves_on_its_warm_start():
    dyn = Dynamics(1.0, 1.0, np.deg2rad(10.0), 5, 50.0)
    problem, cost, _ = _team(12, 5)
    warm = jnp.zeros((5, 12))
    pc = horizon_plan_cost(problem, dyn, cost, penalty="barrier", paths="spanning_tree")

    @jit  # one program: the plan, the warm start's exact cost and the plan's on all pairs (eager is slow)
    def go(w):
        plan = solve(pc, w, jax.random.key(0), PlannerOptions("gradient", 10))
        return plan, pc.exact(w), horizon_cost(problem, plan.u, dyn, cost, paths="all_pairs")

    plan, at_warm, all_pairs = go(warm)
    assert np.isfinite(float(plan.cost)) and float(plan.cost) < float(at_warm)
    np.testing.assert_allclose(float(plan.cost), float(all_pairs), rtol=1e-14)


def test_closed_loop_of_twelve_uavs_runs_on_the_tree():
    """Twelve UAVs ("auto": the tree): the plans are finite, and the recorded R_I is the all-pairs
    Floyd–Warshall value of the recorded positions, bit for bit."""
    sc, base, values = load_config_file(Path(__file__).resolve().parents[2] / "configs" / "sun2011.toml")
    values = {k: v for k, v in values.items() if k not in ("initial_positions", "alive")}
    cfg = dataclasses.replace(base, filters=("modified_icf",), n_steps=4, warmup_steps=1, n_agents=12)
    assert cfg.robustness_paths == "auto"
    points = engine.stack_points([sc.default_params(cfg, **values)])
    [(_, _, _, rec)] = list(engine.run_chunks(sc, cfg, points, 2, chunk_size=2, records=True))
    assert np.all(np.isfinite(rec.plan_cost)) and np.all(np.isfinite(rec.positions))
    ref = np.asarray(jit(jax.vmap(jax.vmap(lambda p: connectivity.connectivity_robustness(p, 100e3))))(rec.positions))
    np.testing.assert_array_equal(rec.robustness, ref)
