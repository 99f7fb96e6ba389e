"""Leader–follower UAVs tracking a CV target, Sun, Zhou, Zou & Ding 2011 — the scenario
``leader_follower`` and everything only it uses:

* :mod:`.scenario` — Config, Params, the step (dynamics, measurements, consensus filters), the
  outputs, ``SCENARIO``;
* :mod:`.objectives` — the cost terms of eqs. 16–19, exact and smooth;
* :mod:`.horizon` — the rollout over ``max_horizon`` steps with t_r masking, and
  :func:`~.horizon.horizon_plan_cost`, the eq. 16 horizon cost as a ``PlanCost`` for the
  generic planners of :mod:`mcjax.planning.solvers`;
* :mod:`.planner` — the leader's re-planning in the closed loop (§4.2);
"""

from mcjax.filters.consensus import per_agent
from mcjax.scenarios.leader_follower.planner import planner_options
from mcjax.scenarios.leader_follower.scenario import (
    NAME, PLANNERS, SCENARIO, Config, Params, Record, Smoothing, State, check_params, default_params, filter_options,
    init, outputs, reduce, series, step, summary, timeseries, timeseries_outputs, training_errors, training_weights,
)

__all__ = ["Config", "NAME", "PLANNERS", "Params", "Record", "SCENARIO", "Smoothing", "State", "check_params",
           "default_params", "filter_options", "init", "outputs", "per_agent", "planner_options", "reduce", "series",
           "step", "summary", "timeseries", "timeseries_outputs", "training_errors", "training_weights"]
