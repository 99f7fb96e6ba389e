"""Planning: generic planners and the receding-horizon cost of Sun et al. 2011 (docs/equations.md §6).

* :mod:`~mcjax.planning.solvers` — planners generic over a cost: ``solve(cost, warm, key,
  options, candidates=None)`` with a :class:`PlanCost` (exact cost, optional smooth
  surrogate); random shooting, CEM, optax gradient, and exhaustive grid search;
* :mod:`~mcjax.planning.objectives` — the cost terms of Sun et al. 2011, eqs. 16–19,
  exact and smooth;
* :mod:`~mcjax.planning.horizon` — the rollout over ``max_horizon`` steps with t_r masking,
  and :func:`horizon_plan_cost`, the Sun et al. 2011, eq. 16 horizon cost as a ``PlanCost``.
"""

from mcjax.planning.horizon import (
    Dynamics, Problem, horizon_cost, horizon_plan_cost, horizon_terms, rollout, shift_plan,
)
from mcjax.planning.objectives import CostParams, CostTerms
from mcjax.planning.solvers import PLANNER_KINDS, Plan, PlanCost, PlannerOptions, solve

__all__ = ["CostParams", "CostTerms", "Dynamics", "PLANNER_KINDS", "Plan", "PlanCost", "PlannerOptions", "Problem",
           "horizon_cost", "horizon_plan_cost", "horizon_terms", "rollout", "shift_plan", "solve"]
