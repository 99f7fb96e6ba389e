"""Three UAVs estimate a constant wind by consensus Kalman filtering and hold a formation on a sine
path, Chen & Lu 2013 — the scenario ``wind_formation`` and everything only it uses:

* :mod:`.params` — Config, Params and their checks;
* :mod:`.step` — the state, the step (measure, filter, correct the path, fly), the record;
* :mod:`.scenario` — the outputs and ``SCENARIO``;
* :mod:`.guidance` — the path correction of eqs. 13–16 (forward root, approach rule, capped
  air step, centre offsets);
* :mod:`.relaxation` — the relaxation switch (soft comm links, eq. 13's path point, eq. 15's cap) for
  ``mcjax tune`` and sensitivities.
"""

from mcjax.scenarios.chen2013.params import (
    CAP_TOL, CLOSURE_TOL, FILTER_KINDS, FORMATION_SIGNS, NAME, NOISES, PAPER_OFFSETS, PAPER_START, Config, Params,
    check_params,
)
from mcjax.scenarios.chen2013.scenario import (
    SCENARIO, default_params, outputs, reduce, series, summary, timeseries, timeseries_outputs,
)
from mcjax.scenarios.chen2013.step import (
    Record, State, formation_term, init, noise_variance, pairs, reference_distances, step, wind,
)
from mcjax.scenarios.chen2013.relaxation import (
    ROUGH, Temperatures, smooth_cap, smooth_next_centre, soft_capped, training_errors, training_weights,
)

__all__ = ["CAP_TOL", "CLOSURE_TOL", "Config", "FILTER_KINDS", "FORMATION_SIGNS", "NAME", "NOISES", "PAPER_OFFSETS",
           "PAPER_START", "Params", "ROUGH", "Record", "SCENARIO", "Temperatures", "State", "check_params",
           "default_params", "formation_term", "init", "noise_variance", "outputs", "pairs", "reduce",
           "reference_distances", "series", "smooth_cap", "smooth_next_centre", "soft_capped",
           "step", "summary", "timeseries", "timeseries_outputs", "training_errors", "training_weights", "wind"]
