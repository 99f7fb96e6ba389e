"""Ren & Lv 2017's UUV scenario: its Config (what fixes the compiled program), its Params (per-run
values a sweep may vary) and their checks."""

from __future__ import annotations

import numpy as np

from mcjax.contract import Param, Setting, config_type, params_type
from mcjax.scenarios import kit
from mcjax.scenarios.kit import bound as kit_bound
from mcjax.scenarios.kit import consistency as kit_consistency
from mcjax.scenarios.kit import faults
from mcjax.tracking.filters.consensus_imm import LIKELIHOODS
from mcjax.tracking.filters.gaussian import Unscented

NAME = "uuv_imm"

#: Filters: name → the target modes it models (0 = CV, 1 = CT).
FILTER_MODES = {"imm": (0, 1), "cv": (0,), "ct": (1,)}
FILTER_KINDS = tuple(FILTER_MODES)
#: Why a filter of the filter contract (mcjax.contract.filter) does not run here, in a few words.
_OWN_FILTERS = ("Ren & Lv 2017's filters are UKFs of its motion models - the IMM over CV and CT, and each alone - "
                "with consensus over the modes, which a filter of the filter contract does not have")
SCHEDULES = ("fixed", "markov")
WEIGHT_KINDS = ("metropolis", "max_degree")
CV, CT = 0, 1

#: Config: everything that fixes shapes or the compiled program (changing it recompiles).
Config = config_type("Config", dict(
    **kit.common_settings(filter_kinds=FILTER_KINDS, plugin_filters=_OWN_FILTERS, n_agents=6, n_steps=100,
                          min_steps=2, warmup_steps=5, divergence_threshold=100.0),
    consensus_steps=Setting(3, "consensus iterations L per step and mode (ours)", low=0, integer=True),
    consensus_weights=Setting("metropolis", "consensus weights (paper: Metropolis)", choices=WEIGHT_KINDS),
    likelihood=Setting("fused", "mode likelihoods: fused by consensus (ours) or local (Li & Jia)",
                       choices=LIKELIHOODS),
    schedule=Setting("fixed", "target modes: fixed = CV, CT on [ct_start, ct_stop), CV; markov = drawn "
                     "per run from target_transition", choices=SCHEDULES),
    ut_alpha=Setting(1.0, "unscented transform alpha (ours; sigma-point spread, in (0, 1])", low=0, low_open=True,
                     high=1.0),
    ut_beta=Setting(2.0, "unscented transform beta (ours)", low=0),
    ut_kappa=Setting(0.0, "unscented transform kappa (ours; > -4, the state has 4 components)", low=-4,
                     low_open=True),
    bound=kit_bound.SETTING,
    consistency=kit_consistency.SETTING,
    **faults.SETTINGS,
), __name__, kit.check_common)


def unscented(cfg) -> Unscented:
    return Unscented(cfg.ut_alpha, cfg.ut_beta, cfg.ut_kappa)


def default_positions(cfg) -> np.ndarray:
    """Our UUV layout (the paper gives none): ``n`` UUVs on a circle of radius 400 m about
    (100 m, 200 m), the middle of the default target path, so neighbours on the circle are
    400 m apart for n = 6 and the default 450 m comm radius links each UUV to its two ring
    neighbours only (a ring: consensus needs several hops to spread information)."""
    n = cfg.n_agents
    angles = 2 * np.pi * np.arange(n) / max(n, 1)
    return np.stack([100.0 + 400.0 * np.cos(angles), 200.0 + 400.0 * np.sin(angles)], -1)


_POS = dict(low=0.0, low_open=True)
_NONNEG = dict(low=0.0)
_PROB = dict(low=0.0, high=1.0)
_CHAIN = np.array([[0.95, 0.05], [0.05, 0.95]])
#: Params: per-run values a sweep may vary without recompiling (Ren & Lv 2017, sec. 4, and
#: our choices where it is silent: configs/ren2017.toml says which).
Params = params_type("Params", dict(
    dt=Param(1.0, "s", "sampling = consensus interval (ours)", **_POS),
    comm_radius=Param(450.0, "m", "communication radius (ours: 450 m makes a ring)", **_NONNEG, per_agent=True,
                      label="comm radius"),
    sensing_radius=Param(10e3, "m", "sonar range (ours: every UUV always measures)", **_NONNEG, per_agent=True,
                         display="km", label="sonar range"),
    sigma_range=Param(float(np.sqrt(5.0)), "m", "range noise std (paper R = diag[5, 0.5] read as variances)",
                      **_POS),
    sigma_bearing=Param(float(np.deg2rad(np.sqrt(0.5))), "rad", "bearing noise std (0.5 deg^2 variance)",
                        **_POS, high=float(np.pi)),
    turn_rate=Param(float(np.deg2rad(3.0)), "rad/s", "omega of the CT mode (ours: 3 deg/s)", low=-1.0, high=1.0,
                    label="turn rate"),
    model_turn_rate_error=Param(0.0, "rad/s", "the filters' CT model uses omega + this (0: known omega)",
                                low=-1.0, high=1.0),
    sigma_accel=Param(0.05, "m/s^2", "the filters' process-noise acceleration std (both modes)", **_POS),
    target_sigma_accel=Param(0.01, "m/s^2", "the true target's acceleration noise std", **_NONNEG),
    ct_start=Param(lambda cfg: float(cfg.n_steps // 3), "steps", "step the CT manoeuvre starts (schedule fixed)",
                   **_NONNEG),
    ct_stop=Param(lambda cfg: float(2 * cfg.n_steps // 3), "steps", "step it ends, exclusive (schedule fixed)",
                  **_NONNEG),
    target_transition=Param(_CHAIN, "", "the true mode chain P(j | l), rows from CV, CT (schedule markov)",
                            **_PROB, shape=(2, 2)),
    imm_transition=Param(_CHAIN, "", "the IMM's mode transition matrix", **_PROB, shape=(2, 2)),
    mu0=Param(np.array([0.5, 0.5]), "", "the IMM's initial mode probabilities [CV, CT]", **_PROB, shape=(2,)),
    uuv_positions=Param(default_positions, "m", "the stationary UUVs (ours: a hexagon)", shape=("n", 2)),
    target_x0=Param(np.array([0.0, 5.0, 0.0, 5.0]), "m, m/s", "initial target state [x, vx, y, vy] (paper)",
                    shape=(4,)),
    p0_diag=Param(np.array([10.0**2, 1.0, 10.0**2, 1.0]), "m^2, (m/s)^2",
                  "prior variances at the first measurement (ours)", **_POS, shape=(4,)),
    alive=Param(lambda cfg: np.ones(cfg.n_agents), "", "1 = alive, 0 = dropped out (masked, never removed)",
                choices=(0, 1), per_agent=True),
    **faults.PARAMS,
), __name__)


def check_params(cfg, values: dict) -> list[tuple[str, str]]:
    """Checks across fields: ``[(field, what is allowed), …]`` for the bad ones."""
    bad = []
    table = Params.TABLE
    for name in ("target_transition", "imm_transition"):
        m = np.asarray(values.get(name, table[name].default), np.float64)
        if np.any(np.abs(m.sum(-1) - 1.0) > 1e-9):
            bad.append((name, "a 2x2 matrix [[P(CV|CV), P(CT|CV)], [P(CV|CT), P(CT|CT)]] whose rows sum to 1"))
    mu0 = np.asarray(values.get("mu0", table["mu0"].default), np.float64)
    if np.any(np.abs(mu0.sum(-1) - 1.0) > 1e-9):
        bad.append(("mu0", "two probabilities [CV, CT] that sum to 1"))
    start = np.asarray(values.get("ct_start", table["ct_start"].default_value(cfg)), np.float64)
    stop = np.asarray(values.get("ct_stop", table["ct_stop"].default_value(cfg)), np.float64)
    if np.any(stop < start):
        bad.append(("ct_stop", "a step >= ct_start"))
    return bad + faults.check(cfg, values, Params)

