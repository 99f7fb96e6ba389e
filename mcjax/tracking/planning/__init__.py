"""Planning: planners generic over a cost (docs/equations.md §6.3).

* :mod:`~mcjax.tracking.planning.solvers` — ``solve(cost, warm, key, options, candidates=None)`` with a
  :class:`PlanCost` (exact cost, optional smooth surrogate); random shooting, CEM, optax
  gradient, and exhaustive grid search.

The costs are the scenarios' own: the receding-horizon cost of Sun et al. 2011 in
:mod:`mcjax.scenarios.sun2011` (``objectives``, ``horizon``), the track score of Chen &
Hao 2022 in :mod:`mcjax.scenarios.chen2022` (``score``).
"""

from mcjax.tracking.planning.solvers import PLANNER_KINDS, Plan, PlanCost, PlannerOptions, solve

__all__ = ["PLANNER_KINDS", "Plan", "PlanCost", "PlannerOptions", "solve"]
