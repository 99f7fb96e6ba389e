"""Six UUVs tracking a manoeuvring (CV <-> CT) target by consensus IMM-UKF, Ren & Lv 2017 — the
scenario ``uuv_imm`` (:mod:`.params`: Config, Params and their checks; :mod:`.step`: the state, the step,
the record; :mod:`.scenario`: the outputs and ``SCENARIO``) and its relaxation switch (:mod:`.relaxation`: the sonar's
range gate, the comm links, the component sizes, the likelier-mode indicator). Its filters
(:mod:`mcjax.tracking.filters.consensus_imm`) and motion models (:mod:`mcjax.tracking.models.motion`) live in the
shared folders."""

from mcjax.scenarios.kit import training_errors, training_weights
from mcjax.scenarios.ren2017.params import (
    CT, CV, FILTER_KINDS, FILTER_MODES, NAME, SCHEDULES, WEIGHT_KINDS, Config, Params, check_params, default_positions,
    unscented,
)
from mcjax.scenarios.ren2017.scenario import (
    SCENARIO, default_params, outputs, reduce, series, summary, timeseries, timeseries_outputs,
)
from mcjax.scenarios.ren2017.relaxation import Temperatures, mode_hits
from mcjax.scenarios.ren2017.step import Record, State, init, step

__all__ = ["CT", "CV", "Config", "FILTER_KINDS", "FILTER_MODES", "NAME", "Params", "Record", "SCENARIO", "SCHEDULES",
           "Temperatures", "State", "WEIGHT_KINDS", "check_params", "default_params", "default_positions", "init",
           "mode_hits", "outputs", "reduce", "series", "step", "summary", "timeseries", "timeseries_outputs",
           "training_errors", "training_weights", "unscented"]
