"""Six UUVs tracking a manoeuvring (CV ↔ CT) target by consensus IMM-UKF — Ren & Lv 2017.

Six stationary UUVs with range–bearing sonars track a target that switches between
constant velocity (CV) and a coordinated turn (CT) at turn rate ω, either on a fixed
schedule (CV, then CT over ``[ct_start, ct_stop)``, then CV — as in the paper's figures) or
as a Markov chain drawn per run (``Config.schedule = "markov"``). Each UUV runs, per filter:

* ``"imm"`` — the consensus IMM-UKF of Ren & Lv 2017 (CV and CT modes,
  :func:`mcjax.tracking.filters.consensus_imm.consensus_imm_ukf_step`);
* ``"cv"`` / ``"ct"`` — the single-model baselines: consensus UKF with the CV model only, or
  the CT model only (the same step with one mode, whose IMM cycle reduces to a UKF).

Consensus runs over the comm graph of ``Params.comm_radius`` (UUVs are stationary, so the
graph is fixed within a run; the default radius gives a ring). Each step records every
UUV's position error per filter (the paper's error E, read as the Euclidean position
error), the true mode and the IMM's CT probability.

Faults (``Config.faults = "on"``, :mod:`mcjax.scenarios.kit.faults`): a lost link drops the
step's consensus messages on it (every iteration of the step: the graph is the step's); a
lost UUV measures nothing, its links carry nothing and its filters hold their states; a
dropped-out sonar gives no measurement that step. The UUVs do not move, so a lost one
changes no geometry.

Units are SI (m, s, rad). The paper's values and our choices for what it leaves open are
listed in ``configs/ren2017.toml``.
"""
from __future__ import annotations

from functools import cache

import jax.numpy as jnp

from mcjax.contract import Output, Scenario, declare
from mcjax.contract.relaxation import Relaxation
from mcjax.scenarios import kit
from mcjax.scenarios.kit import bound as pcrb
from mcjax.scenarios.kit import consistency
from mcjax.scenarios.kit import faults
from mcjax.scenarios.ren2017.params import CT, Config, NAME, Params, check_params
from mcjax.scenarios.ren2017.relaxation import Temperatures
from mcjax.scenarios.ren2017.step import Record, init, step
from mcjax.tracking import metrics


def _masked_mean(values, mask):
    mask = jnp.broadcast_to(mask, values.shape).astype(values.dtype)
    return jnp.sum(mask * values) / jnp.sum(mask)


def _per_filter(cfg, records: Record, alive, after, in_ct) -> dict:
    """Per filter (F,): the errors while the target is in CV (``~in_ct``) and in CT, the ANEES,
    and per UUV the max / min / mean of its own error over the steps ``after`` warm-up."""
    w, n = cfg.warmup_steps, cfg.n_agents
    extra = {k: [] for k in ("error_cv", "error_ct", "anees")}
    per_uuv = {f"uuv{i + 1}_{s}_error": [] for i in range(n) for s in ("max", "min", "mean")}
    for f in range(len(cfg.filters)):
        e, e_own = faults.masked(records.error[:, f, :], alive), records.error[:, f, :]
        extra["error_cv"].append(_masked_mean(e, (after & ~in_ct)[:, None] * alive))
        extra["error_ct"].append(_masked_mean(e, (after & in_ct)[:, None] * alive))
        extra["anees"].append(metrics.mean_over(faults.masked(records.nees[:, f, :], alive), w, alive))
        for i in range(n):
            ei = e_own[:, i]
            per_uuv[f"uuv{i + 1}_max_error"].append(jnp.max(jnp.where(after, ei, -jnp.inf)))
            per_uuv[f"uuv{i + 1}_min_error"].append(jnp.min(jnp.where(after, ei, jnp.inf)))
            per_uuv[f"uuv{i + 1}_mean_error"].append(jnp.sum(jnp.where(after, ei, 0.0)) / jnp.sum(after))
    return {k: jnp.stack(v) for k, v in {**extra, **per_uuv}.items()}


def summary(cfg, records: Record | None, params) -> dict:
    """One run's records (stacked over time) reduced to its outputs, each declared next to its
    value: the common error summary, the errors while the target flies straight and while it
    turns, and per UUV i (numbered from 1, as in the paper's Table 1) the max / min / mean over
    the steps after warm-up of its own position error."""
    r = records
    switched_on, alive = kit.team_weights(cfg, params, r)
    after = cache(lambda: jnp.arange(r.error.shape[0]) >= cfg.warmup_steps)
    in_ct = cache(lambda: r.mode == CT)
    per_filter = cache(lambda: _per_filter(cfg, r, alive(), after(), in_ct()))

    def pick(name):
        return lambda: per_filter()[name]

    per_uuv = {f"uuv{i + 1}_{s}_error": (Output("m", f"{s} over the steps after warm-up of UUV {i + 1}'s position "
                                                "error (Table 1)"), pick(f"uuv{i + 1}_{s}_error"))
               for i in range(cfg.n_agents) for s in ("max", "min", "mean")}
    return declare(
        **kit.error_items(lambda: r.error, alive, cfg, "m"),
        error_cv=(Output("m", "mean position error over alive UUVs and steps after warm-up while the target is in "
                         "CV"), pick("error_cv")),
        error_ct=(Output("m", "the same while the target turns (CT); NaN if it never does"), pick("error_ct")),
        anees=(consistency.anees_output(4, "combined full-state"), pick("anees")),
        **per_uuv,
        **kit.graph_items(lambda: r.lambda2),
        ct_steps=(Output("steps", "steps the target spent turning (CT)", False), lambda: jnp.sum(in_ct())),
        mode_accuracy=(Output("", "fraction of (UUV, step) after warm-up where the IMM's likelier mode is the true "
                              "one", False),
                       lambda: jnp.where(jnp.any(jnp.isnan(r.mu_ct)), jnp.nan,
                                         _masked_mean(r.mode_hit, after()[:, None] * alive()))),
        mu_ct_during_ct=(Output("", "the IMM's mean CT probability while the target turns", False),
                         lambda: _masked_mean(faults.masked(r.mu_ct, alive()), (after() & in_ct())[:, None] * alive())),
        **faults.summary_items(cfg, r and r.faults, switched_on),
        **pcrb.summary_items(cfg, lambda: r.bound, cfg.warmup_steps),
        **consistency.summary_items(cfg, lambda: r.nees, lambda: r.nis, alive, cfg.warmup_steps, 4, 2, anees=False),
    )


def series(cfg, records: Record | None, params) -> dict:
    """A few per-step series of one run, (T, F) per filter, (T,) otherwise, each declared next
    to its value; written when a sweep asks for them."""
    r = records
    switched_on, alive = kit.team_weights(cfg, params, r)
    return declare(
        **kit.error_series_items(lambda: r.error, alive, "m"),
        mode=(Output("", "the target's true mode (0 = CV, 1 = CT)", False), lambda: r.mode),
        mu_ct=(Output("", "the IMM's CT probability, mean over alive UUVs (NaN without 'imm')", False),
               lambda: jnp.sum(faults.masked(r.mu_ct, alive()) * alive(), -1) / jnp.maximum(jnp.sum(alive(), -1), 1.0)),
        lambda2=(Output("", "algebraic connectivity of the comm graph", False), lambda: r.lambda2),
        **faults.series_items(cfg, r and r.faults, switched_on),
        **pcrb.series_items(cfg, lambda: r.bound),
        **consistency.series_items(cfg, lambda: r.nees, lambda: r.nis, alive, 4, 2),
    )


#: Params with no smooth path (:class:`mcjax.contract.relaxation.Relaxation`): the fault rates; the fixed
#: schedule's switch steps (step counts: the mode jumps at a threshold of t); the true mode
#: chain (each jump a threshold of a uniform draw).
ROUGH = (*faults.ROUGH, "ct_start", "ct_stop", "target_transition")

SCENARIO = Scenario(
    name=NAME, title="Ren & Lv 2017: six UUVs track a manoeuvring target by consensus IMM-UKF",
    Config=Config, Params=Params, init=init, step=step, summary=summary, series=series,
    check_params=check_params, relaxation=Relaxation(Temperatures, kit.training_errors, kit.training_weights, ROUGH),
    filter_names={"imm": "IMM-UKF", "cv": "CV-only UKF", "ct": "CT-only UKF"},
    headlines=(("imm", "cv"), ("imm", "ct")),  # the paper's point: the IMM-UKF beats either single model
    filter_words={
        "imm": "Ren & Lv 2017's consensus IMM-UKF: two motion models (constant velocity, coordinated turn) "
               "mixed by their probabilities, fused across UUVs by consensus",
        "cv": "the same consensus unscented Kalman filter with the constant-velocity model only",
        "ct": "the same consensus unscented Kalman filter with the coordinated-turn model only"})
default_params = SCENARIO.default_params
default_params, reduce, outputs, timeseries, timeseries_outputs = kit.aliases(SCENARIO)
