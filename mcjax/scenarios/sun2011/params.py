"""Sun et al. 2011's leader–follower scenario: its Config (what fixes the compiled program), its
Params (per-run values a sweep may vary; the paper's numbers where it gives them, ours marked in
``configs/sun2011.toml``) and their checks."""

from __future__ import annotations

import numpy as np

from mcjax.contract import Param, Setting, config_type, params_type
from mcjax.tracking.filters.consensus import (CONTRIBUTION_KINDS, ICF_VARIANTS, KCF_GAINS, WEIGHT_KINDS,
                                              FilterOptions)
from mcjax.scenarios import kit
from mcjax.scenarios.kit import bound as kit_bound
from mcjax.scenarios.kit import consistency as kit_consistency
from mcjax.scenarios.kit import faults
from mcjax.scenarios.sun2011.objectives import ROBUSTNESS_PATHS, ROBUSTNESS_PENALTIES
from mcjax.scenarios.sun2011.planner import planner_options
from mcjax.tracking.filters.registry import FILTER_KINDS, get
from mcjax.tracking.filters.steps import delayed_sender

NAME = "leader_follower"

PLANNERS = ("none", "gradient", "random", "cem")
#: The filters run by default: the paper's five (the robust ones, "ci" and "hcmci", are opt-in names).
PAPER_FILTERS = ("cif", "icf", "modified_icf", "kcf", "local")
#: How the filters sum their neighbours' messages (Config.consensus_exchange); "auto" is sparse above
#: SPARSE_ABOVE UAVs. The default is "dense" for every team size: measured (docs/benchmarks.md, 2026-12-04),
#: the sparse exchange was slower at 20 and 50 UAVs and even at 100, and a UAV with more links than
#: consensus_neighbours slots turns NaN, a trap a default must not set.
EXCHANGES = ("dense", "sparse", "auto")
SPARSE_ABOVE = 20


def _check(cfg) -> None:
    kit.check_common(cfg)

    def names(filters) -> str:  # as the datasets show them (a filter of one's own by its record's name)
        return kit.shown_filter_names(filters, FILTER_KINDS)

    if cfg.planner != "none":
        if "modified_icf" not in cfg.filters:
            raise ValueError("filters must include 'modified_icf' when a planner is on: "
                             "the leader plans from its modified-ICF estimate (Sun et al. 2011, sec. 4)")
        planner_options(cfg)  # validates the planner budget
    robust = [f for f in cfg.filters if get(f).traits.consensus_only]
    if robust and cfg.consensus_steps < 1:
        raise ValueError(f"consensus_steps must be an integer >= 1 with the filters {names(robust)} (traits."
                         f"consensus_only: they fuse by consensus only); got {cfg.consensus_steps}")
    if cfg.message_delay > 0:
        other = [f for f in cfg.filters if not get(f).traits.late_messages]
        if other:
            late = [k for k in FILTER_KINDS if get(k).traits.late_messages]
            planner = ("; so the planner, which needs modified_icf, must be 'none'" if "modified_icf" in other
                       else "")
            raise ValueError(f"filters must be among {', '.join(late)} when message_delay > 0, or a filter whose "
                             f"traits.late_messages is True: {names(other)} take no late messages (they average "
                             f"this step's information, which a late message cannot join{planner}); got "
                             f"{names(other)}")
        delayed_sender(cfg.filters)  # one mailbox
        if cfg.kcf_gain == "prior_consensus":
            raise ValueError("kcf_gain must be gamma_M or mu_P when message_delay > 0 (prior_consensus averages "
                             "this step's priors); got 'prior_consensus'")


#: Config: everything that fixes shapes or the compiled program (changing it recompiles).
Config = config_type("Config", dict(
    **kit.common_settings(filter_kinds=FILTER_KINDS, plugin_filters=True, filters=PAPER_FILTERS, n_agents=5,
                          n_steps=200, warmup_steps=10, divergence_threshold=1000.0),
    consensus_steps=Setting(1, "consensus iterations L per step (paper: one message per comm interval)",
                            low=0, integer=True),
    consensus_weights=Setting("eq11", "consensus weights (eq11 = Sun et al. 2011 eq. 11)", choices=WEIGHT_KINDS),
    contribution=Setting("component", "weight of an agent's own measurement information (component = "
                         "by its component's size, ours; one = eq. 9 as printed)", choices=CONTRIBUTION_KINDS),
    icf_variant=Setting("contributions", "reading of the ICF (docs/equations.md)", choices=ICF_VARIANTS),
    kcf_gain=Setting("gamma_M", "KCF consensus gain form", choices=KCF_GAINS),
    consensus_exchange=Setting("dense", "how the filters sum their neighbours' messages: dense = over every UAV, n x n "
                               "matrices (cost ~ n^2); sparse = over neighbour lists of consensus_neighbours slots "
                               "(cost ~ links, ours; the same numbers to round-off; a UAV with more links than slots "
                               "makes its filters NaN, the run's nonfinite output); auto = dense up to 20 UAVs, "
                               "sparse above (not faster in our measurements: docs/benchmarks.md); the relaxation "
                               "switch's soft links join every pair: always dense",
                               choices=EXCHANGES),
    consensus_neighbours=Setting(24, "slots of a UAV's neighbour list in the sparse exchange: the most links a UAV "
                                 "may have (more: NaN)", low=1, integer=True),
    planner=Setting("none", "receding-horizon planner; none = open loop (every UAV holds heading_cmd)",
                    choices=PLANNERS),
    max_horizon=Setting(8, "steps the planning rollout runs; the horizon t_r (param horizon) <= this", "steps",
                        low=1, integer=True),
    plan_period=Setting(0, "tau_r fixed in the compiled program: the planner runs only on the steps it "
                        "re-plans (param replan_every must equal it); 0 = tau_r from the Params, free to vary "
                        "in a batch, at the cost of planning every step and keeping the due plans",
                        "steps", low=0, integer=True),
    plan_iterations=Setting(10, "gradient: Adam steps; cem: rounds", low=1, integer=True),
    plan_samples=Setting(256, "random / cem: plans scored per re-plan (cem: >= 2 per round)", low=2,
                         integer=True),
    plan_learning_rate=Setting(0.3, "Adam step on theta, u = tanh(theta)", low=0, low_open=True),
    plan_elite_fraction=Setting(0.1, "cem: fraction of each round refitted", low=0, high=1, low_open=True),
    plan_dtype=Setting("float64", "float type of the planner's problem (float32: solved in coordinates relative "
                       "to the leader's target estimate: the closed loop ran 1.2-1.7x faster; the filters, the "
                       "executed commands and the simulation stay in dtype)", choices=kit.DTYPES),
    robustness_penalty=Setting("barrier", "penalty of the connectivity robustness R_I (barrier = "
                               "softplus(-R_I/s), ours; inverse = the paper's 1/|R_I|)",
                               choices=ROBUSTNESS_PENALTIES),
    robustness_paths=Setting("auto", "how R_I is computed: all_pairs = widest path of every pair, O(n^3), smooth "
                             "by soft Floyd-Warshall; spanning_tree = the same exact R_I in O(n^2), smooth by a "
                             "softmin over a maximum spanning tree's links (a different surrogate, ours); auto = "
                             "all pairs up to 10 UAVs, the tree above", choices=ROBUSTNESS_PATHS),
    bound=kit_bound.SETTING,
    consistency=kit_consistency.SETTING,
    **faults.SETTINGS,
    **faults.DELAY_SETTINGS,
), __name__, _check)


def resolve_exchange(choice: str, n: int) -> str:
    """``"dense"`` or ``"sparse"``: ``Config.consensus_exchange`` for a team of ``n``."""
    if choice not in EXCHANGES:
        raise ValueError(f"consensus_exchange must be one of {', '.join(map(repr, EXCHANGES))}; got {choice!r}")
    return choice if choice != "auto" else ("sparse" if n > SPARSE_ABOVE else "dense")


def filter_options(cfg, smooth: bool = False) -> FilterOptions:
    """The filters' static options from the Config (``smooth``: the relaxation switch is on, whose soft
    links join every pair of UAVs: the dense exchange)."""
    exchange = "dense" if smooth else resolve_exchange(cfg.consensus_exchange, cfg.n_agents)
    return FilterOptions(cfg.consensus_steps, cfg.consensus_weights, cfg.contribution, cfg.icf_variant,
                         cfg.kcf_gain, exchange, cfg.consensus_neighbours)


def _paper_positions(cfg) -> np.ndarray:
    """The paper's five UAVs (sec. 5); extra followers spread behind the leader on a line (ours)."""
    n = cfg.n_agents
    paper = np.array([[20e3, 150e3], [80e3, 150e3], [130e3, 200e3], [130e3, 100e3], [180e3, 150e3]])
    if n <= 5:
        return paper[:n]
    extra = np.stack([np.full(n - 5, 20e3), 150e3 + 20e3 * np.arange(1, n - 4)], -1)
    return np.concatenate([paper, extra])


_POS = dict(low=0.0, low_open=True)
_NONNEG = dict(low=0.0)
_ANGLE = dict(low=-10.0, high=10.0)
#: Params: per-run values a sweep may vary without recompiling. Defaults are the paper's
#: (sec. 5) where it gives one; the others are ours (configs/sun2011.toml says why).
Params = params_type("Params", dict(
    dt=Param(1.0, "s", "radar sampling interval = comm interval (paper: 1 s)", **_POS),
    comm_radius=Param(100e3, "m", "communication radius (paper: 100 km)", **_NONNEG, per_agent=True, display="km",
                      label="comm radius"),
    sensing_radius=Param(120e3, "m", "radar range (paper: 120 km)", **_NONNEG, per_agent=True, display="km",
                         label="radar range"),
    sigma_range=Param(10.0, "m", "range noise std (paper: 10 m)", **_POS),
    sigma_bearing=Param(0.017, "rad", "bearing noise std (paper: 0.017 rad)", **_POS,
                        high=float(np.pi)),
    sigma_accel=Param(50.0, "m/s^2", "the filters' process-noise acceleration std (paper: 50)", **_NONNEG),
    target_sigma_accel=Param(5.0, "m/s^2", "the true target's acceleration noise std (ours)", **_NONNEG),
    uav_speed=Param(800.0, "m/s", "UAV airspeed (paper: 800 m/s)", **_NONNEG, per_agent=True),
    alpha_phi=Param(1.0, "1/s", "autopilot heading gain, eq. 3 (ours)", **_POS),
    turn_rate_max=Param(float(np.deg2rad(10.0)), "rad/s", "turn-rate limit, eq. 4 (ours)", **_NONNEG),
    heading_cmd=Param(float(np.arctan2(-1000.0, 200.0)), "rad", "held heading command (open loop only)",
                      **_ANGLE, per_agent=True),
    initial_positions=Param(_paper_positions, "m", "initial UAV positions (paper, sec. 5)", shape=("n", 2)),
    initial_headings=Param(0.0, "rad", "initial headings (ours)", **_ANGLE, per_agent=True),
    target_x0=Param(np.array([200e3, 200.0, 180e3, -1000.0]), "m, m/s", "initial target state [x, vx, y, vy]",
                    shape=(4,)),
    p0_diag=Param(np.array([100.0**2, 10.0**2, 100.0**2, 10.0**2]), "m^2, (m/s)^2",
                  "prior variances at the first measurement (ours)", **_POS, shape=(4,)),
    kcf_epsilon=Param(0.1, "", "KCF consensus gain epsilon (ours)", **_NONNEG),
    alive=Param(lambda cfg: np.ones(cfg.n_agents), "", "1 = alive, 0 = dropped out (masked, never removed)",
                choices=(0, 1), per_agent=True),
    alpha_I=Param(1000.0, "", "weight of the connectivity-robustness penalty (case 1 of Table 1: 0)", **_NONNEG,
                  label="robustness weight α_I"),
    alpha_C=Param(1.0, "1/rad", "weight of the control effort, eq. 17", **_NONNEG),
    alpha_L=Param(1e-4, "1/m", "weight of the distance to the target", **_NONNEG),
    alpha_S=Param(1e4, "", "weight of the D_safe / D_LT penalties, eqs. 18-19", **_NONNEG),
    d_safe=Param(1e3, "m", "D_safe, eq. 18", **_POS, display="km"),
    d_lt=Param(20e3, "m", "D_LT, eq. 19", **_POS, display="km"),
    robustness_scale=Param(5e3, "m", "s of the barrier softplus(-R_I/s)", **_POS, display="km"),
    plan_temperature=Param(1e3, "m", "temperature of the smooth cost (gradient planner)", **_POS),
    horizon=Param(5, "steps", "t_r, the planning horizon (paper: 5; <= max_horizon)", low=1, integer=True,
                  label="horizon t_r"),
    replan_every=Param(3, "steps", "tau_r, steps between re-plans (paper: 3; <= t_r)", low=1, integer=True),
    **faults.PARAMS,
), __name__)


def check_params(cfg, values: dict) -> list[tuple[str, str]]:
    """Checks across fields: ``[(field, what is allowed), …]`` for the bad ones.

    t_r (``horizon``) must be an integer in [1, max_horizon]; τ_r (``replan_every``) an
    integer in [1, t_r] (Sun et al. 2011, sec. 4.2: 1 ≤ τ_r ≤ t_r)."""
    bad = []
    table = Params.TABLE
    tr = np.asarray(values.get("horizon", table["horizon"].default), np.float64)
    tau = np.asarray(values.get("replan_every", table["replan_every"].default), np.float64)
    if np.any(tr != np.round(tr)) or np.any(tr < 1) or np.any(tr > cfg.max_horizon):
        bad.append(("horizon", f"an integer in [1, max_horizon = {cfg.max_horizon}]"))
    if np.any(tau != np.round(tau)) or np.any(tau < 1) or np.any(tau > tr):
        bad.append(("replan_every", "an integer in [1, horizon]"))
    elif cfg.plan_period > 0 and np.any(tau != cfg.plan_period):
        bad.append(("replan_every", f"equal to config.plan_period = {cfg.plan_period} (set plan_period = 0 "
                                    "to vary it)"))
    return bad + faults.check(cfg, values, Params)
