"""The sequence planner of Chen & Hao 2022's scenario (ours, ``Config.planner = "sequence"``): a
command (θ, ω) per step of the horizon by projected Adam on the smooth eq. 20 score, warm-started
from a grid's best constant command, kept only if its exact score beats it; the first command flies.

One small set-up (configs/chen2022.toml, horizon 4, 3 Adam steps at a learning rate of 5 steps of
the rate limit — large on purpose, so that an unprojected step would leave the box) shared by
every test; planning states from its own closed loop and states with the previous command on
each corner of the command box.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mcjax import configure, engine
from mcjax.contract import FAST_COMPILE
from mcjax.scenarios import chen2022 as ub
from mcjax.scenarios import kit
from mcjax.scenarios.chen2022 import score as urban
from mcjax.study.spec import build_spec
from mcjax.tracking.filters.imm import combine
from mcjax.tracking.models.platforms import fixed_wing_step

ROOT = Path(__file__).resolve().parents[3]
TOL = 1e-12


def jit(fun, **kw):
    """``jax.jit`` with the scenarios' XLA options (:data:`mcjax.contract.FAST_COMPILE`: XLA's older
    CPU fusion code generator, which compiles with much less CPU time; the engine compiles the
    scenarios' programs so). What these tests check does not depend on the code generator."""
    return jax.jit(fun, compiler_options=dict(FAST_COMPILE), **kw)


@pytest.fixture(scope="module")
def setup():
    configure()
    s = build_spec({"base": str(ROOT / "configs" / "chen2022.toml"), "seeds": 2,
                    "config": {"n_steps": 6, "warmup_steps": 1, "horizon": 4, "filters": ["imm"],
                               "planner": "sequence", "plan_iterations": 3, "plan_learning_rate": 5.0}}, ROOT)
    return s.config, kit.cast(s.base_params, jnp.float64)


def _inputs(cfg, p, state):
    imm = state.filters[0]
    xy, _ = combine(imm)
    _, sig = ub.mode_models(p, "imm")
    return ub.buildings_of(p), urban.Belief(xy, imm.x, imm.mu, state.fim, sig, p.emitter[2])


@pytest.fixture(scope="module")
def states(setup):
    """States before every step of 2 closed-loop runs (6 steps), and 4 more: the start with the
    previous command on each corner (±θ_max, ±ω_max) of the command box."""
    cfg, p = setup

    def run(key):
        s0 = ub.init(cfg, p, engine.init_key(key))

        def body(s, t):
            return ub.step(cfg, p, s, jax.random.fold_in(key, t))[0], s
        return jax.lax.scan(body, s0, jnp.arange(cfg.n_steps))[1]

    keys = jax.vmap(lambda i: engine.run_key(0, i))(jnp.arange(2, dtype=jnp.uint32))
    loop = jax.tree.map(lambda a: a.reshape((-1,) + a.shape[2:]), jit(jax.vmap(run))(keys))
    start = jax.tree.map(lambda a: a[0], loop)
    corners = [start._replace(command=jnp.array([a * p.theta_max, b * p.omega_max])) for a in (-1, 1) for b in (-1, 1)]
    return jax.tree.map(lambda *xs: jnp.concatenate([xs[0], jnp.stack(xs[1:])]), loop, *corners)


@pytest.fixture(scope="module")
def planned(setup, states):
    """One compiled program over every state: ``step`` with one key, the plan made with the plan
    key ``step`` draws from that key, and eq. 1 flown with the plan's first command (the plans
    and the step in one program: a program of its own for the plans compiled the planner once more)."""
    cfg, p = setup
    key = engine.run_key(0, 5)
    k_plan, _ = jax.random.split(key)

    def both(state):
        new, rec = ub.step(cfg, p, state, key)
        b, belief = _inputs(cfg, p, state)
        plan = ub.plan_sequence(cfg, p, b, state.uav, state.command, belief, k_plan)
        flown = fixed_wing_step(state.uav, plan.commands[0, 0], plan.commands[0, 1], p.speed, cfg.dt)
        return plan, (new.uav, rec, flown)

    return jit(jax.vmap(both))(states)


@pytest.fixture(scope="module")
def plans(planned):
    return planned[0]


def _flyable(seq, previous, p, cfg):
    """numpy: every command within the bounds of eq. 4 and within one step's rate limit of the one before."""
    seq, prev = np.asarray(seq), np.asarray(previous)
    bound = np.array([float(p.theta_max), float(p.omega_max)])
    rate = np.array([cfg.theta_rate_max, cfg.omega_rate_max]) * cfg.dt
    steps = np.diff(np.concatenate([prev[None], seq]), axis=0)
    return np.all(np.abs(seq) <= bound + TOL) and np.all(np.abs(steps) <= rate + TOL)


def test_every_planned_command_keeps_the_bounds_and_rates(setup, states, plans):
    """Every command of every planned sequence lies within ±θ_max, ±ω_max and within one step's
    rate limit of the command before it (the previous command before the first), also from the
    corners of the command box and with Adam steps of 5 rate limits."""
    cfg, p = setup
    seqs = np.asarray(plans.commands)
    assert seqs.shape == (states.t.shape[0], cfg.horizon, 2)
    for seq, prev in zip(seqs, np.asarray(states.command)):
        assert _flyable(seq, prev, p, cfg), (seq, prev)
    assert np.all(np.asarray(plans.admissible))
    # the test can fail: the sequences are not all the warm start's constant command
    assert np.any(np.asarray(plans.improved)) and np.any(np.ptp(seqs, axis=1) > 1e-6)


def test_projection_against_numpy(setup):
    """:func:`project_sequence` equals clipping each command in turn into the rate box around the
    one before (numpy), its output is flyable, and a flyable sequence is left unchanged."""
    cfg, p = setup
    lim = ub.limits_of(cfg, p)
    rng = np.random.default_rng(3)
    bound = np.array([float(p.theta_max), float(p.omega_max)])
    rate = np.array([cfg.theta_rate_max, cfg.omega_rate_max]) * cfg.dt
    for _ in range(5):
        prev = rng.uniform(-1, 1, 2) * bound
        raw = rng.normal(0, 3, (7, 2)) * rate + prev
        got = np.asarray(ub.project_sequence(jnp.asarray(raw), jnp.asarray(prev), lim, cfg.dt))
        want, c = [], prev
        for r in raw:
            c = np.clip(r, np.maximum(-bound, c - rate), np.minimum(bound, c + rate))
            want.append(c)
        np.testing.assert_allclose(got, np.array(want), rtol=0, atol=1e-15)
        assert _flyable(got, prev, p, cfg) and not _flyable(raw, prev, p, cfg)
        again = np.asarray(ub.project_sequence(jnp.asarray(got), jnp.asarray(prev), lim, cfg.dt))
        assert np.array_equal(again, got)


def test_plan_is_scored_exactly_and_never_worse_than_its_warm_start(setup, states, plans):
    """The plan's score is the exact eq. 20 score of its own track (recomputed), and at least the
    best exact score over the warm start's grid of constant commands (brute force: every command
    of the stride-2 grid held over the horizon); strictly above it exactly when improved."""
    cfg, p = setup
    lim = ub.limits_of(cfg, p)
    w = urban.Weights(p.c1, p.c2, p.c3)
    steps = (cfg.theta_step * cfg.sequence_grid_stride, cfg.omega_step * cfg.sequence_grid_stride)
    counts = urban.grid_counts(cfg.theta_rate_max, cfg.omega_rate_max, cfg.dt, *steps)

    def check(state, seq):
        b, belief = _inputs(cfg, p, state)
        track = ub.sequence_track(state.uav, seq, p.speed, cfg.dt)
        own = urban.track_score(urban.score_terms(b, belief, track, cfg.fim_score), w)

        def constant(c):
            t = urban.predicted_track(state.uav, c, p.speed, cfg.dt, cfg.horizon)
            ok = urban.admissible(b, state.uav, c, t, lim, p.speed, cfg.dt, cfg.theta_rate_max * cfg.dt)
            return jnp.where(ok, urban.track_score(urban.score_terms(b, belief, t, cfg.fim_score), w), -jnp.inf)
        return own, jnp.max(jax.vmap(constant)(urban.candidate_commands(state.command, lim, cfg.dt, steps, counts)))

    own, best = (np.asarray(x) for x in jit(jax.vmap(check))(states, plans.commands))
    score, improved = np.asarray(plans.score), np.asarray(plans.improved)
    assert np.all(np.isfinite(best))
    np.testing.assert_allclose(score, own, rtol=1e-12, atol=1e-12)
    assert np.all(score >= best - 1e-12 * np.abs(best))
    np.testing.assert_array_equal(improved, score > best + 1e-12 * np.abs(best))


def test_a_constant_sequence_flies_the_constant_track(setup, states):
    """:func:`sequence_track` of a constant sequence is :func:`.score.predicted_track` (the track
    the grid scores), so the warm start's exact score is the grid's."""
    cfg, p = setup
    uav = states.uav[3]
    c = jnp.array([0.01, -0.02])
    np.testing.assert_array_equal(np.asarray(ub.sequence_track(uav, jnp.broadcast_to(c, (cfg.horizon, 2)), p.speed,
                                                               cfg.dt)),
                                  np.asarray(urban.predicted_track(uav, c, p.speed, cfg.dt, cfg.horizon)))


def test_the_first_command_of_the_plan_flies(states, planned):
    """``step`` with the sequence planner flies the first command of the plan made from the same
    state and plan key (on re-plan steps: the last step measured), and moves the UAV by eq. 1
    with it; no command breaks a limit and no step enters a building."""
    plan, (uav, rec, flown) = planned
    first = plan.commands[:, 0]
    replan = np.asarray(states.measured)
    assert replan.sum() >= 8 and not np.any(np.asarray(rec.held)[replan])
    np.testing.assert_array_equal(np.asarray(rec.command)[replan], np.asarray(first)[replan])
    np.testing.assert_array_equal(np.asarray(uav)[replan], np.asarray(flown)[replan])
    assert not np.any(np.asarray(rec.violation)) and not np.any(np.asarray(rec.in_building))


def test_other_planners_are_untouched_by_the_sequence_settings(setup, states):
    """The grid planner's command does not depend on the sequence planner's settings."""
    cfg, p = setup
    grid = dataclasses.replace(cfg, planner="grid")
    other = dataclasses.replace(grid, sequence_grid_stride=3, plan_iterations=7)
    state = jax.tree.map(lambda a: a[2], states)
    b, belief = _inputs(cfg, p, state)

    def plan(c):
        return jit(lambda: ub.plan_command(c, p, b, state.uav, state.command, belief, jax.random.PRNGKey(0)))()
    assert all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(plan(grid), plan(other)))
