"""The leader's re-planning in the closed loop of Sun et al. 2011 §4.2 (steps ① – ③): when a
plan is due, the leader (agent 0, or the lowest-numbered UAV left if it is lost to faults)
solves the horizon problem of eq. 16 (:mod:`.horizon`, :mod:`.objectives`) from its own modified-ICF estimate with a generic planner
(:func:`mcjax.tracking.planning.solvers.solve`), in ``Config.plan_dtype``."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mcjax.scenarios import kit
from mcjax.scenarios.sun2011.horizon import Dynamics, Problem, horizon_plan_cost, rollout, shift_plan
from mcjax.scenarios.sun2011.objectives import CostParams
from mcjax.tracking.filters.steps import per_agent
from mcjax.tracking.numerics import symmetrize
from mcjax.tracking.planning.solvers import PlannerOptions, solve


def planner_options(cfg) -> PlannerOptions:
    return PlannerOptions(cfg.planner, cfg.plan_iterations, cfg.plan_samples, cfg.plan_learning_rate,
                          cfg.plan_elite_fraction)


def plan_if_due(cfg, params, state, uavs, filters, age, key, team, leader):
    """Re-plan if due (every τ_r steps, and at step 0): Sun et al. 2011 §4.2 steps ① – ③.

    The leader (agent ``leader``: 0 until it is lost to faults) plans from its own
    modified-ICF estimate and the UAV states it knows, for the ``team`` (n,) 0/1 weights of the
    UAVs alive. With ``Config.plan_period = 0`` the plan is computed every step (one program for
    every τ_r in a batch: under ``vmap`` a branch on a per-run condition computes both sides)
    and kept only when due. With ``plan_period = τ_r > 0`` "due" depends only on the step
    (t mod τ_r = 0, the same in every run of the batch), so ``lax.cond`` skips the planner on
    the other steps; the plans are the same."""
    if cfg.plan_period > 0:
        return jax.lax.cond(state.t % cfg.plan_period == 0,
                            lambda: new_plan(cfg, params, state, uavs, filters, age, key, team, leader),
                            lambda: (state.plan_u, state.plan_cmd, age, state.plan_cost))
    new = new_plan(cfg, params, state, uavs, filters, age, key, team, leader)
    due = (state.t == 0) | (age >= params.replan_every)
    return tuple(jnp.where(due, a, b) for a, b in zip(new, (state.plan_u, state.plan_cmd, age, state.plan_cost)))


def new_plan(cfg, params, state, uavs, filters, age, key, team, leader):
    """A new plan (Sun et al. 2011 §4.2 steps ① – ③): ``(u, commands, 0, cost)``."""
    n, dtype = cfg.n_agents, uavs.dtype
    estimate = per_agent("modified_icf", filters[cfg.filters.index("modified_icf")], n)
    problem = Problem(uavs, estimate.x[leader], symmetrize(estimate.Y[leader]))
    horizon = jnp.asarray(params.horizon, dtype)
    dyn = Dynamics(params.dt, params.alpha_phi, params.turn_rate_max, horizon, params.sigma_accel)
    cost = CostParams(
        params.alpha_I, params.alpha_C, params.alpha_L, params.alpha_S, params.d_safe, params.d_lt,
        params.robustness_scale, params.plan_temperature, kit.agents(params.sensing_radius, n, dtype),
        kit.agents(params.comm_radius, n, dtype), params.sigma_range, params.sigma_bearing,
        team)
    warm = shift_plan(state.plan_u, age, horizon)
    plan = solve_plan(cfg, problem, dyn, cost, warm, key)
    _, _, commands, _ = rollout(problem, plan.u, dyn)
    ok = jnp.all(jnp.isfinite(commands))
    commands = jnp.where(ok, commands, uavs[:, 3])  # a non-finite plan holds the headings
    return plan.u, commands, jnp.zeros_like(age), plan.cost


def solve_plan(cfg, problem: Problem, dyn: Dynamics, cost: CostParams, warm, key):
    """Solve the leader's horizon problem (Sun et al. 2011, eq. 16) in ``Config.plan_dtype``.

    In a narrower float type than the simulation's the problem is first moved to coordinates
    relative to the leader's target estimate (positions ~1e5 m from the origin would lose
    metres in float32; the cost depends on relative positions only — ranges, bearings,
    links — so the plan is the same up to rounding). The plan comes back in the simulation's
    dtype; the commands flown are rolled out from it in that dtype by the caller."""
    dtype, pdt = problem.uavs.dtype, jnp.dtype(cfg.plan_dtype)
    if pdt == dtype:
        return solve(horizon_plan_cost(problem, dyn, cost, penalty=cfg.robustness_penalty,
                                       paths=cfg.robustness_paths), warm, key,
                     planner_options(cfg))
    x = problem.target_mean
    shift = jnp.stack([x[0], x[2]])
    local = Problem(problem.uavs.at[:, :2].add(-shift), x.at[0].set(0.0).at[2].set(0.0), problem.Y)

    def narrow(tree):
        return jax.tree.map(lambda a: jnp.asarray(a).astype(pdt), tree)

    plan = solve(horizon_plan_cost(narrow(local), narrow(dyn), narrow(cost), penalty=cfg.robustness_penalty,
                                   paths=cfg.robustness_paths),
                 narrow(warm), key, planner_options(cfg))
    return jax.tree.map(lambda a: a.astype(dtype), plan)
