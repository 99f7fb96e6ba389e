"""Lou, Cui & Li 2013's flock (:mod:`.scenario`): its Config and Params, their checks, and the
lattice start's sites."""

from __future__ import annotations

import math

import numpy as np

from mcjax.contract import Param, Setting, config_type, params_type
from mcjax.scenarios import kit
from mcjax.scenarios.kit import bound as kit_bound
from mcjax.scenarios.kit import consistency as kit_consistency
from mcjax.scenarios.kit import faults
from mcjax.tracking.filters.consensus import KCF_GAINS
from mcjax.tracking.filters.registry import get
from mcjax.tracking.filters.steps import delayed_sender

NAME = "flocking"
FILTER_KINDS = ("kcf", "local", "ci", "hcmci")
#: The filters run by default: the paper's (the robust "ci" and "hcmci" are opt-in names).
PAPER_FILTERS = ("kcf", "local")
FILTER_NODES = ("sensing", "all")
CONTROL_REFERENCES = ("estimate", "truth")
TARGET_PATHS = ("sine", "line")
START_LAYOUTS = ("uniform", "lattice")
INTEGRATORS = ("dopri5", "rk4")


def _check(cfg) -> None:
    kit.check_common(cfg)

    def names(filters) -> str:  # as the datasets show them (a filter of one's own by its record's name)
        return kit.shown_filter_names(filters, FILTER_KINDS)

    robust = [f for f in cfg.filters if get(f).traits.weights == "doubly_stochastic"]
    if robust and cfg.filter_nodes != "all":
        raise ValueError(f"filter_nodes must be 'all' with the filters {names(robust)}: they need doubly stochastic "
                         f"weights (traits.weights = 'doubly_stochastic'), and take the weights' average as the "
                         f"whole flock's, which holds only when every node runs the filter; with filter_nodes = "
                         f"'sensing' the type-II nodes run none and sit in the consensus as isolated nodes; got "
                         f"filter_nodes = {cfg.filter_nodes!r}")
    early = [f for f in cfg.filters if not get(f).traits.late_messages]
    if early and cfg.message_delay > 0:
        raise ValueError(f"message_delay must be 0 with the filters {names(early)}: they take no late messages "
                         f"(traits.late_messages = False: they average this step's information, which a late "
                         f"message cannot join); got {cfg.message_delay}")
    if cfg.message_delay > 0:
        delayed_sender(cfg.filters)  # one mailbox
    if cfg.message_delay > 0 and cfg.kcf_gain == "prior_consensus":
        raise ValueError("kcf_gain must be mu_P or gamma_M when message_delay > 0 (prior_consensus averages "
                         "this step's priors); got 'prior_consensus'")


Config = config_type("Config", dict(
    **kit.common_settings(filter_kinds=FILTER_KINDS, plugin_filters=True, filters=PAPER_FILTERS, n_agents=20,
                          n_steps=300, min_steps=2, warmup_steps=20, divergence_threshold=5.0),
    max_substeps=Setting(200, "most sub-steps per step (dopri5: attempts, rejected ones included; rk4: each "
                         "sized from the flock's stiffness and closing speeds) (ours)", low=1, integer=True),
    integrator=Setting("dopri5", "dopri5 = Dormand-Prince 5(4) pair with step-size control at tolerance; rk4 = "
                       "classical RK4 sub-steps sized for stability at substep_safety (before issue 37) (ours)",
                       choices=INTEGRATORS),
    tolerance=Setting(1e-6, "dopri5: bound on each sub-step's error estimate, absolute, per position (m), "
                      "velocity (m/s) and gain b_ij (1/s) component (ours)", "m, m/s", low=0.0, low_open=True),
    filter_nodes=Setting("sensing", "nodes that run a filter and join its consensus: sensing = type I only "
                         "(paper), all = type II too (with no measurement)", choices=FILTER_NODES),
    control_reference=Setting("estimate", "what type-I nodes steer to: their KCF estimate (paper) or the true "
                              "target (the ideal case of Theorem 2)", choices=CONTROL_REFERENCES),
    target_path=Setting("sine", "sine = along y = sin x (paper); line = straight along x at constant speed",
                        choices=TARGET_PATHS),
    kcf_gain=Setting("mu_P", "KCF consensus gain: mu_P = Lou et al. 2013 Alg. 1; gamma_M = Olfati-Saber 2009",
                     choices=KCF_GAINS),
    start_attempts=Setting(64, "initial draws tried per run before the run is flagged", low=1, integer=True),
    start_layout=Setting("uniform", "initial positions: uniform = U[0, box]^2 (paper); lattice = a square lattice "
                         "of lattice_spacing jittered by lattice_jitter (ours: a valid start for any n_agents)",
                         choices=START_LAYOUTS),
    bound=kit_bound.SETTING,
    consistency=kit_consistency.SETTING,
    **faults.SETTINGS,
    **faults.DELAY_SETTINGS,
), __name__, _check)


def _default_m(cfg):
    return float(max(1, cfg.n_agents // 2))


_POS = dict(low=0.0, low_open=True)
Params = params_type("Params", dict(
    dt=Param(0.1, "s", "sampling step of the filters and the controllers (ours)", **_POS),
    R=Param(8.4, "m", "communication radius (paper)", **_POS, label="comm radius R"),
    epsilon=Param(0.4, "m", "hysteresis: a new link forms below R - epsilon (ours)", **_POS),
    n_sensing=Param(_default_m, "", "M, the number of type-I (sensing) nodes (paper: 10 of 20)", low=1.0,
                    integer=True, label="sensing nodes M"),
    c1=Param(1.0, "1/s^2", "position gain of eq. 10 (ours)", **_POS),
    c2=Param(2.0, "1/s", "velocity gain of eq. 10; also l of eqs. 15-16 (ours)", **_POS),
    k=Param(0.1, "", "adaptation rate k_ij of eq. 11 (ours, every pair; see configs/lou2013.toml)", **_POS),
    target_speed=Param(1.0, "m/s", "the target's speed along x (ours)", **_POS),
    sigma_meas=Param(0.1, "m", "position measurement noise std per axis (ours)", **_POS),
    sigma_accel=Param(1.0, "m/s^2", "the filters' CV process noise std (ours)", **_POS),
    kcf_epsilon=Param(0.1, "", "KCF consensus step epsilon of Alg. 1 (ours)", **_POS),
    p0_diag=Param(np.array([0.1, 0.1, 0.1, 0.1]), "m^2, (m/s)^2", "prior variances; the filters start at the "
                  "true state (paper: x(0))", **_POS, shape=(4,)),
    box=Param(8.0, "m", "initial positions U[0, box]^2 (paper: 8)", **_POS),
    v0=Param(0.1, "m/s", "initial velocities U[0, v0]^2 (paper: 0.1)", low=0.0),
    start_margin=Param(0.2, "m", "no pair may start in [R - start_margin, R) (ours)", low=0.0),
    substep_safety=Param(1.0, "", "sub-step h = safety x min(1/sqrt(stiffness), 1/damping, half a gap / "
                         "closing speed) (ours)", **_POS),
    start_min_distance=Param(0.3, "m", "no two nodes may start closer than this (ours; the paper's Fig. 6 "
                             "starts near 0.3)",
                             low=0.0),
    lattice_spacing=Param(1.75, "m", "start_layout = lattice: the lattice's spacing (ours: about the paper's "
                          "density; with R = 8.4 no lattice distance falls near R)", **_POS),
    lattice_jitter=Param(0.1, "m", "start_layout = lattice: each node moves by U[-jitter, jitter]^2 from its "
                         "site (ours)", low=0.0),
    **faults.PARAMS,
), __name__)


def check_params(cfg, values: dict) -> list[tuple[str, str]]:
    def get(name):
        return kit.param_value(Params, cfg, values, name)

    bad = []
    if np.any(get("n_sensing") > cfg.n_agents):
        bad.append(("n_sensing", f"an integer in [1, n_agents = {cfg.n_agents}]"))
    if np.any(get("epsilon") >= get("R")):
        bad.append(("epsilon", "in (0, R): new links form below R - epsilon"))
    if np.any(get("start_margin") >= get("R")):
        bad.append(("start_margin", "in [0, R)"))
    if cfg.start_layout == "lattice":
        args = (get("R"), get("start_margin"), get("start_min_distance"))
        if not np.all(_lattice_valid(cfg.n_agents, get("lattice_spacing"), 0.0, *args)):
            bad.append(("lattice_spacing", "such that every pair of lattice sites is either below R - start_margin "
                        "or at R or beyond, neighbours below R - start_margin and at least start_min_distance apart "
                        "(start_layout = lattice)"))
        elif not np.all(_lattice_valid(cfg.n_agents, get("lattice_spacing"), get("lattice_jitter"), *args)):
            bad.append(("lattice_jitter", "small enough that no jittered lattice pair can start in [R - start_margin, "
                        "R), neighbours stay below R - start_margin and at least start_min_distance apart "
                        "(start_layout = lattice)"))
    return bad + faults.check(cfg, values, Params)


def lattice_sites(n: int) -> np.ndarray:
    """The sites of ``start_layout = "lattice"`` in units of the spacing, (n, 2): row by row
    on a grid of ``ceil(sqrt(n))`` columns, cell centres from (0.5, 0.5). Filled row by row,
    every site but the first has a neighbour one unit away to its left or below it, so the
    sites' unit links form a connected graph."""
    cols = math.isqrt(max(n - 1, 0)) + 1
    i = np.arange(n)
    return np.stack([i % cols + 0.5, i // cols + 0.5], axis=1)


def _lattice_valid(n, spacing, jitter, R, margin, min_distance):
    """Whether every draw of the jittered lattice meets the start rule (:mod:`.scenario`), by
    bounds: each node moves at most ``sqrt(2)·jitter`` from its site, so a pair's distance
    lies within ``2·sqrt(2)·jitter`` of ``spacing`` times its sites' distance. Sufficient:
    the unit links stay below ``R - margin`` (the graph is connected, :func:`lattice_sites`),
    no pair's range meets ``[R - margin, R)``, and the shortest is ≥ ``min_distance``.
    Array arguments broadcast (sweep points); returns a boolean array."""
    if n < 2:
        return np.ones(np.broadcast(spacing, jitter, R, margin, min_distance).shape, bool)
    sites = lattice_sites(n)
    d0 = np.unique(np.round(np.sqrt(np.sum((sites[:, None] - sites[None]) ** 2, -1)), 12))
    d0 = d0[d0 > 0]
    s, spread, R, margin, dmin = (np.asarray(a, np.float64)[..., None] for a in
                                  (spacing, 2.0 * math.sqrt(2.0) * np.asarray(jitter), R, margin, min_distance))
    lo, hi = s * d0 - spread, s * d0 + spread
    outside = np.all((hi < R - margin) | (lo >= R), axis=-1)
    return outside & (s[..., 0] + spread[..., 0] < R[..., 0] - margin[..., 0]) & (lo[..., 0] >= dmin[..., 0])

