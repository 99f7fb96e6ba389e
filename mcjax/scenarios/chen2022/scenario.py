"""One UAV localises a static radio emitter among buildings by its azimuth — Chen & Hao 2022.

A fixed-wing UAV (eq. 1, limits of eq. 4 and Alg. 1) measures only the azimuth of a ground
emitter. Buildings (axis-aligned boxes) hide the emitter (shadow: no measurement) or
reflect its signal (NLOS: the measured azimuth is the direction of the summed field of the
direct and the reflected paths, eqs. 5–6, so it is biased towards the mirror images). The
UAV runs an IMM-EKF over three measurement modes — LOS (bias 0, σ 0.2°) and NLOS ± (bias
±20°, σ 1°), eqs. 11–12 — and every step picks its command (θ, ω) from a grid by the track
score ``c1 J_FIM + c2 J_T + c3 J_NLOS`` (eqs. 13–20, :mod:`.score`, :mod:`.planner`). In the
shadow it holds its previous command (the paper's rule), as long as that stays admissible and (ours,
``max_hold_steps`` > 0) at most that many steps in a row. The filters start on the first measured
bearing (``Config.init = "first_bearing"``, ours) or from an isotropic prior (``"prior"``).

Filters (``Config.filters``): ``"imm"`` — the paper's 3-mode IMM-EKF, which the planner
uses; ``"ekf"`` — a single EKF that assumes line of sight (ours: what the IMM buys). The
error of a filter is the horizontal distance of its estimate from the emitter; the mean of
the last step's error over runs is the paper's "RMSE" of eq. 23 (Table 1).

Units are SI (m, s, rad). The paper's values, and our choices where it is silent, are
listed in ``configs/chen2022.toml``.
"""

from mcjax.contract import FAST_COMPILE, Scenario
from mcjax.contract.relaxation import Relaxation
from mcjax.scenarios import kit
from mcjax.scenarios.chen2022.params import Config, NAME, Params, check_params
from mcjax.scenarios.chen2022.readout import series, summary, training_weights
from mcjax.scenarios.chen2022.relaxation import Temperatures
from mcjax.scenarios.chen2022.step import init, step


SCENARIO = Scenario(
    name=NAME, title="Chen & Hao 2022: one UAV localises an emitter among buildings by azimuth (IMM-EKF, FIM "
    "planning)", Config=Config, Params=Params, init=init, step=step, summary=summary, series=series,
    check_params=check_params,
    # rough: max_hold_steps (a step count; the soft hold has no limit), plan_temperature (only the exact
    # gradient planner's smooth objective reads it; the smooth system's soft grid does not)
    relaxation=Relaxation(Temperatures, kit.training_errors, training_weights, ("max_hold_steps", "plan_temperature")),
    compiler_options=FAST_COMPILE,
    filter_names={"imm": "IMM-EKF", "ekf": "EKF"},
    filter_words={
        "imm": "Chen & Hao 2022's IMM-EKF over three measurement modes (line of sight, and reflected paths "
               "biased either way); the planner steers by it",
        "ekf": "a single extended Kalman filter that assumes every bearing has line of sight (what the IMM buys)"})
#: The default Params and the record's derived functions (of :func:`summary`, :func:`series`), by their usual names.
default_params, reduce, outputs, timeseries, timeseries_outputs = kit.aliases(SCENARIO)
