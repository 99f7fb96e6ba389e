"""Receding-horizon planning (seed 000 §4, algorithms.md §5).

* :mod:`~mcjax.planning.objectives` — the eq. 16–19 cost terms, exact and smooth;
* :mod:`~mcjax.planning.horizon` — the rollout over ``max_horizon`` steps with t_r masking;
* :mod:`~mcjax.planning.solvers` — random shooting, CEM and optax gradient planners.
"""

from mcjax.planning.horizon import Dynamics, Problem, horizon_cost, horizon_terms, rollout, shift_plan
from mcjax.planning.objectives import CostParams, CostTerms
from mcjax.planning.solvers import PLANNER_KINDS, Plan, PlannerOptions, solve

__all__ = ["CostParams", "CostTerms", "Dynamics", "PLANNER_KINDS", "Plan", "PlannerOptions", "Problem",
           "horizon_cost", "horizon_terms", "rollout", "shift_plan", "solve"]
