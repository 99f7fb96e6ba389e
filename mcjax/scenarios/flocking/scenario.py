"""A flocking mobile sensor network tracks a target with the Kalman-consensus filter — Lou,
Cui & Li 2013.

``N`` double-integrator nodes (eq. 1) in the plane follow a target moving along ``y = sin x``.
Only the first ``M`` (type I) measure the target's position; they estimate it with the
Kalman-consensus filter of Alg. 1 (``kcf``, the ``μ P`` gain form) and steer by their own
estimate (eq. 10). Type-II nodes run no filter and align their velocities through adaptive
gains (eq. 11). Every node feels the potential of eq. 12 from its neighbours in the
hysteresis graph (links form below ``R − ε`` and break only at ``R``), which should keep
every link and prevent collisions (Theorem 2). Each step of ``dt``:

1. the type-I nodes measure the target and run the filters over the graph of the nodes
   that run one (``Config.filter_nodes``);
2. the flock is integrated over ``dt`` at the current topology by the Dormand–Prince 5(4)
   pair with step-size control, each 0.1 s step's error within ``Config.tolerance`` (m, m/s;
   :func:`.dynamics.dopri5_adaptive`; ``Config.integrator = "rk4"``: the RK4 sub-steps sized
   from the flock's stiffness and closing speeds used before, :func:`.dynamics.rk4_adaptive`),
   at most ``Config.max_substeps`` sub-steps, each type-I node steering to its estimate
   extrapolated at constant velocity within the step;
3. the hysteresis graph is updated; links that broke (never expected) and sub-steps where
   a link reached ``R`` are counted and flag the run.

The initial flock is drawn inside the compiled program: positions U[0, box]², velocities
U[0, v0]² (the paper: box 8, v0 0.1), redrawn up to ``Config.start_attempts`` times until
the initial graph is connected, no pair sits within ``start_margin`` below R (the potential
is stiff there) and no two nodes are closer than ``start_min_distance``. A run whose draws
all fail is flagged (``start_failed``) and runs from its last draw. ``Config.start_layout =
"lattice"`` (ours, for scaling studies; not the paper's) places the nodes instead on a square
lattice of ``lattice_spacing`` jittered by U[−lattice_jitter, lattice_jitter]² per node
(:func:`lattice_sites`); :func:`check_params` rejects a spacing or jitter with which some
draw could break the rule above, and the same test still flags any draw that does.

Filters (``Config.filters``): ``kcf`` and ``local`` (each type-I node's standalone Kalman
filter: the paper's Fig. 2–3 baseline). Errors are the position errors of the type-I
nodes' estimates. Units: the paper's (m, s). Our choices where it is silent are marked in
``configs/lou2013.toml``.

Faults (:mod:`mcjax.scenarios.faults`, ``Config.faults = "on"``; ours, the paper has none).
The graph of the flocking control is the hysteresis graph of radius R, the same as the
filters'; its interactions — the potential of eq. 12 and the velocity alignment of eq. 11 —
are relative positions and velocities a node senses, not messages. So a *lost link* drops only
that step's KCF exchange (the neighbour's prior and measurement information), never a link of
the control; a *sensor dropout* leaves a type-I node without its measurement. A *lost node*
leaves the flock at once: it measures, sends and receives nothing, has no link of the graph
(so no neighbour feels its potential, and none forms with it later — kept, the potential's
barrier at R would tie the flock to a stopped node and break at R, which Theorem 2 excludes),
stops where it is, its filter states hold, and it leaves the error statistics, the energy of
eq. 15, the speed mismatch and the smallest distance. Its links' removal is not a link broken
(``edges_removed``). The fault counts count the links between filter nodes and the type-I
nodes' sensors. With ``Config.message_delay = k > 0`` the KCF's consensus messages arrive k
steps late (:func:`mcjax.filters.consensus.kcf_step`: the disagreement of k steps ago; the
neighbours' old measurement information is not fused); the control, sensed, is not delayed.
"""

from mcjax.contract import FAST_COMPILE, Scenario
from mcjax.scenarios import kit
from mcjax.scenarios.flocking.params import NAME, Config, Params, check_params
from mcjax.scenarios.flocking.readout import series, summary, training_weights
from mcjax.scenarios.flocking.smoothing import ROUGH, Smoothing
from mcjax.scenarios.flocking.step import init, sensing_mask, step  # sensing_mask: read here by benchmarks
from mcjax.smoothing import Smooth


SCENARIO = Scenario(
    name=NAME, title="Lou, Cui & Li 2013: a flocking sensor network tracks a target with the Kalman-consensus "
    "filter", Config=Config, Params=Params, init=init, step=step, summary=summary, series=series,
    check_params=check_params, smooth=Smooth(Smoothing, kit.training_errors, training_weights, ROUGH),
    compiler_options=FAST_COMPILE,
    # two of its programs running at once on two CPU devices wait for each other for good (XLA's CPU
    # runtime, its sub-steps in a data-dependent while loop): a sweep of four 100-run batches hung
    one_device=True,
    filter_words={
        "kcf": "Kalman-consensus filter of Lou, Cui & Li 2013 (Alg. 1): a local update with the neighbours' "
               "measurements plus a step towards their estimates",
        "local": "each node's own Kalman filter on its own measurements, nothing shared"})
default_params, reduce, outputs, timeseries, timeseries_outputs = kit.aliases(SCENARIO)
