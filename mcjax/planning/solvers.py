"""Planners for the receding-horizon problem: one signature, two families (algorithms.md §5).

``solve(problem, warm, key, dyn, cost, options) -> Plan`` for every kind:

* ``"random"`` — random shooting (the baseline of seed 000's ref. [17]): ``samples`` plans
  drawn uniformly in [−1, 1]^(H×n), plus the warm start, scored by the exact cost; the best
  wins.
* ``"cem"`` — cross-entropy method: ``iterations`` rounds of ``samples // iterations``
  Gaussian draws (clipped to [−1, 1]) around a mean started at the warm start; the mean
  and spread refit to the best ``elite_fraction``; the best plan ever scored wins.
* ``"gradient"`` — optax Adam on free parameters θ with ``u = tanh θ`` (so every plan
  respects the turn-rate limit), ``iterations`` steps on the *smooth* cost inside the
  compiled program, started from the warm start; the result is kept only if its *exact*
  cost beats the warm start's.

The budget is static (``PlannerOptions``), so one compiled program serves a batch. Every
solver returns the exact cost of the plan it returns, and never a plan worse than (or a
cost less finite than) the warm start.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax

from mcjax.planning.horizon import Dynamics, Problem, horizon_cost
from mcjax.planning.objectives import ROBUSTNESS_PENALTIES, CostParams

PLANNER_KINDS = ("gradient", "random", "cem")


@dataclass(frozen=True)
class PlannerOptions:
    """Static choices of a planner (changing one recompiles)."""

    kind: str = "gradient"
    iterations: int = 10         # gradient: Adam steps; cem: rounds
    samples: int = 256           # random / cem: plans scored (the sample budget)
    learning_rate: float = 0.3   # Adam step in θ (u = tanh θ)
    elite_fraction: float = 0.1  # cem
    penalty: str = "barrier"     # robustness penalty: "barrier" | "inverse"

    def __post_init__(self):
        if self.kind not in PLANNER_KINDS:
            raise ValueError(f"planner must be one of {', '.join(PLANNER_KINDS)}; got {self.kind!r}")
        if not isinstance(self.iterations, int) or self.iterations < 1:
            raise ValueError(f"plan_iterations must be an integer >= 1; got {self.iterations!r}")
        if not isinstance(self.samples, int) or self.samples < 2:
            raise ValueError(f"plan_samples must be an integer >= 2; got {self.samples!r}")
        if self.kind == "cem" and self.samples // self.iterations < 2:
            raise ValueError("cem needs plan_samples // plan_iterations >= 2 samples per round; "
                             f"got plan_samples={self.samples}, plan_iterations={self.iterations}")
        if not self.learning_rate > 0:
            raise ValueError(f"plan_learning_rate must be > 0; got {self.learning_rate!r}")
        if not 0 < self.elite_fraction <= 1:
            raise ValueError(f"plan_elite_fraction must be in (0, 1]; got {self.elite_fraction!r}")
        if self.penalty not in ROBUSTNESS_PENALTIES:
            raise ValueError(f"robustness_penalty must be one of {', '.join(ROBUSTNESS_PENALTIES)}; "
                             f"got {self.penalty!r}")


class Plan(NamedTuple):
    u: jax.Array     # (H, n) in [−1, 1]
    cost: jax.Array  # exact cost of u


def _exact(problem, dyn, cost, options):
    return lambda u: horizon_cost(problem, u, dyn, cost, penalty=options.penalty, smooth=False)


def _keep_better(candidate: Plan, fallback: Plan) -> Plan:
    better = candidate.cost < fallback.cost  # False for NaN: a non-finite plan is never kept
    return Plan(jnp.where(better, candidate.u, fallback.u), jnp.where(better, candidate.cost, fallback.cost))


def _random(problem, warm, key, dyn, cost, options) -> Plan:
    exact = _exact(problem, dyn, cost, options)
    draws = jax.random.uniform(key, (options.samples - 1,) + warm.shape, warm.dtype, -1.0, 1.0)
    plans = jnp.concatenate([warm[None], draws])
    costs = jax.vmap(exact)(plans)
    costs = jnp.where(jnp.isnan(costs), jnp.inf, costs)
    best = jnp.argmin(costs)
    return Plan(plans[best], costs[best])


def _cem(problem, warm, key, dyn, cost, options) -> Plan:
    exact = _exact(problem, dyn, cost, options)
    m = options.samples // options.iterations
    n_elite = max(1, int(round(options.elite_fraction * m)))

    def round_(carry, k):
        mean, std, best = carry
        draws = jnp.clip(mean + std * jax.random.normal(k, (m,) + warm.shape, warm.dtype), -1.0, 1.0)
        costs = jax.vmap(exact)(draws)
        costs = jnp.where(jnp.isnan(costs), jnp.inf, costs)
        order = jnp.argsort(costs)
        elite = draws[order[:n_elite]]
        best = _keep_better(Plan(draws[order[0]], costs[order[0]]), best)
        return (jnp.mean(elite, 0), jnp.std(elite, 0) + 0.02, best), None

    start = Plan(warm, exact(warm))
    std0 = jnp.full_like(warm, 0.5)
    (_, _, best), _ = jax.lax.scan(round_, (warm, std0, start), jax.random.split(key, options.iterations))
    return best


def _gradient(problem, warm, key, dyn, cost, options) -> Plan:
    del key
    exact = _exact(problem, dyn, cost, options)

    def smooth(theta):
        return horizon_cost(problem, jnp.tanh(theta), dyn, cost, penalty=options.penalty, smooth=True)

    opt = optax.adam(options.learning_rate)
    theta0 = jnp.arctanh(jnp.clip(warm, -0.995, 0.995))

    def step(carry, _):
        theta, state = carry
        g = jax.grad(smooth)(theta)
        g = jnp.where(jnp.isfinite(g), g, 0.0)
        updates, state = opt.update(g, state, theta)
        return (optax.apply_updates(theta, updates), state), None

    (theta, _), _ = jax.lax.scan(step, (theta0, opt.init(theta0)), None, length=options.iterations)
    u = jnp.tanh(theta)
    return _keep_better(Plan(u, exact(u)), Plan(warm, exact(warm)))


_SOLVERS = {"gradient": _gradient, "random": _random, "cem": _cem}


def solve(problem: Problem, warm: jax.Array, key, dyn: Dynamics, cost: CostParams,
          options: PlannerOptions) -> Plan:
    """Plan the next ``t_r`` headings of every UAV (seed 000 eq. 20 by receding horizon, §4.2).

    ``warm`` (H, n): the previous plan shifted by τ_r (:func:`mcjax.planning.horizon.shift_plan`).
    Returns the plan and its exact cost."""
    return _SOLVERS[options.kind](problem, warm, key, dyn, cost, options)
