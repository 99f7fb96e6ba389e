"""Planners generic over a cost: one signature for every kind (docs/equations.md §6.3).

``solve(cost, warm, key, options, candidates=None) -> Plan`` for every kind. A plan ``u`` is
an array of any fixed shape (the warm start's); ``cost`` is a :class:`PlanCost`: the exact
cost ``u -> scalar`` that every planner reports and the sampled planners minimise, and an
optional differentiable surrogate that only the gradient planner uses. The horizon cost of
Sun et al. 2011, eq. 16 is one client:
:func:`mcjax.scenarios.sun2011.horizon.horizon_plan_cost`.

* ``"random"`` — random shooting (the baseline of Sun et al. 2011's ref. [17]): ``samples`` plans
  (the warm start and ``samples − 1`` draws uniform in [−1, 1] per entry) scored by the
  exact cost; the best wins.
* ``"cem"`` — cross-entropy method: ``iterations`` rounds of ``samples // iterations``
  Gaussian draws (clipped to [−1, 1]) around a mean started at the warm start; the mean
  and spread refit to the best ``elite_fraction``; the best plan ever scored (the warm
  start included) wins.
* ``"gradient"`` — optax Adam on free parameters θ with ``u = tanh θ`` (so every plan stays
  in [−1, 1]), ``iterations`` steps on the *smooth* cost inside the compiled program,
  started from the warm start; the result is kept only if its *exact* cost beats the warm
  start's.
* ``"grid"`` — exhaustive search over a finite candidate set the caller supplies
  (``candidates`` of shape (K, *warm.shape), entries unrestricted — not clipped): every
  candidate and the warm start are scored by the exact cost; the best wins, ties going to
  the warm start, then to the lower index. ``iterations``, ``samples``, … are unused.

Random, CEM and gradient assume entries in [−1, 1] (the random draws and the tanh map
produce them; CEM clips). A NaN cost never wins: random, CEM and grid score NaN as +inf
(so a plan whose cost is NaN is returned only if every plan scored is, with cost +inf) and
the gradient planner keeps the warm start unless its result is strictly better.

The budget is static (``PlannerOptions``), so one compiled program serves a batch. Every
solver returns the exact cost of the plan it returns, and never a plan worse than (or a
cost less finite than) the warm start.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import optax

PLANNER_KINDS = ("gradient", "random", "cem", "grid")


class PlanCost(NamedTuple):
    """What a planner minimises. Both functions map a plan ``u`` (the warm start's shape) to
    a scalar and must be traceable (they run inside ``jit``/``vmap``/``scan``)."""

    exact: Callable[[jax.Array], jax.Array]
    """The cost every planner reports and the sampled planners (random, CEM, grid) minimise."""
    smooth: Callable[[jax.Array], jax.Array] | None = None
    """A differentiable surrogate of ``exact``; required by the ``"gradient"`` kind only."""


@dataclass(frozen=True)
class PlannerOptions:
    """Static choices of a planner (changing one recompiles). The validation messages name
    the corresponding ``Config`` fields (``planner``, ``plan_iterations``, …)."""

    kind: str = "gradient"
    iterations: int = 10         # gradient: Adam steps; cem: rounds
    samples: int = 256           # random / cem: plans scored (the sample budget)
    learning_rate: float = 0.3   # Adam step in θ (u = tanh θ)
    elite_fraction: float = 0.1  # cem

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


class Plan(NamedTuple):
    u: jax.Array     # the warm start's shape (random / CEM / gradient: entries in [−1, 1])
    cost: jax.Array  # exact cost of u


def _keep_better(candidate: Plan, fallback: Plan) -> Plan:
    better = candidate.cost < fallback.cost  # False for NaN: a non-finite plan is never kept
    return Plan(jnp.where(better, candidate.u, fallback.u), jnp.where(better, candidate.cost, fallback.cost))


def _best_of(exact, plans) -> Plan:
    """The plan of least exact cost among ``plans`` (P, ...); NaN scores +inf; ties go to the
    lowest index."""
    costs = jax.vmap(exact)(plans)
    costs = jnp.where(jnp.isnan(costs), jnp.inf, costs)
    best = jnp.argmin(costs)
    return Plan(plans[best], costs[best])


def _random(cost: PlanCost, warm, key, options, candidates) -> Plan:
    del candidates
    draws = jax.random.uniform(key, (options.samples - 1,) + warm.shape, warm.dtype, -1.0, 1.0)
    return _best_of(cost.exact, jnp.concatenate([warm[None], draws]))


def _grid(cost: PlanCost, warm, key, options, candidates) -> Plan:
    del key, options
    return _best_of(cost.exact, jnp.concatenate([warm[None], jnp.asarray(candidates, warm.dtype)]))


def _cem(cost: PlanCost, warm, key, options, candidates) -> Plan:
    del candidates
    exact = cost.exact
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

    c0 = exact(warm)
    start = Plan(warm, jnp.where(jnp.isnan(c0), jnp.inf, c0))  # a NaN warm start never wins
    std0 = jnp.full_like(warm, 0.5)
    (_, _, best), _ = jax.lax.scan(round_, (warm, std0, start), jax.random.split(key, options.iterations))
    return best


def _gradient(cost: PlanCost, warm, key, options, candidates) -> Plan:
    del key, candidates
    exact = cost.exact

    def smooth(theta):
        return cost.smooth(jnp.tanh(theta))

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


_SOLVERS = {"gradient": _gradient, "random": _random, "cem": _cem, "grid": _grid}


def solve(cost: PlanCost, warm: jax.Array, key, options: PlannerOptions,
          candidates: jax.Array | None = None) -> Plan:
    """Minimise ``cost`` from the warm start ``warm`` with the planner ``options.kind``.

    ``warm``: the plan to beat (any fixed shape; for Sun et al. 2011 the previous plan shifted by
    τ_r, :func:`mcjax.scenarios.sun2011.horizon.shift_plan`). ``key``: a PRNG key (used by random and
    CEM). ``candidates`` (K, *warm.shape): the finite set the ``"grid"`` kind searches
    (required by it, rejected by the other kinds; cast to ``warm``'s dtype, not clipped).
    Returns the plan and its exact cost.

    The checks below run at trace time, on shapes only, so ``solve`` may be jitted and
    vmapped (``cost``, ``options`` closed over; ``warm``, ``key``, ``candidates`` batched)."""
    if not isinstance(cost, PlanCost):
        raise TypeError(f"cost must be a PlanCost(exact, smooth=None); got {type(cost).__name__}")
    if options.kind == "gradient" and cost.smooth is None:
        raise ValueError("the gradient planner needs a differentiable surrogate: "
                         "PlanCost(exact, smooth) with smooth not None")
    if options.kind == "grid":
        if candidates is None:
            raise ValueError("the grid planner needs candidates: an array of shape (K, *warm.shape)")
        shape = tuple(jnp.shape(candidates))
        if len(shape) != jnp.ndim(warm) + 1 or shape[1:] != tuple(jnp.shape(warm)):
            want = "".join(f", {d}" for d in jnp.shape(warm))
            raise ValueError(f"grid candidates must have shape (K, *warm.shape) = (K{want}); got {shape}")
    elif candidates is not None:
        raise ValueError(f"candidates are only used by the grid planner; got planner {options.kind!r}")
    return _SOLVERS[options.kind](cost, warm, key, options, candidates)
