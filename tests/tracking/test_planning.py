"""Planning: the receding-horizon cost of Sun et al. 2011 §4 against independent forms,
rollout invariants, t_r masking, finite gradients in degenerate geometry; and the planners,
generic over a cost — on that cost and on simple costs with known minimisers,
including the grid kind."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mcjax.contract import FAST_COMPILE
from mcjax.tracking import graph
from mcjax.tracking.models.sensors import range_bearing
from mcjax.tracking.planning import PlanCost, PlannerOptions, solve
from mcjax.scenarios.sun2011.horizon import (
    Dynamics, Problem, horizon_cost, horizon_plan_cost, horizon_terms, rollout, shift_plan,
)
from mcjax.scenarios.sun2011.objectives import (
    CostParams, a_optimality, information_after_prediction, position_information, robustness_penalty,
)

N = 5
LAYOUT = np.array([[20, 150], [80, 150], [130, 200], [130, 100], [180, 150]]) * 1e3
TARGET = np.array([200e3, 200.0, 180e3, -1000.0])
DYN = Dynamics(1.0, 1.0, np.deg2rad(10.0), 5, 50.0)


def jit(fun, **kw):
    """``jax.jit`` with the scenarios' XLA options (:data:`mcjax.contract.FAST_COMPILE`: XLA's older
    CPU fusion code generator, which compiles with much less CPU time; the engine compiles the
    scenarios' programs so). What these tests check does not depend on the code generator."""
    return jax.jit(fun, compiler_options=dict(FAST_COMPILE), **kw)


def cost_params(n=N, **kw):
    values = dict(alpha_I=1000.0, alpha_C=1.0, alpha_L=1e-4, alpha_S=1e4, d_safe=1e3, d_lt=20e3,
                  robustness_scale=5e3, temperature=1e3, sensing_radius=np.full(n, 120e3),
                  comm_radius=np.full(n, 100e3), sigma_range=10.0, sigma_bearing=0.017, alive=np.ones(n))
    values.update(kw)
    return CostParams(**{k: jnp.asarray(v, jnp.float64) for k, v in values.items()})


def problem(xy=LAYOUT, headings=0.0, target=TARGET, pos_sd=100.0, vel_sd=10.0):
    xy = np.asarray(xy, float)
    uavs = np.concatenate([xy, np.full((len(xy), 1), 800.0), np.broadcast_to(headings, (len(xy),))[:, None]], -1)
    Y = np.diag(1.0 / np.array([pos_sd, vel_sd, pos_sd, vel_sd]) ** 2)
    return Problem(jnp.asarray(uavs), jnp.asarray(target, float), jnp.asarray(Y))


def test_position_information_is_jacobian_form():
    """I = Hᵀ R⁻¹ H (Sun et al. 2011, eq. 10) with H the Jacobian of the range–bearing model."""
    rng = np.random.default_rng(0)
    sensors = rng.uniform(-50e3, 50e3, (6, 2))
    x = np.array([3e3, 100.0, -7e3, 5.0])
    R_inv = np.diag([1 / 10.0**2, 1 / 0.017**2])
    got = position_information(jnp.asarray(sensors), jnp.asarray(x[[0, 2]]), 10.0, 0.017)
    jacobian = jit(jax.jacfwd(range_bearing))  # compiled once for the six sensors
    for s, I in zip(sensors, np.asarray(got)):
        H = np.asarray(jacobian(jnp.asarray(x), jnp.asarray(s)))[:, [0, 2]]
        np.testing.assert_allclose(I, H.T @ R_inv @ H, rtol=1e-6)  # ε = 1 m in r: 1e-10 relative


def test_a_optimality_is_trace_of_inverse():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(4, 4))
    Y = A @ A.T + 4 * np.eye(4)
    blocks = rng.normal(size=(3, 2, 2))
    blocks = blocks @ np.swapaxes(blocks, -1, -2)
    gates = np.array([1.0, 0.0, 0.5])
    total = Y.copy()
    total[np.ix_([0, 2], [0, 2])] += np.einsum("i,ijk->jk", gates, blocks)
    tr, P = a_optimality(jnp.asarray(Y), jnp.asarray(blocks), jnp.asarray(gates))
    np.testing.assert_allclose(float(tr), np.trace(np.linalg.inv(total)), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(P), np.linalg.inv(total), rtol=1e-10, atol=1e-14)


def test_robustness_penalties():
    R = jnp.array([-50e3, -5e3, 0.0, 5e3, 50e3])
    barrier = np.asarray(robustness_penalty(R, "barrier", 5e3, 1e3, smooth=False))
    assert np.all(np.diff(barrier) < 0)  # monotone: grows as R falls toward and below 0
    np.testing.assert_allclose(barrier[0], 10.0, rtol=1e-4)  # ≈ −R/s for a broken graph
    inverse = np.asarray(robustness_penalty(R[R != 0], "inverse", 5e3, 1e3, smooth=False))
    np.testing.assert_allclose(inverse, 1 / np.abs(np.asarray(R[R != 0])))  # the paper's 1/|R|
    smooth = np.asarray(robustness_penalty(R[R != 0], "inverse", 5e3, 1.0, smooth=True))
    np.testing.assert_allclose(smooth, inverse, rtol=1e-6)
    # no information neighbour: R = +inf costs nothing
    assert float(robustness_penalty(jnp.array(jnp.inf), "barrier", 5e3, 1e3, smooth=False)) == 0.0


def test_smooth_cost_tends_to_exact():
    prob, u = problem(), jnp.asarray(np.random.default_rng(2).uniform(-1, 1, (8, N)))
    # one jitted program for both temperatures (the temperature is data; eager horizon terms are slow)
    terms = jit(lambda cp_exact, cp_smooth, v: (
        horizon_terms(prob, v, DYN, cp_exact, penalty="barrier", smooth=False),
        horizon_terms(prob, v, DYN, cp_smooth, penalty="barrier", smooth=True)))
    for T, tol in ((100.0, 0.1), (1.0, 1e-3)):
        exact, smooth = terms(cost_params(), cost_params(temperature=T), u)
        for e, s in zip(exact, smooth):
            np.testing.assert_allclose(float(s), float(e), rtol=tol, atol=tol)


def test_rollout_straight_and_rate_limited():
    prob = problem(headings=0.3)
    poses, prev, cmds, targets = rollout(prob, jnp.zeros((8, N)), DYN)
    t = np.arange(1, 9)[:, None]
    # u = 0 holds the heading: straight lines at 800 m/s (Sun et al. 2011, eq. 3)
    np.testing.assert_allclose(poses[..., 0], LAYOUT[:, 0] + 800.0 * t * np.cos(0.3), rtol=1e-12)
    np.testing.assert_allclose(poses[..., 1], LAYOUT[:, 1] + 800.0 * t * np.sin(0.3), rtol=1e-12)
    # the target mean follows the CV model
    np.testing.assert_allclose(targets[-1], TARGET + 8 * np.array([200.0, 0, -1000.0, 0]) * [1, 0, 1, 0])
    # any plan respects the eq. 4 turn-rate limit
    u = jnp.asarray(np.random.default_rng(3).uniform(-1, 1, (8, N)))
    poses, prev, cmds, _ = rollout(prob, u, DYN)
    turn = np.abs(np.angle(np.exp(1j * (np.asarray(poses[..., 3]) - np.asarray(prev)))))
    assert np.all(turn <= np.deg2rad(10.0) + 1e-12)
    np.testing.assert_allclose(np.asarray(cmds) - np.asarray(prev), np.deg2rad(10.0) * np.asarray(u))


def test_horizon_masks_steps_beyond_t_r():
    prob = problem()
    u = jnp.asarray(np.random.default_rng(4).uniform(-1, 1, (8, N)))
    cp = cost_params()
    # one compiled program for every t_r (t_r is data, not shape): the gradient of the smooth cost
    # and the exact cost of the plan and of its tail flipped
    @jit
    def go(v, t_r):
        dyn = DYN._replace(horizon=t_r)
        g = jax.grad(lambda w: horizon_cost(prob, w, dyn, cp, smooth=True))(v)
        flipped = jnp.where((jnp.arange(v.shape[0]) >= t_r)[:, None], -v, v)
        return g, horizon_cost(prob, v, dyn, cp), horizon_cost(prob, flipped, dyn, cp)

    for t_r in (3, 5, 8):
        g, exact, exact_flipped = go(u, float(t_r))
        g = np.asarray(g)
        assert np.all(g[t_r:] == 0.0) and np.any(g[:t_r] != 0.0)
        assert float(exact_flipped) == float(exact)
    assert go._cache_size() == 1


def test_shift_plan():
    u = jnp.arange(8.0)[:, None] * jnp.ones((1, 2))
    np.testing.assert_array_equal(shift_plan(u, 3, 5)[:, 0], [3, 4, 0, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(shift_plan(u, 1, 8)[:, 0], [1, 2, 3, 4, 5, 6, 7, 0])


def degenerate_batch(n_runs=1000, seed=5):
    """Random planning problems, a quarter each with coincident UAVs, a UAV on the target,
    every UAV out of sensing range, and a graph broken into isolated UAVs."""
    rng = np.random.default_rng(seed)
    xy = LAYOUT + rng.uniform(-40e3, 40e3, (n_runs, N, 2))
    target = np.tile(TARGET, (n_runs, 1)) + rng.normal(0, 1, (n_runs, 4)) * [10e3, 50, 10e3, 50]
    q = n_runs // 4
    xy[:q, 1] = xy[:q, 0]                                   # coincident UAVs
    xy[:q, 3] = xy[:q, 2] = xy[:q, 4]                       # three on one spot
    xy[q:2 * q, 4] = target[q:2 * q][:, [0, 2]]             # a UAV on the target
    xy[2 * q:3 * q] += np.array([-1000e3, 0.0])             # nobody in sensing range
    xy[3 * q:] = np.array([[0, 0], [500e3, 0], [0, 500e3], [-500e3, 0], [0, -500e3]])  # no links
    headings = rng.uniform(-np.pi, np.pi, (n_runs, N))
    uavs = np.concatenate([xy, np.full((n_runs, N, 1), 800.0), headings[..., None]], -1)
    sd = rng.uniform(10, 500, (n_runs, 4))
    Y = np.einsum("bi,ij->bij", 1 / sd**2, np.eye(4))
    u = rng.uniform(-1, 1, (n_runs, 8, N))
    u[::7] = 0.0  # exactly straight plans too
    return Problem(jnp.asarray(uavs), jnp.asarray(target), jnp.asarray(Y)), jnp.asarray(u)


def test_horizon_cost_depends_on_relative_positions_only():
    """Moving the UAVs and the target estimate together (by up to 300 km) leaves the exact and
    the smooth horizon cost unchanged to rounding — what lets the float32 planner
    (``plan_dtype``) solve in coordinates relative to the target estimate."""
    probs, u = degenerate_batch(200, seed=11)
    off = jnp.asarray(np.random.default_rng(11).uniform(-3e5, 3e5, (200, 2)))
    moved = Problem(probs.uavs.at[..., :2].add(off[:, None]),
                    probs.target_mean.at[:, 0].add(off[:, 0]).at[:, 2].add(off[:, 1]), probs.Y)
    cp = cost_params()
    # one program: the exact and the smooth cost
    cost = jit(jax.vmap(lambda q, v: (horizon_cost(q, v, DYN, cp, smooth=False),
                                      horizon_cost(q, v, DYN, cp, smooth=True))))
    for smooth, a, b in zip((False, True), cost(probs, u), cost(moved, u)):
        a, b = np.asarray(a), np.asarray(b)
        assert np.all(np.isfinite(a))
        np.testing.assert_allclose(b, a, rtol=1e-9, err_msg=f"smooth={smooth}")


def test_gradient_finite_in_degenerate_geometry():
    """Both penalties (barrier, inverse), their gradients in one compiled program."""
    probs, u = degenerate_batch(400)
    q = 100  # runs per kind of degeneracy
    cp = cost_params()

    def grads(penalty):
        return jax.vmap(jax.grad(lambda q, v: horizon_cost(q, v, DYN, cp, penalty=penalty, smooth=True),
                                 argnums=1))
    both = jit(lambda probs, u: [grads(penalty)(probs, u) for penalty in ("barrier", "inverse")])(probs, u)
    for penalty, g in zip(("barrier", "inverse"), both):
        g = np.asarray(g)
        assert np.all(np.isfinite(g)), (penalty, np.argwhere(~np.isfinite(g))[:5])
    # and the geometry really is degenerate: coincident UAVs, no sensing, broken graphs
    xy = np.asarray(probs.uavs[..., :2])
    assert np.all(np.linalg.norm(xy[:q, 0] - xy[:q, 1], axis=-1) == 0.0)
    assert np.all(np.asarray(graph.algebraic_connectivity(graph.adjacency(jnp.asarray(xy[3 * q:]), 100e3))) < 1e-9)
    r_t = np.linalg.norm(xy[2 * q:3 * q] - np.asarray(probs.target_mean)[2 * q:3 * q, None, [0, 2]], axis=-1)
    assert np.all(r_t > 120e3)


def test_gradient_planner_turns_towards_an_unseen_target():
    """One UAV 200 km from the target, heading away: only the distance term acts, and the
    best first move is to turn towards the target (the shorter way round)."""
    uav = np.array([[0.0, 0.0]])
    target = np.array([0.0, 0.0, 200e3, 0.0])  # due +y
    prob = problem(uav, headings=0.1, target=target)  # heading ~east: turn left (+) to face north
    cp = cost_params(n=1, alpha_I=0.0, alpha_C=0.0)
    warm = jnp.zeros((8, 1))
    plan_cost = horizon_plan_cost(prob, DYN, cp, penalty="barrier")
    opts = PlannerOptions("gradient", iterations=30)
    # one jitted program: the plan and the warm start's exact cost (eager horizon costs are slow)
    plan, at_warm = jit(lambda w: (solve(plan_cost, w, jax.random.PRNGKey(0), opts),
                                   horizon_cost(prob, w, DYN, cp)))(warm)
    assert np.all(np.asarray(plan.u)[:5, 0] > 0.9)  # full left turn over the horizon
    assert float(plan.cost) < float(at_warm)


def test_gradient_solver_reports_exact_cost_and_never_loses_to_the_warm_start():
    """The closed loop's planner on the horizon cost over degenerate geometry; the exact costs
    are checked in one jitted program (eager horizon costs are slow)."""
    probs, warm = degenerate_batch(64, seed=7)
    cp = cost_params()
    opts = PlannerOptions("gradient", iterations=4)
    keys = jax.random.split(jax.random.PRNGKey(0), 64)
    exact = jax.vmap(lambda q, v: horizon_cost(q, v, DYN, cp))

    @jit
    def go(probs, warm, keys):
        plans = jax.vmap(lambda q, w, k: solve(horizon_plan_cost(q, DYN, cp, penalty="barrier"), w, k, opts))(
            probs, warm, keys)
        return plans, exact(probs, plans.u), exact(probs, warm)

    plans, at_u, at_warm = go(probs, warm, keys)
    np.testing.assert_allclose(plans.cost, at_u, rtol=1e-12)
    assert np.all(np.asarray(plans.cost) <= np.asarray(at_warm))
    assert np.all(np.abs(np.asarray(plans.u)) <= 1.0)
    assert np.mean(np.asarray(plans.cost) < np.asarray(at_warm)) > 0.5  # it does improve


def _toy_cost(target):
    """A cheap cost with the traits that trip planners: non-smooth (an L1 distance), a smooth
    surrogate that differs from it, and a NaN region (u[0, 0] > 0.8)."""
    def exact(u):
        return jnp.where(u[0, 0] > 0.8, jnp.nan, jnp.sum(jnp.abs(u - target)))

    return PlanCost(exact, lambda u: jnp.sum(jnp.sqrt((u - target) ** 2 + 0.01)))


@pytest.mark.parametrize("kind", ["gradient", "random", "cem"])
def test_solvers_report_exact_cost_and_never_lose_to_the_warm_start(kind):
    """Every kind, on a cost cheap to compile: the reported cost is the exact cost of the plan,
    never worse than the warm start's, a NaN warm start is left for a finite plan by the sampled
    kinds (the gradient kind keeps a warm start it cannot strictly beat), entries stay in [-1, 1]."""
    rng = np.random.default_rng(7)
    targets = jnp.asarray(rng.uniform(-1, 1, (64, 8, N)))
    warm = rng.uniform(-1, 1, (64, 8, N))
    warm[::4, 0, 0] = 0.9  # a NaN warm start in a quarter of the runs
    warm = jnp.asarray(warm)
    opts = PlannerOptions(kind, iterations=4, samples=32)
    keys = jax.random.split(jax.random.PRNGKey(0), 64)

    @jit
    def go(targets, warm, keys):
        plans = jax.vmap(lambda c, w, k: solve(_toy_cost(c), w, k, opts))(targets, warm, keys)
        exact = jax.vmap(lambda c, v: _toy_cost(c).exact(v))
        return plans, exact(targets, plans.u), exact(targets, warm)

    plans, at_u, at_warm = go(targets, warm, keys)
    cost, at_u, at_warm = np.asarray(plans.cost), np.asarray(at_u), np.asarray(at_warm)
    finite = np.isfinite(at_warm)
    assert (~finite).sum() >= 16
    np.testing.assert_allclose(cost[finite], at_u[finite], rtol=1e-12)
    assert np.all(cost[finite] <= at_warm[finite])
    assert np.mean(cost[finite] < at_warm[finite]) > 0.5  # it does improve
    assert np.all(np.abs(np.asarray(plans.u)) <= 1.0)
    if kind == "gradient":
        assert np.all(np.isnan(cost[~finite]))  # kept: NaN < NaN is false
    else:
        assert np.all(np.isfinite(cost[~finite]))
        np.testing.assert_allclose(cost[~finite], at_u[~finite], rtol=1e-12)


def test_information_after_prediction():
    """``(F P Fᵀ + Q)⁻¹`` against numpy, with a CV F and Q (Sun et al. 2011, eq. 1)."""
    rng = np.random.default_rng(12)
    A = rng.normal(size=(4, 4))
    P = A @ A.T + np.eye(4)
    F = np.eye(4) + np.diag([1.0, 0, 1.0], 1)
    Q = np.diag([0.25, 1.0, 0.25, 1.0]) * 50.0**2
    got = information_after_prediction(jnp.asarray(P), jnp.asarray(F), jnp.asarray(Q))
    np.testing.assert_allclose(np.asarray(got), np.linalg.inv(F @ P @ F.T + Q), rtol=1e-10)


def test_horizon_plan_cost_is_horizon_cost():
    """exact / smooth are eq. 16 with smooth=False / True, with the penalty passed through
    (the non-default one here). One jitted program: eager horizon costs are slow."""
    prob, u = problem(), jnp.asarray(np.random.default_rng(13).uniform(-1, 1, (8, N)))
    cp = cost_params()
    pc = horizon_plan_cost(prob, DYN, cp, penalty="inverse")
    got = jit(lambda v: jnp.stack([
        pc.exact(v), horizon_cost(prob, v, DYN, cp, penalty="inverse", smooth=False),
        pc.smooth(v), horizon_cost(prob, v, DYN, cp, penalty="inverse", smooth=True),
        horizon_cost(prob, v, DYN, cp, penalty="barrier", smooth=False)]))(u)
    exact, exact_ref, smooth, smooth_ref, barrier = np.asarray(got)
    assert exact == exact_ref and smooth == smooth_ref
    assert exact != smooth and exact != barrier


def test_planner_options_validation():
    with pytest.raises(ValueError, match="planner must be one of gradient, random, cem, grid"):
        PlannerOptions("newton")
    with pytest.raises(ValueError, match="cem needs"):
        PlannerOptions("cem", iterations=10, samples=8)
    with pytest.raises(ValueError, match="plan_iterations must be an integer >= 1"):
        PlannerOptions("gradient", iterations=0)
    with pytest.raises(ValueError, match="plan_samples must be an integer >= 2"):
        PlannerOptions("random", samples=1)
    with pytest.raises(ValueError, match="plan_learning_rate must be > 0"):
        PlannerOptions(learning_rate=0.0)
    with pytest.raises(ValueError, match="plan_elite_fraction must be in"):
        PlannerOptions("cem", elite_fraction=1.5)
    with pytest.raises(TypeError):  # the penalty belongs to the cost, not to the solver
        PlannerOptions(penalty="barrier")
    with pytest.raises(ValueError, match="robustness_penalty must be one of barrier, inverse"):
        horizon_plan_cost(problem(), DYN, cost_params(), penalty="log")


# --- generic costs -------------------------------------------------------------------------


def quadratic(centre, weights=1.0, offset=0.0):
    """``Σ w (u − c)² + offset``: the minimiser is ``centre`` exactly, its cost ``offset``."""
    return lambda u: jnp.sum(weights * (u - centre) ** 2) + offset


def test_grid_returns_the_known_minimiser_among_the_candidates():
    """Candidates well outside [−1, 1] (grid must not clip); the cost's minimiser is candidate
    #k, a different k in every problem of a jitted, vmapped batch."""
    rng = np.random.default_rng(20)
    B, K = 6, 9
    cands = rng.uniform(-4.0, 4.0, (B, K, 2))
    ks = rng.permutation(K)[:B]
    centres = cands[np.arange(B), ks]
    warm = rng.uniform(-1, 1, (B, 2))
    weights = np.array([1.0, 3.0])
    opts = PlannerOptions("grid")

    def one(w, c, centre):
        return solve(PlanCost(quadratic(centre, weights, 1.5)), w, jax.random.PRNGKey(0), opts, candidates=c)

    plans = jit(jax.vmap(one))(jnp.asarray(warm), jnp.asarray(cands), jnp.asarray(centres))
    np.testing.assert_array_equal(np.asarray(plans.u), centres)  # exactly candidate #k, unclipped
    np.testing.assert_array_equal(np.asarray(plans.cost), np.full(B, 1.5))
    assert np.any(np.abs(centres) > 1.0)
    # and against brute force for a cost whose minimiser is not a candidate
    off = np.array([0.3, -0.2])
    plans = jit(jax.vmap(lambda w, c: solve(PlanCost(quadratic(off, weights)), w, None, opts, candidates=c)))(
        jnp.asarray(warm), jnp.asarray(cands))
    every = np.concatenate([warm[:, None], cands], 1)
    scores = np.sum(weights * (every - off) ** 2, -1)
    best = np.argmin(scores, 1)
    np.testing.assert_array_equal(np.asarray(plans.u), every[np.arange(B), best])
    np.testing.assert_allclose(np.asarray(plans.cost), scores[np.arange(B), best], rtol=1e-14)


@pytest.mark.parametrize("nan_at", [0, 2, 4])
def test_grid_nan_cost_never_wins(nan_at):
    """The NaN candidate sits on the quadratic's minimiser (it would win if NaN compared
    low, or if argmin returned the first NaN as numpy's does)."""
    cands = np.array([[2.0, 2.0], [1.0, -1.0], [0.5, 0.5], [-3.0, 1.0], [0.2, 0.1]])
    nan_c = cands[nan_at]
    centre = jnp.asarray(nan_c)
    exact = lambda u: jnp.where(jnp.all(u == centre), jnp.nan, jnp.sum((u - centre) ** 2))
    warm = jnp.array([9.0, 9.0])
    plan = jit(lambda w, c: solve(PlanCost(exact), w, None, PlannerOptions("grid"), candidates=c))(
        warm, jnp.asarray(cands))
    scores = np.sum((cands - nan_c) ** 2, -1)
    scores[nan_at] = np.inf
    np.testing.assert_array_equal(np.asarray(plan.u), cands[np.argmin(scores)])
    assert np.isfinite(float(plan.cost)) and float(plan.cost) == scores.min()
    # a NaN warm start loses to any finite candidate
    plan = solve(PlanCost(exact), centre, None, PlannerOptions("grid"), candidates=jnp.asarray(cands))
    assert np.isfinite(float(plan.cost)) and not np.array_equal(np.asarray(plan.u), nan_c)
    # every cost NaN: the warm start is kept (scored +inf)
    plan = solve(PlanCost(lambda u: jnp.nan * jnp.sum(u)), warm, None, PlannerOptions("grid"),
                 candidates=jnp.asarray(cands))
    np.testing.assert_array_equal(np.asarray(plan.u), np.asarray(warm))
    assert float(plan.cost) == np.inf


def test_grid_keeps_the_warm_start_when_every_candidate_is_worse():
    warm = jnp.array([[0.25, -0.5], [0.75, 0.0]])  # a (2, 2) plan: any fixed shape works
    cands = jnp.asarray(np.random.default_rng(21).uniform(-2, 2, (7, 2, 2)))
    plan = solve(PlanCost(quadratic(warm, offset=-2.0)), warm, None, PlannerOptions("grid"), candidates=cands)
    np.testing.assert_array_equal(np.asarray(plan.u), np.asarray(warm))
    assert float(plan.cost) == -2.0
    # a tie goes to the warm start too: equal cost, different plan
    plan = solve(PlanCost(lambda u: jnp.sum(u**2)), jnp.array([1.0, 0.0]), None, PlannerOptions("grid"),
                 candidates=jnp.array([[0.0, 1.0], [-1.0, 0.0]]))
    np.testing.assert_array_equal(np.asarray(plan.u), [1.0, 0.0])


def test_solve_errors():
    cost = PlanCost(quadratic(0.0))
    warm, key = jnp.zeros(2), jax.random.PRNGKey(0)
    with pytest.raises(ValueError, match="grid planner needs candidates"):
        solve(cost, warm, key, PlannerOptions("grid"))
    with pytest.raises(ValueError, match=r"must have shape \(K, \*warm.shape\) = \(K, 2\); got \(4, 3\)"):
        solve(cost, warm, key, PlannerOptions("grid"), candidates=jnp.zeros((4, 3)))
    with pytest.raises(ValueError, match=r"= \(K, 2\); got \(2,\)"):  # a single plan, no K axis
        solve(cost, warm, key, PlannerOptions("grid"), candidates=jnp.zeros(2))
    with pytest.raises(ValueError, match="gradient planner needs a differentiable surrogate"):
        solve(cost, warm, key, PlannerOptions("gradient"))
    with pytest.raises(ValueError, match="candidates are only used by the grid planner; got planner 'cem'"):
        solve(cost, warm, key, PlannerOptions("cem", iterations=2, samples=8), candidates=jnp.zeros((4, 2)))
    with pytest.raises(TypeError, match="cost must be a PlanCost"):
        solve(quadratic(0.0), warm, key, PlannerOptions("random"))


@pytest.mark.parametrize("kind", ["random", "cem", "gradient"])
def test_planners_on_a_generic_cost(kind):
    """Not Sun et al.'s cost: a weighted L1 distance to a point inside [−1, 1]^(3×2) (non-smooth
    exact cost; the gradient planner descends a smooth surrogate and reports the exact cost)."""
    target = jnp.asarray(np.random.default_rng(22).uniform(-0.8, 0.8, (3, 2)))
    exact = lambda u: jnp.sum(jnp.abs(u - target))
    smooth = lambda u: jnp.sum(jnp.sqrt((u - target) ** 2 + 1e-4))
    cost = PlanCost(exact, smooth)
    opts = PlannerOptions(kind, iterations=30 if kind == "gradient" else 4, samples=64, learning_rate=0.1)
    warms = jnp.asarray(np.random.default_rng(23).uniform(-1, 1, (8, 3, 2)))
    keys = jax.random.split(jax.random.PRNGKey(3), 8)
    plans = jit(jax.vmap(lambda w, k: solve(cost, w, k, opts)))(warms, keys)
    warm_cost = np.asarray(jax.vmap(exact)(warms))
    assert np.all(np.asarray(plans.cost) < warm_cost)
    np.testing.assert_allclose(np.asarray(plans.cost), np.asarray(jax.vmap(exact)(plans.u)), rtol=1e-14)
    assert np.all(np.abs(np.asarray(plans.u)) <= 1.0)
    if kind == "gradient":  # it converges (the sampled planners only improve, at this budget)
        assert np.all(np.asarray(plans.cost) < 0.1 * warm_cost)


def test_plan_derivative_through_the_unrolled_adam_matches_central_differences():
    """What ``mcjax tune`` differentiates when it tunes the planner's weights: the plan of the
    gradient planner (10 Adam steps on the smooth eq. 16 cost, Sun et al. 2011) as a function
    of log α_I, log α_L and log α_C. Forward-mode derivative (as ``mcjax tune`` takes it)
    against central differences of the same plan, float64, step 1e-5 (measured: agreement to
    2.5e-10 of each column's largest entry, which is ~1)."""
    rng = np.random.default_rng(4)
    prob = problem(LAYOUT + rng.uniform(-20e3, 20e3, LAYOUT.shape), headings=rng.uniform(-1, 1, N))
    warm = jnp.asarray(rng.uniform(-0.2, 0.2, (5, N)))
    opts = PlannerOptions("gradient", iterations=10)
    key = jax.random.PRNGKey(0)

    def plan_of(log_w):
        w = jnp.exp(log_w)
        cp = cost_params(alpha_I=w[0], alpha_L=w[1], alpha_C=w[2])
        return solve(horizon_plan_cost(prob, DYN, cp, penalty="barrier"), warm, key, opts).u

    w0 = jnp.log(jnp.array([1000.0, 1e-4, 1.0]))
    h = 1e-5
    # One compiled program, one vmapped forward-mode pass (a jitted jacfwd and a jitted vmap of
    # the plan traced and compiled the unrolled Adam twice): lanes 0-2 push the unit tangents
    # through at w0 (the derivative's columns, as jacfwd does); lanes 3-8 give the plans at
    # w0 ± h e_k (their primal values, not derivatives) for the central differences.
    points = jnp.concatenate([jnp.broadcast_to(w0, (3, 3)), w0 + h * jnp.eye(3), w0 - h * jnp.eye(3)])
    tangents = jnp.concatenate([jnp.eye(3), jnp.zeros((6, 3))])
    values, columns = jit(jax.vmap(lambda w, t: jax.jvp(plan_of, (w,), (t,))))(points, tangents)
    jac = jnp.moveaxis(columns[:3], 0, -1)                     # (5, N, 3)
    plans = values[3:]
    fd = jnp.moveaxis((plans[:3] - plans[3:]) / (2 * h), 0, -1)
    jac, fd = np.asarray(jac), np.asarray(fd)
    assert np.all(np.isfinite(jac))
    for k, name in enumerate(("alpha_I", "alpha_L", "alpha_C")):
        scale = np.max(np.abs(fd[..., k]))
        assert scale > 1e-6, name  # the weight moves the plan
        np.testing.assert_allclose(jac[..., k], fd[..., k], rtol=0, atol=1e-6 * scale, err_msg=name)
