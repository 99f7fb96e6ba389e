"""Chen & Lu 2013's wind and formation scenario: its Config (what fixes the compiled program), its
Params (per-run values a sweep may vary) and their checks."""

from __future__ import annotations

import numpy as np

from mcjax.contract import Param, Setting, config_type, params_type
from mcjax.scenarios import kit
from mcjax.scenarios.kit import bound as kit_bound
from mcjax.scenarios.kit import consistency as kit_consistency
from mcjax.scenarios.kit import faults
from mcjax.tracking.filters.consensus import WEIGHT_KINDS

NAME = "wind_formation"
FILTER_KINDS = ("kcf", "local", "cif", "ci", "hcmci")
#: The filters run by default: the paper's (the robust "ci" and "hcmci" are opt-in names).
PAPER_FILTERS = ("kcf", "local", "cif")
NOISES = ("uniform", "gaussian")
FORMATION_SIGNS = ("corrective", "printed")
#: Closing tolerance of the offsets (m): the last row must equal the sum of the chain.
CLOSURE_TOL = 1e-6
#: An air step counts as capped (eq. 15) when the wanted one is longer than l by this fraction:
#: on the path the centre's wanted step is l itself, up to rounding.
CAP_TOL = 1e-9


def _check(cfg) -> None:
    kit.check_common(cfg)
    if cfg.n_agents < 2:
        raise ValueError(f"n_agents must be an integer >= 2 (a formation); got {cfg.n_agents}")
    if cfg.report_agent > cfg.n_agents:
        raise ValueError(f"report_agent must be an integer in [1, n_agents = {cfg.n_agents}]; "
                         f"got {cfg.report_agent}")
    if cfg.bound == "on" and cfg.wind_noise != "gaussian":   # no Fisher information (module .step, "The bound")
        raise ValueError(f"bound must be 'off' when wind_noise = 'uniform' (a uniform noise has no Fisher "
                         f"information: no Cramér–Rao bound); bound = 'on' needs wind_noise = 'gaussian'; "
                         f"got bound = {cfg.bound!r}, wind_noise = {cfg.wind_noise!r}")


Config = config_type("Config", dict(
    **kit.common_settings(filter_kinds=FILTER_KINDS, plugin_filters=True, filters=PAPER_FILTERS, n_agents=3,
                          n_steps=100, min_steps=2, warmup_steps=0, divergence_threshold=20.0, error_unit="m/s"),
    wind_noise=Setting("uniform", "wind measurement noise: uniform on [-noise_scale, noise_scale] or "
                       "gaussian with std noise_scale (ours)", choices=NOISES),
    weights=Setting("max_degree", "consensus weights of the kcf: max_degree = Chen & Lu 2013 eq. 7",
                    choices=WEIGHT_KINDS),
    formation_sign=Setting("corrective", "sign of eq. 12's formation term: corrective (ours: pulls a UAV "
                           "towards its slot) or printed", choices=FORMATION_SIGNS),
    report_agent=Setting(2, "the UAV (1-based) whose per-axis wind errors are reported (paper: UAV2)",
                         low=1, integer=True),
    root_grid=Setting(128, "grid cells that bracket eq. 13's roots before bisection (ours)", low=2,
                      integer=True),
    bound=kit_bound.SETTING,
    consistency=kit_consistency.SETTING,
    **faults.SETTINGS,
), __name__, _check)

#: The paper's starting positions of its three UAVs (m).
PAPER_START = np.array([[10000.0, 7000.0], [10000.0, 12000.0], [12000.0, 9000.0]])
#: The paper's reference vectors as the chain d_12, d_23 and the closing d_13 (configs/chen2013.toml).
PAPER_OFFSETS = np.array([[0.0, 3200.0], [1300.0, -1600.0], [1300.0, 1600.0]])


def _default_start(cfg):
    if cfg.n_agents == 3:
        return PAPER_START.copy()
    return np.stack([np.full(cfg.n_agents, 10000.0), 7000.0 + 2500.0 * np.arange(cfg.n_agents)], axis=1)


def _default_offsets(cfg):
    if cfg.n_agents == 3:
        return PAPER_OFFSETS.copy()
    n = cfg.n_agents
    chain = np.tile([[0.0, 1000.0]], (n, 1))
    chain[-1] = [0.0, 1000.0 * (n - 1)]
    return chain


_POS = dict(low=0.0, low_open=True)
Params = params_type("Params", dict(
    dt=Param(10.0, "s", "measurement and guidance interval (paper: 10 s)", **_POS),
    step_length=Param(1000.0, "m", "l: the look-ahead of eq. 13 and the longest air step of eq. 15 "
                      "(paper: V dt = 1000 m)", **_POS),
    wind_speed=Param(40.0, "m/s", "the constant wind's speed (paper)", low=0.0),
    wind_direction=Param(np.pi / 4, "rad", "the wind's direction from the x axis (paper: 45 deg)"),
    noise_scale=Param(10.0, "m/s", "wind measurement noise: the uniform bound or the Gaussian std (ours)", **_POS,
                      label="wind noise"),
    sigma_wind_process=Param(0.5, "m/s", "the filters' random-walk wind model, std per step (ours)", **_POS),
    sigma_wind_prior=Param(50.0, "m/s", "the filters' prior std about zero wind (ours)", **_POS),
    eta=Param(0.01, "1/s", "formation factor eta of eq. 12 (ours)", low=0.0, label="formation factor η"),
    comm_radius=Param(1.0e5, "m", "UAVs within this distance exchange estimates (ours: complete graph)", **_POS,
                      display="km", label="comm radius"),
    path_amplitude=Param(2000.0 / 3.0, "m", "path y = amplitude sin(x / scale) (paper: 2000/3)"),
    path_scale=Param(1200.0, "m", "path y = amplitude sin(x / scale) (paper: 1200)", **_POS),
    formation_tolerance=Param(50.0, "m", "pairwise distances count as in formation within this of the "
                              "reference (ours)", **_POS),
    start=Param(_default_start, "m", "starting positions (paper: (10000, 7000), (10000, 12000), (12000, 9000))",
                shape=("n", 2)),
    offsets=Param(_default_offsets, "m", "pairwise formation offsets d_ij = p_j - p_i: rows d_12, d_23, ..., "
                  "then the closing d_1n (= their sum)", shape=("n", 2)),
    **faults.PARAMS,
), __name__)


def check_params(cfg, values: dict) -> list[tuple[str, str]]:
    offsets = kit.param_value(Params, cfg, values, "offsets")
    bad = []
    if offsets.shape[-2:] == (cfg.n_agents, 2):   # one formation, or one per sweep point
        gaps = np.linalg.norm(np.sum(offsets[..., : cfg.n_agents - 1, :], axis=-2) - offsets[..., -1, :], axis=-1)
        if np.any(gaps > CLOSURE_TOL * (1.0 + np.max(np.abs(offsets)))):
            bad.append(("offsets", f"pairwise offsets that close: the last row d_1n must equal the sum of the "
                        f"rows d_12 ... d_(n-1)n (they are {float(np.max(gaps)):g} m apart)"))
    return bad + faults.check(cfg, values, Params)

