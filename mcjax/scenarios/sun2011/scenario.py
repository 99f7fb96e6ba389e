"""Leader–follower UAV team tracking a CV target — Sun et al. 2011.

One leader (agent 0) and four followers with range–bearing radars (sensing radius 120 km)
and a 100 km comm range track a constant-velocity target. Each step records, for every
filter, each agent's position error and NEES, plus λ2, degrees, connectivity robustness R_I
and how many agents see the target.

``Config.planner = "none"`` is the open loop: every UAV holds ``Params.heading_cmd``.
Otherwise the loop is closed as in Sun et al. 2011 §4: every τ_r steps (``Params.replan_every``)
the leader plans the headings of all UAVs over the horizon t_r (``Params.horizon``) from
its own modified-ICF estimate and the UAV states it knows, minimising eq. 16 with eqs.
18–19 as penalties (:mod:`.planner`, :mod:`.horizon`, :mod:`.objectives`), and the UAVs fly
the first τ_r commands.

Units are SI (m, s, rad). Defaults are the paper's numbers; the values the paper leaves
open are our choices, marked in ``configs/sun2011.toml``.
"""

from __future__ import annotations

import jax.numpy as jnp

from mcjax.contract import FAST_COMPILE, Output, Scenario, declare
from mcjax.contract.relaxation import Relaxation
from mcjax.scenarios import kit
from mcjax.scenarios.kit import bound as pcrb
from mcjax.scenarios.kit import consistency
from mcjax.scenarios.kit import faults
from mcjax.scenarios.sun2011.params import Config, NAME, Params, check_params
from mcjax.scenarios.sun2011.step import ROUGH, Record, Temperatures, init, step
from mcjax.tracking import metrics


def summary(cfg, records: Record | None, params) -> dict:
    """One run's records (stacked over time) reduced to its outputs, each declared next to its
    value (:func:`mcjax.contract.declare`; ``records`` None: the declarations alone)."""
    r, w, F = records, cfg.warmup_steps, len(cfg.filters)
    switched_on, alive = kit.team_weights(cfg, params, r)
    return declare(
        **kit.error_items(lambda: r.error, alive, cfg, "m"),
        leader_rmse=(Output("m", "the leader's (agent 0) position RMSE after warm-up"),
                     lambda: jnp.stack([metrics.rmse(r.error[:, f, :1], w) for f in range(F)])),
        anees=(consistency.anees_output(4),
               lambda: jnp.stack([metrics.mean_over(faults.masked(r.nees[:, f, :], alive()), w, alive())
                                   for f in range(F)])),
        **kit.graph_items(lambda: r.lambda2),
        robustness_min=(Output("m", "smallest connectivity robustness R_I of any agent over the run", False),
                        lambda: jnp.min(r.robustness)),
        seeing_mean=(Output("", "mean number of agents that see the target", False),
                     lambda: jnp.mean(r.n_seeing.astype(r.lambda2.dtype))),
        seeing_min=(Output("", "fewest agents that see the target at any step", False), lambda: jnp.min(r.n_seeing)),
        plan_cost_mean=(Output("", "mean exact eq. 16 cost of the plans in force (0 in open loop)", False),
                        lambda: jnp.mean(r.plan_cost)),
        **faults.summary_items(cfg, r and r.faults, switched_on),
        **pcrb.summary_items(cfg, lambda: r.bound, w),
        **consistency.summary_items(cfg, lambda: r.nees, lambda: r.nis, alive, w, 4, 2, anees=False),
    )


def series(cfg, records: Record | None, params) -> dict:
    """A few per-step series of one run, (T, F) per filter, (T,) otherwise, each declared next
    to its value; written when a sweep asks for them."""
    r = records
    switched_on, alive = kit.team_weights(cfg, params, r)
    return declare(
        **kit.error_series_items(lambda: r.error, alive, "m"),
        leader_error=(Output("m", "the leader's (agent 0) position error"), lambda: r.error[..., 0]),
        lambda2=(Output("", "algebraic connectivity of the comm graph", False), lambda: r.lambda2),
        robustness_min=(Output("m", "smallest connectivity robustness R_I", False),
                        lambda: jnp.min(r.robustness, -1)),
        n_seeing=(Output("", "agents that see the target", False), lambda: r.n_seeing),
        plan_cost=(Output("", "exact eq. 16 cost of the plan in force (0 in open loop)", False),
                   lambda: r.plan_cost),
        **faults.series_items(cfg, r and r.faults, switched_on),
        **pcrb.series_items(cfg, lambda: r.bound),
        **consistency.series_items(cfg, lambda: r.nees, lambda: r.nis, alive, 4, 2),
    )


#: Teams of at least this many UAVs compile without XLA's YNN reduction kernels (see
#: :func:`compiler_options`).
LARGE_TEAM = 64


def compiler_options(cfg):
    """XLA's older fusion emitters (:data:`mcjax.contract.FAST_COMPILE`) for every team; from
    :data:`LARGE_TEAM` UAVs also without XLA's YNN reduction kernels: at 100 UAVs the planner's
    gradient summed its pairwise terms in one YNN kernel that took ~27 % of a closed-loop run,
    which took 10–31 % less time without (docs/benchmarks.md, 2026-12-04). Smaller teams keep
    the program every built-in configuration was checked with (their golden rows): the option
    changes the order of the sums, so the last bits of the results."""
    if cfg.n_agents >= LARGE_TEAM:
        return {**FAST_COMPILE, "xla_cpu_experimental_ynn_fusion_type": ""}
    return FAST_COMPILE


SCENARIO = Scenario(
    name=NAME, title="Sun, Zhou, Zou & Ding 2011: leader-follower UAVs, consensus information filters, "
    "receding-horizon planning", Config=Config, Params=Params, init=init, step=step, summary=summary,
    series=series, check_params=check_params,
    relaxation=Relaxation(Temperatures, kit.training_errors, kit.training_weights, ROUGH),
    compiler_options=compiler_options,
    filter_names={"cif": "CIF", "icf": "ICF", "modified_icf": "modified ICF", "kcf": "KCF", "local": "local EKF",
                  "ci": "CI", "hcmci": "HCMCI"},
    headlines=(("modified_icf", "icf"),),  # the paper's point: the modified ICF beats the ICF
    filter_words={
        "cif": "centralised information filter: one filter fuses every UAV's measurements (the bound the "
               "distributed filters aim at)",
        "icf": "information consensus filter (Casbeer & Beard 2009): the UAVs average their new measurement "
               "information by consensus with their neighbours, then update",
        "modified_icf": "Sun et al. 2011's modified information consensus filter: each UAV adds its own "
                        "measurement information, then averages the whole information pair with its neighbours",
        "kcf": "Kalman-consensus filter (Olfati-Saber 2009): a local update with the neighbours' measurements "
               "plus a step towards their estimates",
        "local": "each UAV's own extended Kalman filter on its own measurements, nothing shared",
        "ci": "consensus on information (Battistelli & Chisci 2014): each UAV updates with its own measurement, "
              "then averages its information matrix and vector with its neighbours' — covariance intersection, "
              "so its covariance is never too small, at the price of diluting the new measurements",
        "hcmci": "hybrid consensus on measurements and information (Battistelli et al. 2015): each UAV averages "
                 "its neighbours' predictions and, separately, their new measurement information, then adds N "
                 "times the averaged measurements — the centralised filter once the averages converge"})
default_params, reduce, outputs, timeseries, timeseries_outputs = kit.aliases(SCENARIO)
