"""Leader–follower UAVs tracking a CV target, Sun, Zhou, Zou & Ding 2011 — the scenario
``leader_follower`` and everything only it uses:

* :mod:`.params` — Config, Params and their checks;
* :mod:`.step` — the state, the step (dynamics, measurements, consensus filters), the record,
  the relaxation switch;
* :mod:`.scenario` — the outputs and ``SCENARIO``;
* :mod:`.objectives` — the cost terms of eqs. 16–19, exact and smooth;
* :mod:`.horizon` — the rollout over ``max_horizon`` steps with t_r masking, and
  :func:`~.horizon.horizon_plan_cost`, the eq. 16 horizon cost as a ``PlanCost`` for the
  generic planners of :mod:`mcjax.tracking.planning.solvers`;
* :mod:`.planner` — the leader's re-planning in the closed loop (§4.2);
"""

from mcjax.scenarios.kit import training_errors, training_weights
from mcjax.scenarios.sun2011.params import Config, NAME, PLANNERS, Params, check_params, filter_options
from mcjax.scenarios.sun2011.planner import planner_options
from mcjax.tracking.filters.steps import per_agent
from mcjax.scenarios.sun2011.scenario import (
    SCENARIO, default_params, outputs, reduce, series, summary, timeseries, timeseries_outputs,
)
from mcjax.scenarios.sun2011.step import Record, State, Temperatures, init, step

__all__ = ["Config", "NAME", "PLANNERS", "Params", "Record", "SCENARIO", "Temperatures", "State", "check_params",
           "default_params", "filter_options", "init", "outputs", "per_agent", "planner_options", "reduce", "series",
           "step", "summary", "timeseries", "timeseries_outputs", "training_errors", "training_weights"]
