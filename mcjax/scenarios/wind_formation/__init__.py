"""Three UAVs estimate a constant wind by consensus Kalman filtering and hold a formation on a sine
path, Chen & Lu 2013 — the scenario ``wind_formation`` and everything only it uses:

* :mod:`.scenario` — Config, Params, the step, the outputs, ``SCENARIO``;
* :mod:`.guidance` — the path correction of eqs. 13–16 (forward root, approach rule, capped
  air step, centre offsets).
"""

from mcjax.scenarios.wind_formation.scenario import (
    CAP_TOL, CLOSURE_TOL, FILTER_KINDS, FORMATION_SIGNS, NAME, NOISES, PAPER_OFFSETS, PAPER_START, SCENARIO, Config,
    Params, Record, State, check_params, default_params, formation_term, init, noise_variance, outputs, pairs, reduce,
    reference_distances, series, step, summary, timeseries, timeseries_outputs, wind,
)

__all__ = ["CAP_TOL", "CLOSURE_TOL", "Config", "FILTER_KINDS", "FORMATION_SIGNS", "NAME", "NOISES", "PAPER_OFFSETS",
           "PAPER_START", "Params", "Record", "SCENARIO", "State", "check_params", "default_params", "formation_term",
           "init", "noise_variance", "outputs", "pairs", "reduce", "reference_distances", "series", "step", "summary",
           "timeseries", "timeseries_outputs", "wind"]
