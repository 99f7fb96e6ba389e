"""A flocking mobile sensor network tracks a target with the Kalman-consensus filter, Lou, Cui &
Li 2013 — the scenario ``flocking`` and everything only it uses:

* :mod:`.scenario` — Config, Params, the step, the outputs, ``SCENARIO``;
* :mod:`.dynamics` — connectivity-preserving flocking of double integrators (eqs. 1, 10–16):
  potential, controllers, the integrators (an error-controlled Dormand–Prince pair; RK4 sub-steps), energy;
* :mod:`.smoothing` — the smoothing switch: soft links with hysteresis (``mcjax tune``, sensitivities).
"""

from mcjax.scenarios.flocking.scenario import (
    CONTROL_REFERENCES, FILTER_KINDS, FILTER_NODES, NAME, SCENARIO, START_LAYOUTS, TARGET_PATHS, Config, Params, Record,
    State, check_params, default_params, init, lattice_sites, outputs, reduce, sensing_mask, series, step, summary,
    target_state, timeseries, timeseries_outputs, training_errors, training_weights,
)
from mcjax.scenarios.flocking.smoothing import ROUGH, Smoothing, soft_hysteresis, soft_link_changes

__all__ = ["CONTROL_REFERENCES", "Config", "FILTER_KINDS", "FILTER_NODES", "NAME", "Params", "ROUGH", "Record",
           "SCENARIO", "START_LAYOUTS", "Smoothing", "State", "TARGET_PATHS", "check_params", "default_params", "init",
           "lattice_sites", "outputs", "reduce", "sensing_mask", "series", "soft_hysteresis", "soft_link_changes",
           "step", "summary", "target_state", "timeseries", "timeseries_outputs", "training_errors",
           "training_weights"]
