"""Chen & Hao 2022's scenario (:mod:`.scenario`): its Config and Params, their checks, and the
building layout as :class:`~.environment.Buildings`."""

from __future__ import annotations

import numpy as np

from mcjax.contract import Param, Setting, config_type, params_type
from mcjax.scenarios import kit
from mcjax.scenarios.chen2022 import environment as env
from mcjax.scenarios.chen2022 import score as urban
from mcjax.scenarios.kit import bound as kit_bound
from mcjax.scenarios.kit import consistency as kit_consistency

NAME = "urban_bearing"

FILTER_KINDS = ("imm", "ekf")
#: Why a filter of the filter contract (mcjax.contract.filter) does not run here, in a few words.
_OWN_FILTERS = ("Chen & Hao 2022 fly one UAV with no comm graph, and its filters are an IMM over the "
                "propagation modes (LOS, NLOS) and one EKF")
PLANNERS = ("grid", "gradient", "sequence")
INITS = ("first_bearing", "prior")
LOS, NLOS_PLUS, NLOS_MINUS = 0, 1, 2
DEG = float(np.pi / 180.0)


def _check(cfg) -> None:
    kit.check_common(cfg)
    if "imm" not in cfg.filters:
        raise ValueError("filters must include 'imm': the planner scores tracks with the IMM-EKF's "
                         "mode estimates and probabilities (Chen & Hao 2022, eq. 16)")


_settings = kit.common_settings(filter_kinds=FILTER_KINDS, plugin_filters=_OWN_FILTERS, n_agents=1, n_steps=250,
                                warmup_steps=25, divergence_threshold=2000.0)
_settings["n_agents"] = Setting(1, "number of UAVs (the paper's system has one)", choices=(1,))

#: Config: what fixes shapes or the compiled program (the grid's size follows from the rates,
#: the step and Δt, so they live here).
Config = config_type("Config", dict(
    **_settings,
    dt=Setting(2.0, "time step (paper: 2 s)", "s", low=0, low_open=True),
    theta_rate_max=Setting(1.0 * DEG, "largest |d theta/dt| (paper: 1 deg/s)", "rad/s", low=0, low_open=True),
    omega_rate_max=Setting(1.0 * DEG, "largest |d omega/dt| (paper: 1 deg/s^2)", "rad/s^2", low=0,
                           low_open=True),
    theta_step=Setting(1.0 * DEG, "grid step of theta (ours: 1 deg)", "rad", low=0, low_open=True),
    omega_step=Setting(0.5 * DEG, "grid step of omega (ours: 0.5 deg/s)", "rad/s", low=0, low_open=True),
    horizon=Setting(10, "predicted steps n of a candidate track (ours)", "steps", low=1, integer=True),
    fim_score=Setting("logdet", "J_FIM scores log det FIM (ours) or the paper's raw det", choices=urban.FIM_SCORES),
    planner=Setting("grid", "grid = the paper's search over constant (theta, omega); gradient = optax on the smooth "
                    "score of a constant command; sequence = optax on a command per horizon step (ours)",
                    choices=PLANNERS),
    plan_iterations=Setting(20, "gradient / sequence planner: Adam steps per re-plan", low=1, integer=True),
    plan_learning_rate=Setting(0.3, "gradient / sequence planner: Adam step, in units of one step's largest "
                               "command change", low=0, low_open=True),
    sequence_grid_stride=Setting(2, "sequence planner: its warm start's grid steps are theta_step and omega_step "
                                 "times this (ours; 1 = the grid planner's grid)", low=1, integer=True),
    init=Setting("first_bearing", "the filters' start: first_bearing = on the bearing measured at uav0, at a range "
                 "drawn with std prior_sigma (ours: bearings-only practice); prior = a point drawn with std prior_sigma "
                 "per axis about the emitter", choices=INITS),
    bound=kit_bound.SETTING,
    consistency=kit_consistency.SETTING,
), __name__, _check)


_POS = dict(low=0.0, low_open=True)
_PROB = dict(low=0.0, high=1.0)
#: Our building layout (the paper gives heights only): rows [x_lo, y_lo, x_hi, y_hi, height] in m, chosen by
#: the criterion of tests/scenarios/chen2022/test_layout.py (configs/chen2022.toml; the first layout is in
#: configs/chen2022_wide_prior.toml).
DEFAULT_BUILDINGS = np.array([[4950.0, 4650.0, 5050.0, 4750.0, 200.0],
                              [5270.0, 5300.0, 5400.0, 5400.0, 100.0]])
#: The IMM's chain from dwell times (benchmarks/papers/chen2022_dwell_times.py; configs/chen2022.toml).
_TRANSITION = np.array([[0.9819, 0.00905, 0.00905], [0.0676, 0.9324, 0.0], [0.0676, 0.0, 0.9324]])

#: Params: per-run values a sweep may vary without recompiling.
Params = params_type("Params", dict(
    speed=Param(25.0, "m/s", "UAV speed V (paper)", **_POS),
    theta_max=Param(5.0 * DEG, "rad", "largest |theta| (paper: 5 deg)", low=0.0, high=float(np.pi / 2)),
    omega_max=Param(8.0 * DEG, "rad/s", "largest |omega| (paper: 8 deg/s)", low=0.0),
    h_min=Param(100.0, "m", "lowest altitude (paper)", low=0.0),
    h_max=Param(400.0, "m", "highest altitude (paper)", low=0.0),
    emitter=Param(np.array([5000.0, 5000.0, 0.0]), "m", "the emitter's position (paper)", shape=(3,)),
    uav0=Param(np.array([0.0, 0.0, 200.0, 0.0]), "m, rad", "UAV start [x, y, z, heading] (paper)", shape=(4,)),
    buildings=Param(DEFAULT_BUILDINGS, "m", "boxes [x_lo, y_lo, x_hi, y_hi, height] (ours: layout; paper: "
                    "heights 100 and 200 m)"),
    R2=Param(0.5, "", "reflectance of the walls (paper)", **_PROB),
    power=Param(1.0, "W", "transmit power P (paper; scales every path alike)", **_POS),
    directivity=Param(1.0, "", "antenna directivity D (paper: omnidirectional)", **_POS),
    sigma_los=Param(0.2 * DEG, "rad", "LOS bearing noise std (paper: 0.2 deg)", **_POS,
                    high=float(np.pi)),
    sigma_nlos=Param(1.0 * DEG, "rad", "NLOS bearing noise std (paper: 1 deg)", **_POS,
                     high=float(np.pi)),
    bias_los=Param(0.0, "rad", "the LOS mode's bearing bias (paper: 0)", low=-np.pi, high=np.pi),
    bias_nlos=Param(20.0 * DEG, "rad", "the NLOS modes' bearing bias +/- (paper: 20 deg)", low=0.0, high=np.pi),
    imm_transition=Param(_TRANSITION, "", "the IMM's mode transition matrix P(j | l), modes LOS, NLOS+, NLOS- "
                         "(ours: from dwell times)", **_PROB, shape=(3, 3)),
    mu0=Param(np.array([0.8, 0.1, 0.1]), "", "the IMM's initial mode probabilities (ours)", **_PROB, shape=(3,)),
    prior_sigma=Param(1000.0, "m", "std of the initial estimate about the emitter per axis; the initial FIM "
                      "is its inverse square (ours)", **_POS),
    process_noise=Param(0.0, "m", "std of the filters' random walk per step (paper: none)", low=0.0),
    max_hold_steps=Param(0, "steps", "most steps in a row the shadow's hold may last, then the planner flies "
                         "(ours; 0 = no limit, the paper's rule)", low=0, integer=True),
    c1=Param(0.2, "", "weight of J_FIM (paper: 0.2)", label="weight c1 (FIM)"),
    c2=Param(0.5, "", "weight of J_T, steps clear of buildings and shadow (paper: 0.5)",
             label="weight c2 (clear steps)"),
    c3=Param(-0.3, "", "weight of J_NLOS, steps in the reflection region (paper: -0.3)",
             label="weight c3 (NLOS steps)"),
    plan_temperature=Param(20.0, "m", "temperature of the smooth indicators (gradient planner)", **_POS),
), __name__)


def check_params(cfg, values: dict) -> list[tuple[str, str]]:
    """Checks across fields and of the building layout: ``[(field, what is allowed), …]``."""
    def get(name):
        return kit.param_value(Params, cfg, values, name)

    bad = []
    boxes = get("buildings")
    layout_ok = boxes.ndim == 2 and boxes.shape[1] == 5 and np.all(np.isfinite(boxes))
    if not layout_ok:
        bad.append(("buildings", "a list of boxes [x_lo, y_lo, x_hi, y_hi, height] (m)"))
    else:
        degenerate = np.nonzero((boxes[:, 0] >= boxes[:, 2]) | (boxes[:, 1] >= boxes[:, 3]) | (boxes[:, 4] <= 0))[0]
        if degenerate.size:
            bad.append(("buildings", f"boxes with x_lo < x_hi, y_lo < y_hi and height > 0 (box(es) "
                        f"{degenerate.tolist()} are degenerate)"))
    h_min, h_max = get("h_min"), get("h_max")
    if np.any(h_min >= h_max):
        bad.append(("h_min", "an altitude below h_max"))
    uav0 = get("uav0")
    if np.any((uav0[..., 2] < h_min) | (uav0[..., 2] > h_max)):
        bad.append(("uav0", "a start altitude within [h_min, h_max]"))
    if layout_ok and not bad:
        b = buildings_np(boxes)
        for name, point in (("emitter", get("emitter")), ("uav0", uav0[..., :3])):
            if np.any(np.asarray(env.inside(b, point))):
                bad.append((name, "a point outside every building (boxes are closed: walls and roofs count)"))
    for name in ("imm_transition",):
        m = get(name)
        if np.any(np.abs(m.sum(-1) - 1.0) > 1e-9):
            bad.append((name, "a 3x3 matrix whose rows (from LOS, NLOS+, NLOS-) sum to 1"))
    if np.any(np.abs(get("mu0").sum(-1) - 1.0) > 1e-9):
        bad.append(("mu0", "three probabilities [LOS, NLOS+, NLOS-] that sum to 1"))
    return bad


def buildings_np(boxes) -> env.Buildings:
    """A building layout ``[x_lo, y_lo, x_hi, y_hi, height]`` rows as numpy :class:`~.environment.Buildings`."""
    boxes = np.asarray(boxes, np.float64)
    return env.Buildings(boxes[:, 0:2], boxes[:, 2:4], boxes[:, 4])


def buildings_of(params) -> env.Buildings:
    """The Params' building layout as :class:`~.environment.Buildings` (arrays of its dtype)."""
    b = params.buildings
    return env.Buildings(b[:, 0:2], b[:, 2:4], b[:, 4])
