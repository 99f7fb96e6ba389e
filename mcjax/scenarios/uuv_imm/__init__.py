"""Six UUVs tracking a manoeuvring (CV <-> CT) target by consensus IMM-UKF, Ren & Lv 2017 — the
scenario ``uuv_imm`` (:mod:`.scenario`) and its smoothing switch (:mod:`.smoothing`: the sonar's
range gate, the comm links, the component sizes, the likelier-mode indicator). Its filters
(:mod:`mcjax.filters.consensus_imm`) and motion models (:mod:`mcjax.models.motion`) live in the
shared folders."""

from mcjax.scenarios.uuv_imm.scenario import (
    CT, CV, FILTER_KINDS, FILTER_MODES, NAME, SCENARIO, SCHEDULES, WEIGHT_KINDS, Config, Params, Record, State,
    check_params, default_params, default_positions, init, outputs, reduce, series, step, summary, timeseries,
    timeseries_outputs, training_errors, training_weights, unscented,
)
from mcjax.scenarios.uuv_imm.smoothing import Smoothing, mode_hits

__all__ = ["CT", "CV", "Config", "FILTER_KINDS", "FILTER_MODES", "NAME", "Params", "Record", "SCENARIO", "SCHEDULES",
           "Smoothing", "State", "WEIGHT_KINDS", "check_params", "default_params", "default_positions", "init",
           "mode_hits", "outputs", "reduce", "series", "step", "summary", "timeseries", "timeseries_outputs",
           "training_errors", "training_weights", "unscented"]
