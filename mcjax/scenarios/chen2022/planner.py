"""The planner of Chen & Hao 2022, Alg. 1: the command (θ, ω) maximising the track score of
eq. 20 (:mod:`.score`) over a grid of the commands the rate limits allow, or the gradient
planner on its smooth form; the sequence planner (ours: a command per step of the horizon,
:func:`plan_sequence`); and the soft stand-in of the grid's choice for ``mcjax tune``."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax

from mcjax.scenarios.chen2022 import environment as env
from mcjax.scenarios.chen2022 import score as urban
from mcjax.tracking.models.platforms import FixedWingLimits, command_box, fixed_wing_step
from mcjax.tracking.planning.solvers import PlanCost, PlannerOptions, solve
from mcjax.scenarios.chen2022.relaxation import (
    soft_admissible_log, soft_argmax_command, soft_candidate_commands, soft_command_box,
)


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
    ends on an inadmissible one. The sequence planner (:func:`plan_sequence`) flies the first
    command of its plan. Returns ``(command (2,), exact score, admissible)``."""
    if cfg.planner == "sequence":
        plan = plan_sequence(cfg, params, b, uav, previous, belief, key)
        return plan.commands[0], plan.score, plan.admissible
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


def smooth_plan_command(cfg, params, b: env.Buildings, uav, previous, belief: urban.Belief, temperatures):
    """The training surrogate of :func:`plan_command`, for the grid planner of Chen & Hao 2022,
    Alg. 1 (lines 3–9) and eq. 20: the same grid of candidate commands (spread over a soft
    command box, :func:`.relaxation.soft_candidate_commands`), each scored by the
    smooth eq. 20 score (:func:`.score.surrogate_score_terms`), the choice a
    soft argmax weighed by smooth admissibility (:func:`.relaxation.soft_argmax_command`).
    No fallback and no warm-start switch: the command is a smooth function of the weights,
    the state and the belief. Used for every ``Config.planner`` (docs/tune.md). Returns
    ``(command (2,), the soft argmax's mean surrogate score)``."""
    lim = limits_of(cfg, params)
    w = urban.Weights(params.c1, params.c2, params.c3)
    T = temperatures.geometry
    lo, hi = soft_command_box(previous, lim, cfg.dt, temperatures.command)
    counts = urban.grid_counts(cfg.theta_rate_max, cfg.omega_rate_max, cfg.dt, cfg.theta_step, cfg.omega_step)
    commands = soft_candidate_commands(lo, hi, counts, temperatures.command)

    def score(c):
        track = urban.predicted_track(uav, c, params.speed, cfg.dt, cfg.horizon)
        j = urban.track_score(urban.surrogate_score_terms(b, belief, track, cfg.fim_score, T), w)
        ok = soft_admissible_log(b, uav, c, track, lim, params.speed, cfg.dt, cfg.theta_rate_max * cfg.dt, T)
        return j, ok

    scores, log_ok = jax.vmap(score)(commands)
    command, weights = soft_argmax_command(commands, scores, log_ok, temperatures.plan)
    return command, weights @ scores


# --------------------------------------------------------------------------- the sequence planner (ours)


def project_sequence(commands, previous, limits: FixedWingLimits, dt):
    """Each command of ``commands`` (n, 2) clipped in turn into the box the rate limits allow
    around the one before (Chen & Hao 2022, Alg. 1, line 3:
    :func:`mcjax.tracking.models.platforms.command_box`,
    ``previous`` before the first): a sequence every step of which keeps the bounds and the
    rate limits of eq. 4 / Alg. 1, and unchanged if it already does (a projection onto the
    flyable sequences, not the Euclidean one)."""
    def body(prev, c):
        lo, hi = command_box(prev, limits, dt)
        c = jnp.clip(c, lo, hi)
        return c, c
    return jax.lax.scan(body, jnp.asarray(previous, commands.dtype), commands)[1]


def sequence_track(uav, commands, speed, dt):
    """The positions ``[x, y, z, ψ]`` (n, 4) when ``commands`` (n, 2) are flown in turn from
    ``uav`` (Chen & Hao 2022, eq. 1); a constant sequence gives :func:`.score.predicted_track`."""
    def body(s, c):
        s = fixed_wing_step(s, c[0], c[1], speed, dt)
        return s, s
    return jax.lax.scan(body, uav, commands)[1]


class SequencePlan(NamedTuple):
    """A plan of the sequence planner: the commands (n, 2), the first of which flies; the exact
    eq. 20 score of their track; admissible or not; whether Adam's sequence beat the
    warm start (False: the warm start's constant command, repeated)."""

    commands: jax.Array
    score: jax.Array
    admissible: jax.Array
    improved: jax.Array


def plan_sequence(cfg, params, b: env.Buildings, uav, previous, belief: urban.Belief, key) -> SequencePlan:
    """The sequence planner (ours; ``Config.planner = "sequence"``): a command (θ, ω) per step
    of the horizon instead of one constant command (Chen & Hao 2022, Alg. 1 holds one), chosen
    by the track score of eq. 20.

    1. Warm start: the best admissible constant command of the grid of Alg. 1 (lines 3–9) with
       steps ``sequence_grid_stride`` times ``theta_step``, ``omega_step`` (exact score).
    2. ``plan_iterations`` steps of projected Adam (``plan_learning_rate``) on the sequence,
       scaled by one step's largest change (θ̇_max Δt, ω̇_max Δt), minimising
       ``−(J_smooth + log p_adm)``: the smooth eq. 20 score of its track
       (:func:`.score.surrogate_score_terms` at ``plan_temperature``) and the smooth
       admissibility (:func:`.relaxation.soft_admissible_log`). After every step the sequence is
       projected onto the flyable ones (:func:`project_sequence`), so every iterate keeps the
       box and the rate limits, and the warm start — whose command often lies on an edge of
       the rate box — is represented exactly (a tanh squash cannot reach an edge).
    3. Acceptance: the final sequence is kept only if its exact score (eq. 20 on its track,
       :func:`.score.admissible` with its first command) beats the warm start's strictly;
       otherwise the warm start's constant command is repeated."""
    lim = limits_of(cfg, params)
    w = urban.Weights(params.c1, params.c2, params.c3)
    T = params.plan_temperature
    n = cfg.horizon
    unit = jnp.stack([lim.theta_rate_max, lim.omega_rate_max]) * cfg.dt

    def ok(first, track):
        return urban.admissible(b, uav, first, track, lim, params.speed, cfg.dt, cfg.theta_rate_max * cfg.dt)

    def exact_constant(c):
        track = urban.predicted_track(uav, c, params.speed, cfg.dt, n)
        score = urban.track_score(urban.score_terms(b, belief, track, cfg.fim_score), w)
        return jnp.where(ok(c, track), -score, jnp.inf)

    def exact_sequence(seq):
        track = sequence_track(uav, seq, params.speed, cfg.dt)
        score = urban.track_score(urban.score_terms(b, belief, track, cfg.fim_score), w)
        return jnp.where(ok(seq[0], track), -score, jnp.inf)

    def smooth(v):
        seq = v * unit
        track = sequence_track(uav, seq, params.speed, cfg.dt)
        j = urban.track_score(urban.surrogate_score_terms(b, belief, track, cfg.fim_score, T), w)
        adm = soft_admissible_log(b, uav, seq[0], track, lim, params.speed, cfg.dt,
                                  cfg.theta_rate_max * cfg.dt, T)
        return -(j + adm)

    stride = cfg.sequence_grid_stride
    steps = (cfg.theta_step * stride, cfg.omega_step * stride)
    counts = urban.grid_counts(cfg.theta_rate_max, cfg.omega_rate_max, cfg.dt, *steps)
    candidates = urban.candidate_commands(previous, lim, cfg.dt, steps, counts)
    warm = solve(PlanCost(exact_constant), jnp.asarray(previous, candidates.dtype), key, PlannerOptions("grid"),
                 candidates)
    start = jnp.broadcast_to(warm.u, (n, 2))
    opt = optax.adam(cfg.plan_learning_rate)

    def adam_step(carry, _):
        v, state = carry
        g = jax.grad(smooth)(v)
        g = jnp.where(jnp.isfinite(g), g, 0.0)
        updates, state = opt.update(g, state, v)
        v = project_sequence(optax.apply_updates(v, updates) * unit, previous, lim, cfg.dt) / unit
        return (v, state), None

    v0 = start / unit
    (v, _), _ = jax.lax.scan(adam_step, (v0, opt.init(v0)), None, length=cfg.plan_iterations)
    seq = project_sequence(v * unit, previous, lim, cfg.dt)
    cost = exact_sequence(seq)
    better = cost < warm.cost
    final = jnp.where(better, cost, warm.cost)
    return SequencePlan(jnp.where(better, seq, start), -final, jnp.isfinite(final), better)
