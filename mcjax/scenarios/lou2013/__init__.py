"""A flocking mobile sensor network tracks a target with the Kalman-consensus filter, Lou, Cui &
Li 2013 — the scenario ``flocking`` and everything only it uses:

* :mod:`.scenario` — the scenario's description, its outputs (summary, series), the training loss's
  weights and ``SCENARIO``, assembled from:
* :mod:`.params` — Config, Params and their checks; :mod:`.step` — State, Record, init and the step;
* :mod:`.model` — connectivity-preserving flocking of double integrators (eqs. 1, 10–16):
  potential, controllers, energy; :mod:`.dynamics` — its integrators over a step (an error-controlled
  Dormand–Prince pair; RK4 sub-steps);
* :mod:`.relaxation` — the relaxation switch: soft links with hysteresis (``mcjax tune``, sensitivities).
"""

from mcjax.scenarios.lou2013.params import (
    CONTROL_REFERENCES, FILTER_KINDS, FILTER_NODES, NAME, START_LAYOUTS, TARGET_PATHS, Config, Params, check_params,
    lattice_sites,
)
from mcjax.scenarios.lou2013.scenario import (
    SCENARIO, default_params, outputs, reduce, series, summary, timeseries, timeseries_outputs, training_weights,
)
from mcjax.scenarios.kit import training_errors
from mcjax.scenarios.lou2013.relaxation import ROUGH, Temperatures, soft_hysteresis, soft_link_changes
from mcjax.scenarios.lou2013.step import Record, State, init, sensing_mask, step, target_state

__all__ = ["CONTROL_REFERENCES", "Config", "FILTER_KINDS", "FILTER_NODES", "NAME", "Params", "ROUGH", "Record",
           "SCENARIO", "START_LAYOUTS", "Temperatures", "State", "TARGET_PATHS", "check_params", "default_params", "init",
           "lattice_sites", "outputs", "reduce", "sensing_mask", "series", "soft_hysteresis", "soft_link_changes",
           "step", "summary", "target_state", "timeseries", "timeseries_outputs", "training_errors",
           "training_weights"]
