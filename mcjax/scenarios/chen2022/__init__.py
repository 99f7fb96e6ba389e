"""One UAV localises a static radio emitter among buildings by its azimuth, Chen & Hao 2022 —
the scenario ``urban_bearing`` and everything only it uses:

* :mod:`.scenario` — the scenario's description and ``SCENARIO``, assembled from:
* :mod:`.params` — Config, Params and their checks; :mod:`.step` — State, Record, the measurement, init and
  the step (Alg. 1; exact, or smooth for ``mcjax tune``); :mod:`.readout` — the outputs (summary, series);
* :mod:`.environment` — buildings: occupancy, line of sight and shadow, one-bounce
  reflections, the measured azimuth (eqs. 3, 5–10);
* :mod:`.score` — the track score of eqs. 13–20 (FIM, shadow, NLOS), its candidates and its
  smooth forms;
* :mod:`.relaxation` — the relaxation switch: its temperatures and the smooth stand-ins of the buildings'
  tests, the measured azimuth and the grid's choice (``mcjax tune``, sensitivities);
* :mod:`.planner` — the command of Alg. 1 (grid or gradient planner; ours: the sequence planner) and its
  soft stand-in;
* :mod:`.mode_filters` — the IMM-EKF over the LOS / NLOS± modes (eqs. 11–12).
"""

from mcjax.scenarios.chen2022.mode_filters import filter_bank, gated_mode_filter, mode_filter, mode_models
from mcjax.scenarios.chen2022.params import (
    DEFAULT_BUILDINGS, DEG, FILTER_KINDS, INITS, LOS, NAME, NLOS_MINUS, NLOS_PLUS, PLANNERS, Config, Params,
    buildings_np, buildings_of, check_params,
)
from mcjax.scenarios.chen2022.planner import (
    SequencePlan, limits_of, plan_command, plan_sequence, planner_options, project_sequence, sequence_track,
    smooth_plan_command,
)
from mcjax.scenarios.chen2022.readout import series, summary, training_weights
from mcjax.scenarios.chen2022.scenario import (
    SCENARIO, default_params, outputs, reduce, timeseries, timeseries_outputs,
)
from mcjax.scenarios.chen2022.relaxation import Temperatures
from mcjax.scenarios.chen2022.step import Record, State, first_bearing_prior, init, inv2, measure, step

__all__ = ["Config", "DEFAULT_BUILDINGS", "DEG", "FILTER_KINDS", "INITS", "LOS", "NAME", "NLOS_MINUS", "NLOS_PLUS",
           "PLANNERS", "Params", "Record", "SCENARIO", "SequencePlan", "Temperatures", "State", "buildings_np",
           "buildings_of", "check_params", "default_params", "filter_bank", "first_bearing_prior", "gated_mode_filter",
           "init", "inv2", "limits_of", "measure", "mode_filter", "mode_models", "outputs", "plan_command",
           "plan_sequence", "planner_options", "project_sequence", "reduce", "sequence_track", "series",
           "smooth_plan_command", "step", "summary", "timeseries", "timeseries_outputs", "training_weights"]
