"""Six UUVs tracking a manoeuvring (CV <-> CT) target by consensus IMM-UKF, Ren & Lv 2017 — the
scenario ``uuv_imm`` (:mod:`.scenario`). Its filters (:mod:`mcjax.filters.consensus_imm`) and
motion models (:mod:`mcjax.models.motion`) live in the shared folders."""

from mcjax.scenarios.uuv_imm.scenario import (
    CT, CV, FILTER_KINDS, FILTER_MODES, NAME, SCENARIO, SCHEDULES, WEIGHT_KINDS, Config, Params, Record, State,
    check_params, default_params, default_positions, init, outputs, reduce, series, step, summary, timeseries,
    timeseries_outputs, unscented,
)

__all__ = ["CT", "CV", "Config", "FILTER_KINDS", "FILTER_MODES", "NAME", "Params", "Record", "SCENARIO", "SCHEDULES",
           "State", "WEIGHT_KINDS", "check_params", "default_params", "default_positions", "init", "outputs", "reduce",
           "series", "step", "summary", "timeseries", "timeseries_outputs", "unscented"]
