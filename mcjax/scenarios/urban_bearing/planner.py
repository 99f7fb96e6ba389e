"""The planner of Chen & Hao 2022, Alg. 1: the command (θ, ω) maximising the track score of
eq. 20 (:mod:`.score`) over a grid of the commands the rate limits allow, or the gradient
planner on its smooth form; and the soft stand-in of the grid's choice for ``mcjax tune``."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mcjax.models.platforms import FixedWingLimits
from mcjax.planning.solvers import PlanCost, PlannerOptions, solve
from mcjax.scenarios.urban_bearing import environment as env
from mcjax.scenarios.urban_bearing import score as urban


def limits_of(cfg, params) -> FixedWingLimits:
    """The command limits of eq. 4 and Alg. 1: bounds from the Params, rates from the Config."""
    return FixedWingLimits(params.theta_max, jnp.asarray(cfg.theta_rate_max, params.theta_max.dtype),
                           params.omega_max, jnp.asarray(cfg.omega_rate_max, params.theta_max.dtype),
                           params.h_min, params.h_max)


def planner_options(cfg) -> PlannerOptions:
    """The gradient planner's budget (``Config.plan_iterations``, ``plan_learning_rate``)."""
    return PlannerOptions(cfg.planner, cfg.plan_iterations, learning_rate=cfg.plan_learning_rate)


def plan_command(cfg, params, b: env.Buildings, uav, previous, belief: urban.Belief, key):
    """The planner's command: the grid of Alg. 1 (or the gradient planner on the smooth score)
    over the commands the rate limits allow, maximising eq. 20 among the admissible ones
    (:mod:`.score`). Plans live in the unit box: u ∈ [−1, 1]² maps to the
    command box. The gradient planner falls back to the grid's best admissible command when it
    ends on an inadmissible one. Returns ``(command (2,), exact score, admissible)``."""
    lim = limits_of(cfg, params)
    w = urban.Weights(params.c1, params.c2, params.c3)
    lo, hi = urban.command_box(previous, lim, cfg.dt)
    width = hi - lo
    safe_w = jnp.where(width > 0, width, 1.0)

    def to_command(u):
        return jnp.clip(lo + (u + 1.0) / 2.0 * width, lo, hi)

    def to_unit(c):
        return jnp.where(width > 0, 2.0 * (c - lo) / safe_w - 1.0, 0.0)

    def track_of(c):
        return urban.predicted_track(uav, c, params.speed, cfg.dt, cfg.horizon)

    def ok(c, track):
        return urban.admissible(b, uav, c, track, lim, params.speed, cfg.dt, cfg.theta_rate_max * cfg.dt)

    def exact(u):
        c = to_command(u)
        track = track_of(c)
        score = urban.track_score(urban.score_terms(b, belief, track, cfg.fim_score), w)
        return jnp.where(ok(c, track), -score, jnp.inf)

    def smooth(u):
        c = to_command(u)
        track = track_of(c)
        return -urban.track_score(urban.smooth_score_terms(b, belief, track, cfg.fim_score, params.plan_temperature), w)

    counts = urban.grid_counts(cfg.theta_rate_max, cfg.omega_rate_max, cfg.dt, cfg.theta_step, cfg.omega_step)
    commands = urban.candidate_commands(previous, lim, cfg.dt, (cfg.theta_step, cfg.omega_step), counts)
    candidates = jax.vmap(to_unit)(commands)
    warm = to_unit(previous)
    grid = solve(PlanCost(exact), warm, key, PlannerOptions("grid"), candidates)
    if cfg.planner == "grid":
        plan = grid
    else:
        # Adam from the better of the previous command and the level-off one; if it ends on an
        # inadmissible command (a track that was clear one step ago can meet a building at its
        # new last step), the grid's best admissible command is flown instead (ours: the hard
        # constraints hold whatever the planner)
        level = candidates[counts[0] * counts[1] + counts[1] // 2]
        warm = jnp.where(exact(level) < exact(warm), level, warm)
        plan = solve(PlanCost(exact, smooth), warm, key, planner_options(cfg))
        plan = jax.tree.map(lambda g, a: jnp.where(jnp.isfinite(plan.cost), a, g), grid, plan)
    return to_command(plan.u), -plan.cost, jnp.isfinite(plan.cost)


def smooth_plan_command(cfg, params, b: env.Buildings, uav, previous, belief: urban.Belief, smoothing):
    """The training surrogate of :func:`plan_command`, for the grid planner of Chen & Hao 2022,
    Alg. 1 (lines 3–9) and eq. 20: the same grid of candidate commands (spread over a soft
    command box, :func:`.score.soft_candidate_commands`), each scored by the
    smooth eq. 20 score (:func:`.score.surrogate_score_terms`), the choice a
    soft argmax weighed by smooth admissibility (:func:`.score.soft_argmax_command`).
    No fallback and no warm-start switch: the command is a smooth function of the weights,
    the state and the belief. Used for every ``Config.planner`` (docs/tune.md). Returns
    ``(command (2,), the soft argmax's mean surrogate score)``."""
    lim = limits_of(cfg, params)
    w = urban.Weights(params.c1, params.c2, params.c3)
    T = smoothing.geometry
    lo, hi = urban.soft_command_box(previous, lim, cfg.dt, smoothing.command)
    counts = urban.grid_counts(cfg.theta_rate_max, cfg.omega_rate_max, cfg.dt, cfg.theta_step, cfg.omega_step)
    commands = urban.soft_candidate_commands(lo, hi, counts, smoothing.command)

    def score(c):
        track = urban.predicted_track(uav, c, params.speed, cfg.dt, cfg.horizon)
        j = urban.track_score(urban.surrogate_score_terms(b, belief, track, cfg.fim_score, T), w)
        ok = urban.soft_admissible_log(b, uav, c, track, lim, params.speed, cfg.dt, cfg.theta_rate_max * cfg.dt, T)
        return j, ok

    scores, log_ok = jax.vmap(score)(commands)
    command, weights = urban.soft_argmax_command(commands, scores, log_ok, smoothing.plan)
    return command, weights @ scores
