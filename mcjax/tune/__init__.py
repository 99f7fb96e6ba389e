"""Tune continuous Params by gradient through the whole closed loop (``mcjax tune``).

A tune spec is a sweep spec (``base``, ``[config]``, ``[params]``, ``chunk_size``,
``description``; no ``[grid]``, ``[zip]``, ``seeds`` or ``base_seed``) with a ``[tune]`` table::

    [tune]
    optimizer = "adam"          # an optax optimiser (OPTIMIZERS), called with learning_rate
    learning_rate = 0.1         # in the unconstrained coordinates z (see Bound)
    steps = 30                  # optimisation steps
    train_seeds = 128           # runs per loss evaluation: seeds 0..N-1 of train_base_seed,
    train_base_seed = 1         #   the same every step (common random numbers)
    heldout_seeds = 1000        # evaluation of the initial and the final Params (exact simulation)
    heldout_base_seed = 0       #   must differ from train_base_seed
    checkpoint_every = 10       # simulation steps per jax.checkpoint block (memory vs recompute)
    gradient_window = 0         # truncate the gradient to windows of this many steps (0: the whole run)
    [tune.params.alpha_I]       # one table per tuned Param: bounds, scale, optional initial value
    low = 10.0
    high = 1e5
    scale = "log"               # "linear" or "log" (low > 0)
    [tune.loss]                 # the training loss (Loss)
    filter = "modified_icf"
    [tune.relaxation]           # temperatures of the scenario's relaxation switch (Relaxation.Temperatures;
                                # [tune.smoothing], its former name, is still read)

**The training loss** of a run is ``rmse_c / c + w · sigmoid((smax − D)/τ)``: ``rmse_c`` the
RMS over steps after warm-up and alive agents of the softly clipped error ``c·tanh(e/c)`` of the
chosen filter, ``smax = τ_m·logsumexp(e/τ_m)`` a soft maximum of the same errors (≥ their max,
by at most ``τ_m·log N``), ``D`` the scenario's ``divergence_threshold`` — so the second term is
a soft version of the divergence flag. The loss of a batch is the mean over its runs. Runs use
the scenario's step with its relaxation switch on (:class:`mcjax.contract.relaxation.Relaxation`) and the
engine's keys (run ``i`` of base seed ``b`` draws what ``mcjax sweep`` draws for seed ``i``).

**Gradients** go through every step: dynamics, sensing, filters and the planner's unrolled
Adam (which differentiates its own smooth cost, so the tune's derivative is of second order).
``gradient = "forward"`` (default) pushes one tangent per tuned Param forward with the run
(``jax.jacfwd``): memory does not grow with the number of steps, and for the few Params a
tune has it compiles several times faster than reverse mode on this code (measured: 2.5 vs
12 min for the 20-step closed loop, docs/tune.md). ``gradient = "reverse"`` is one backward
pass (``jax.grad``) with ``jax.checkpoint`` over blocks of ``checkpoint_every`` steps, so
memory holds one block's intermediates plus a state per block rather than every step's. Each run's gradient is
computed on its own; a run whose loss or gradient is not finite is left out of the mean (the
trace counts them). ``gradient_window = K`` truncates the derivative to windows of K steps
(:func:`run_loss`): biased, but it does not grow exponentially with the run's length as the
full derivative of the chaotic closed loop does (docs/tune.md).

**Bounds** (:class:`Bound`): a Param ``x`` in ``(low, high)`` is optimised as ``z`` with
``x = low + (high − low)·sigmoid(z)`` (``scale = "linear"``) or
``log x = log low + (log high − log low)·sigmoid(z)`` (``"log"``), so every step stays inside.

The package: :mod:`mcjax.tune.spec` reads the spec (:func:`load_tune_spec`);
:mod:`mcjax.tune.loss` holds the loss and its gradient (:func:`run_loss`,
:func:`batch_function`, :class:`Evaluator`); :mod:`mcjax.tune.optimise` the optimisation loop
with its atomic per-step state (:func:`optimise`) and the held-out evaluation in the sweep's
format (:func:`evaluation_spec`); :mod:`mcjax.tune.runner` runs a spec into its folder as ``mcjax tune``
does (:func:`run_tune`), reporting through callbacks. Its output folder is kept by :mod:`mcjax.study.store`.
"""


from mcjax.tune.loss import (RUNS_PER_DEVICE, Evaluation, Evaluator, batch_function, params_at, program_key,
                             run_loss, train_keys)
from mcjax.study.store import TUNE_IDENTITY_FILE as IDENTITY_FILE
from mcjax.study.store import prepare_evaluation
from mcjax.tune.optimise import (ROLE_COLUMN, ROLES, STATE_FILE, TRACE_FILE, RoleExecutor, evaluation_spec,
                                 final_values, finished, identity, load_state, make_optimizer, optimise,
                                 paired_differences, plot_trace, prepare_tune_output, run_evaluation, save_state,
                                 summary_text, trace_columns, with_role, write_failures_end_the_command)
from mcjax.tune.spec import (BOUND_KEYS, GRADIENT_MODES, LOSS_KEYS, MAX_STEPS, MAX_TRAIN_SEEDS, NONFINITE_ERROR,
                             OPTIMIZERS, SCALES, SHARED_KEYS, TUNE_KEYS, Bound, Loss, TuneSpec, build_tune_spec,
                             continuous_params, from_unconstrained, load_tune_spec, to_unconstrained)
from mcjax.tune.runner import TuneProgress, TuneResult, run_tune, tune_headline

__all__ = [
    "RUNS_PER_DEVICE", "Evaluation", "Evaluator", "batch_function", "params_at", "program_key", "run_loss",
    "train_keys", "IDENTITY_FILE", "ROLE_COLUMN", "ROLES", "STATE_FILE", "TRACE_FILE", "RoleExecutor",
    "evaluation_spec", "final_values", "finished", "identity", "load_state", "make_optimizer", "optimise",
    "paired_differences", "plot_trace", "prepare_evaluation", "prepare_tune_output", "run_evaluation", "save_state",
    "summary_text",
    "trace_columns", "with_role", "write_failures_end_the_command", "BOUND_KEYS", "GRADIENT_MODES", "LOSS_KEYS", "MAX_STEPS",
    "MAX_TRAIN_SEEDS", "NONFINITE_ERROR", "OPTIMIZERS", "SCALES", "SHARED_KEYS", "TUNE_KEYS", "Bound", "Loss",
    "TuneSpec", "build_tune_spec", "continuous_params", "from_unconstrained", "load_tune_spec", "to_unconstrained",
    "TuneProgress", "TuneResult", "run_tune", "tune_headline",
]
