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
    [tune.smoothing]            # temperatures of the scenario's smooth surrogates (Surrogate.Smoothing)

**The training loss** of a run is ``rmse_c / c + w · sigmoid((smax − D)/τ)``: ``rmse_c`` the
RMS over steps after warm-up and alive agents of the softly clipped error ``c·tanh(e/c)`` of the
chosen filter, ``smax = τ_m·logsumexp(e/τ_m)`` a soft maximum of the same errors (≥ their max,
by at most ``τ_m·log N``), ``D`` the scenario's ``divergence_threshold`` — so the second term is
a soft version of the divergence flag. The loss of a batch is the mean over its runs. Runs use
the scenario's :class:`~mcjax.contract.Surrogate` (smooth sensing gate and comm graph) and the
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

This module holds the spec reader (:func:`load_tune_spec`), the loss and its gradient
(:func:`loss_and_grad`), the optimisation loop with its atomic per-step state
(:func:`optimise`) and the held-out evaluation in the sweep's format (:func:`evaluate`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, NamedTuple

import numpy as np
import pandas as pd

from mcjax import scenarios
from mcjax.sweep import (MAX_BASE_SEED, MAX_SEEDS, SpecError, SweepSpec, _check_keys, _count, _is_number,
                         _read_toml, _show, _suggest, build_spec, is_config_file)

#: optax optimisers a spec may name (each is called as ``optax.NAME(learning_rate)``).
OPTIMIZERS = ("adam", "adamw", "sgd", "rmsprop", "adagrad", "adabelief", "lamb", "lion", "nadam", "radam",
              "yogi", "adamax", "amsgrad", "novograd")
SCALES = ("linear", "log")
TUNE_KEYS = ("optimizer", "learning_rate", "steps", "train_seeds", "train_base_seed", "heldout_seeds",
             "heldout_base_seed", "gradient", "gradient_window", "checkpoint_every", "params", "loss", "smoothing")
#: How the gradient is computed: forward mode (one tangent per tuned Param, memory independent
#: of the number of steps) or reverse mode (one backward pass, memory bounded by jax.checkpoint).
GRADIENT_MODES = ("forward", "reverse")
BOUND_KEYS = ("low", "high", "scale", "initial")
LOSS_KEYS = ("filter", "error_scale", "divergence_weight", "divergence_temperature", "max_temperature")
#: The keys of a sweep spec a tune spec takes (plus ``tune``); seeds come from ``[tune]``.
SHARED_KEYS = ("scenario", "base", "chunk_size", "config", "params", "description")
MAX_STEPS = 100_000
MAX_TRAIN_SEEDS = 100_000
#: What an error that is not finite counts as, in units of the error scale c.
NONFINITE_ERROR = 1e3


class Bound(NamedTuple):
    """One tuned Param: bounds, scale of the transform, initial value (all floats)."""

    name: str
    low: float
    high: float
    scale: str
    initial: float


class Loss(NamedTuple):
    """The training loss (see the module docstring); lengths in the error's unit."""

    filter: str
    error_scale: float             # c, the soft clip c·tanh(e/c)
    divergence_weight: float       # w
    divergence_temperature: float  # τ of sigmoid((smax − D)/τ)
    max_temperature: float         # τ_m of the soft maximum
    divergence_threshold: float    # D (the Config's)
    warmup_steps: int


@dataclass(frozen=True)
class TuneSpec:
    """A validated tune spec: the shared sweep part (:class:`~mcjax.sweep.SweepSpec`, its
    ``base_params`` holding the initial values) and the ``[tune]`` table."""

    sweep: SweepSpec
    bounds: tuple
    loss: Loss
    smoothing: Any
    optimizer: str = "adam"
    learning_rate: float = 0.1
    steps: int = 30
    train_seeds: int = 128
    train_base_seed: int = 1
    heldout_seeds: int = 1000
    heldout_base_seed: int = 0
    checkpoint_every: int = 10
    gradient: str = "forward"
    gradient_window: int = 0
    source: dict = dataclasses.field(default_factory=dict)
    base_dir: str = "."

    @property
    def names(self) -> list[str]:
        return [b.name for b in self.bounds]

    def initial(self) -> np.ndarray:
        return np.array([b.initial for b in self.bounds])


# ------------------------------------------------------------------ transforms


def to_unconstrained(bounds, x) -> np.ndarray:
    """``z`` of Params values ``x`` (inverse of :func:`from_unconstrained`; numpy)."""
    out = []
    for b, v in zip(bounds, np.asarray(x, np.float64)):
        if b.scale == "log":
            s = (math.log(v) - math.log(b.low)) / (math.log(b.high) - math.log(b.low))
        else:
            s = (v - b.low) / (b.high - b.low)
        out.append(math.log(s) - math.log1p(-s))
    return np.array(out)


def from_unconstrained(bounds, z):
    """Params values of the unconstrained ``z`` (P,): ``low + (high − low)·sigmoid(z)``, or the
    same in log space for a ``"log"`` scale (traceable: JAX arrays in, JAX arrays out)."""
    import jax
    import jax.numpy as jnp

    out = []
    for i, b in enumerate(bounds):
        s = jax.nn.sigmoid(z[i])
        if b.scale == "log":
            out.append(jnp.exp(math.log(b.low) + (math.log(b.high) - math.log(b.low)) * s))
        else:
            out.append(b.low + (b.high - b.low) * s)
    return jnp.stack(out)


# ------------------------------------------------------------------ spec


def _number(where: str, value, *, positive: bool = False, nonneg: bool = False) -> float:
    if not _is_number(value) or not math.isfinite(value) or (positive and value <= 0) or (nonneg and value < 0):
        what = "a number > 0" if positive else "a number >= 0" if nonneg else "a finite number"
        raise SpecError(f"{where}: must be {what}; got {_show(value)}")
    return float(value)


def _tune_table(where: str, table: dict, key: str) -> dict:
    value = table.get(key, {})
    if not isinstance(value, dict):
        raise SpecError(f"{where}{key}: must be a table ([{where}{key}]); got {_show(value)}")
    return value


def _bound(scenario, cfg, base_params, name: str, table) -> Bound:
    where = f"tune.params.{name}"
    if name not in scenario.params_table:
        if name in scenario.settings:
            raise SpecError(f"{where}: {name} is a Config field (fixed in the compiled program), not a Param; only "
                            f"continuous Params can be tuned")
        raise SpecError(f"{where}: unknown Param{_suggest(name, list(scenario.params_table))}; allowed: continuous "
                        f"scalar Params of {scenario.name} ({', '.join(continuous_params(scenario, cfg))})")
    p = scenario.params_table[name]
    if p.integer or p.choices is not None:
        raise SpecError(f"{where}: {name} is not continuous (it takes {p.allowed()}); only continuous Params can be "
                        f"tuned ({', '.join(continuous_params(scenario, cfg))})")
    if np.ndim(getattr(base_params, name)) != 0 or p.shape is not None or (not p.per_agent and not p.scalar(cfg)):
        raise SpecError(f"{where}: {name} is an array here; only Params with one number can be tuned")
    if not isinstance(table, dict):
        raise SpecError(f"{where}: must be a table {{low = ..., high = ..., scale = \"linear\"|\"log\"}}; "
                        f"got {_show(table)}")
    _check_keys(f"{where}.", table, BOUND_KEYS)
    for k in ("low", "high"):
        if k not in table:
            raise SpecError(f"{where}.{k}: missing; give the bounds low < high")
    low, high = _number(f"{where}.low", table["low"]), _number(f"{where}.high", table["high"])
    if not low < high:
        raise SpecError(f"{where}: bounds reversed or empty: low must be < high; got low = {low:g}, high = {high:g}")
    for k, v in (("low", low), ("high", high)):
        msg = p.problem(v)
        if msg:
            raise SpecError(f"{where}.{k}: {msg} (the Param's allowed range)")
    scale = table.get("scale", "linear")
    if scale not in SCALES:
        raise SpecError(f"{where}.scale: must be one of {', '.join(SCALES)}; got {_show(scale)}")
    if scale == "log" and low <= 0:
        raise SpecError(f"{where}.low: must be > 0 for scale = \"log\"; got {low:g}")
    if "initial" in table:
        initial = _number(f"{where}.initial", table["initial"])
        origin = f"{where}.initial: must lie"
    else:
        initial = float(getattr(base_params, name))
        origin = f"{where}: the initial value (params.{name} or the base config's) must lie"
    if not low < initial < high:
        raise SpecError(f"{origin} strictly inside (low, high) = ({low:g}, {high:g}); got {initial:g}")
    return Bound(name, low, high, scale, initial)


def continuous_params(scenario, cfg) -> list[str]:
    """The Params a tune spec may name: continuous (not integer, no choices) and scalar."""
    return [k for k, p in scenario.params_table.items() if not p.integer and p.choices is None and p.shape is None
            and (p.per_agent or p.scalar(cfg)) and np.ndim(p.default_value(cfg)) == 0]


def build_tune_spec(data: dict, base_dir: str | Path) -> TuneSpec:
    """Validate a tune spec given as a dict; :class:`~mcjax.sweep.SpecError` names the key."""
    data = json.loads(json.dumps(data))
    _check_keys("", data, (*SHARED_KEYS, "tune"))
    if "tune" not in data:
        raise SpecError("tune: missing; a tune spec needs a [tune] table (see docs/tune.md)")
    tune = data["tune"]
    if not isinstance(tune, dict):
        raise SpecError(f"tune: must be a table; got {_show(tune)}")
    _check_keys("tune.", tune, TUNE_KEYS)
    shared = {k: v for k, v in data.items() if k != "tune"}
    spec = build_spec(shared, base_dir, seeds=1)
    scenario, cfg = spec.scenario, spec.config
    if scenario.surrogate is None:
        raise SpecError(f"scenario: {scenario.name} has no smooth surrogate (Scenario.surrogate), which "
                        f"mcjax tune needs; tunable built-in scenarios: "
                        f"{', '.join(n for n, s in scenarios.BUILTIN.items() if s.surrogate is not None)}")
    optimizer = tune.get("optimizer", "adam")
    if optimizer not in OPTIMIZERS:
        raise SpecError(f"tune.optimizer: must be one of {', '.join(OPTIMIZERS)}; got {_show(optimizer)}"
                        f"{_suggest(optimizer, OPTIMIZERS) if isinstance(optimizer, str) else ''}")
    lr = _number("tune.learning_rate", tune.get("learning_rate", 0.1), positive=True)
    steps = _count("tune.steps", tune.get("steps", 30), 1, MAX_STEPS)
    train_seeds = _count("tune.train_seeds", tune.get("train_seeds", 128), 1, MAX_TRAIN_SEEDS)
    train_base = _count("tune.train_base_seed", tune.get("train_base_seed", 1), 0, MAX_BASE_SEED)
    heldout = _count("tune.heldout_seeds", tune.get("heldout_seeds", 1000), 1, MAX_SEEDS)
    heldout_base = _count("tune.heldout_base_seed", tune.get("heldout_base_seed", 0), 0, MAX_BASE_SEED)
    if heldout_base == train_base:
        raise SpecError(f"tune.heldout_base_seed: must differ from tune.train_base_seed = {train_base} (held-out "
                        f"seeds are not training seeds)")
    block = _count("tune.checkpoint_every", tune.get("checkpoint_every", min(10, cfg.n_steps)), 1, cfg.n_steps)
    mode = tune.get("gradient", "forward")
    if mode not in GRADIENT_MODES:
        raise SpecError(f"tune.gradient: must be one of {', '.join(GRADIENT_MODES)}; got {_show(mode)}")
    window = _count("tune.gradient_window", tune.get("gradient_window", 0), 0, cfg.n_steps)
    params_table = _tune_table("tune.", tune, "params")
    if not params_table:
        raise SpecError("tune.params: must name at least one Param to tune ([tune.params.NAME] with low, high)")
    bounds = tuple(_bound(scenario, cfg, spec.base_params, k, v) for k, v in params_table.items())
    lt = _tune_table("tune.", tune, "loss")
    _check_keys("tune.loss.", lt, LOSS_KEYS)
    filt = lt.get("filter", cfg.filters[0])
    if filt not in cfg.filters:
        raise SpecError(f"tune.loss.filter: must be one of the config's filters ({', '.join(cfg.filters)}); "
                        f"got {_show(filt)}")
    D = float(cfg.divergence_threshold)
    loss = Loss(filt,
                _number("tune.loss.error_scale", lt.get("error_scale", D), positive=True),
                _number("tune.loss.divergence_weight", lt.get("divergence_weight", 1.0), nonneg=True),
                _number("tune.loss.divergence_temperature", lt.get("divergence_temperature", D / 5), positive=True),
                _number("tune.loss.max_temperature", lt.get("max_temperature", D / 50), positive=True),
                D, int(cfg.warmup_steps))
    Smoothing = scenario.surrogate.Smoothing
    st = _tune_table("tune.", tune, "smoothing")
    _check_keys("tune.smoothing.", st, list(Smoothing._fields))
    smoothing = Smoothing(**{k: _number(f"tune.smoothing.{k}", v, positive=True) for k, v in st.items()})
    for b in bounds:  # checks across fields (e.g. the horizon) at both bounds
        for v in (b.low, b.high):
            if scenario.check_params is not None:
                values = {**{k: v2 for k, v2 in spec.source.get("params", {}).items()}, b.name: v}
                for name, allowed in scenario.check_params(cfg, values):
                    if name == b.name:
                        raise SpecError(f"tune.params.{b.name}: must be {allowed} over its bounds")
    return TuneSpec(spec, bounds, loss, smoothing, optimizer, lr, steps, train_seeds, train_base, heldout,
                    heldout_base, block, mode, window, data, str(Path(base_dir).resolve()))


def load_tune_spec(path: str | Path) -> TuneSpec:
    """Read and validate a tune spec file (``base`` relative to its folder)."""
    path = Path(path)
    data = _read_toml(path, "tune spec")
    if is_config_file(data):
        raise SpecError(f"{path} is a config file (it names a scenario, no base), not a tune spec: name it as "
                        f"`base` in a tune spec with a [tune] table")
    return build_tune_spec(data, path.parent)


# ------------------------------------------------------------------ loss and gradient


def params_at(bounds, base, x):
    """The Params ``base`` with the tuned fields (``bounds``) set to ``x`` (P,) (traceable)."""
    import jax.numpy as jnp

    values = {k: jnp.asarray(v) for k, v in base._asdict().items()}
    for i, b in enumerate(bounds):
        values[b.name] = x[i]
    return type(base)(**values)


def run_loss(scenario, cfg, loss: Loss, smoothing, block: int, params, key, window: int = 0, remat: bool = True):
    """The training loss of one run (module docstring) with its parts:
    ``(loss, (soft RMSE, soft divergence))``. The closed loop runs the scenario's surrogate
    step through the engine's time-loop driver (:func:`mcjax.engine.time_loop`: the exact
    simulation's keys) over ``ceil(T / block)`` blocks of ``block`` steps, each block under
    ``jax.checkpoint`` when ``remat`` (reverse mode; forward mode stores no intermediates and
    skips it); the loss is computed from the stacked errors (T, n) of the loss's filter.

    ``window = K > 0`` truncates the gradient (not the value): at steps ``K, 2K, …`` the state
    enters the next step through ``stop_gradient``, so the derivative counts how the Params act
    on the errors within each window of K steps from the state the window starts in, and not
    how a change carries over from earlier windows (truncated differentiation through time).
    The loss's value is the same for every K."""
    import jax
    import jax.numpy as jnp

    from mcjax import engine

    sur = scenario.surrogate
    f = cfg.filters.index(loss.filter)
    weights = sur.weights(cfg, params)
    state = scenario.init(cfg, params, engine.init_key(key))
    T = cfg.n_steps
    c, tm = loss.error_scale, loss.max_temperature
    dtype = weights.dtype
    neg = jnp.asarray(-1e30, dtype)

    def advance(state, key_t, t):
        if window > 0:  # a new window: the state's derivative is dropped (the value is kept)
            cut = (t % window == 0) & (t > 0)
            state = jax.tree.map(lambda a: jnp.where(cut, jax.lax.stop_gradient(a), a), state)
        state, errors = sur.step(cfg, params, state, key_t, smoothing)
        return state, errors[f]

    _, e = engine.time_loop(advance, state, key, T, block=block, remat=remat)  # (T, n)
    e = jnp.where(jnp.isfinite(e), e, NONFINITE_ERROR * c)
    mask = (jnp.arange(T)[:, None] >= loss.warmup_steps) & (weights > 0)
    clipped = c * jnp.tanh(e / c)
    sq = jnp.sum(jnp.where(mask, clipped**2, 0.0))
    count = jnp.sum(mask.astype(dtype))
    lse = jax.nn.logsumexp(jnp.where(mask, e / tm, neg))
    rmse = jnp.sqrt(sq / jnp.maximum(count, 1.0))
    soft_div = jax.nn.sigmoid((tm * lse - loss.divergence_threshold) / loss.divergence_temperature)
    return rmse / c + loss.divergence_weight * soft_div, (rmse, soft_div)


#: Jitted batch functions per program (:func:`program_key`), so evaluators of the same program
#: in one process share their compiled code.
_FUNCTIONS: dict = {}


def program_key(spec: TuneSpec) -> str:
    """What fixes a tune's compiled program: scenario and Config, the tuned Params and their
    bounds, the loss, the smoothing, the gradient mode and blocks (not the Params' values,
    which the program takes as an argument)."""
    s = spec.sweep
    return json.dumps([s.scenario.name, repr(s.config), [[b.name, b.low, b.high, b.scale] for b in spec.bounds],
                       list(spec.loss), list(spec.smoothing), spec.checkpoint_every, spec.gradient,
                       spec.gradient_window],
                      sort_keys=True, default=str)


def batch_function(spec: TuneSpec) -> Callable:
    """``f(z, keys, base) -> (losses (R,), grads (R, P), soft RMSE (R,), soft divergence (R,))``:
    every run's training loss at the base Params ``base`` with the tuned ones at ``z``, and its
    gradient with respect to ``z``, jitted (one program; the caller spreads batches over
    devices). One function per :func:`program_key`."""
    key = program_key(spec)
    if key not in _FUNCTIONS:
        _FUNCTIONS[key] = _batch_function(spec)
    return _FUNCTIONS[key]


def _batch_function(spec: TuneSpec) -> Callable:
    import jax

    s = spec.sweep
    scenario, cfg, loss, smoothing, block, bounds = (s.scenario, s.config, spec.loss, spec.smoothing,
                                                     spec.checkpoint_every, spec.bounds)
    window = spec.gradient_window

    def one(z, key, base):
        def of_z(z):
            params = params_at(bounds, base, from_unconstrained(bounds, z))
            return run_loss(scenario, cfg, loss, smoothing, block, params, key, window, spec.gradient == "reverse")

        if spec.gradient == "reverse":
            (value, (rmse, div)), g = jax.value_and_grad(of_z, has_aux=True)(z)
            return value, g, rmse, div

        def pushed(z):  # forward mode: one tangent per tuned Param
            value, aux = of_z(z)
            return value, (value, aux)

        g, (value, (rmse, div)) = jax.jacfwd(pushed, has_aux=True)(z)
        return value, g, rmse, div

    from mcjax.engine import compiler_options

    return jax.jit(jax.vmap(one, in_axes=(None, 0, None)), compiler_options=compiler_options(scenario))


def train_keys(spec: TuneSpec):
    """The training runs' keys: the engine's keys of seeds ``0 … train_seeds−1`` of
    ``train_base_seed`` (the same at every optimisation step: common random numbers)."""
    import jax
    import jax.numpy as jnp

    from mcjax.engine import run_key

    return jax.vmap(lambda i: run_key(spec.train_base_seed, i))(jnp.arange(spec.train_seeds, dtype=jnp.uint32))


class Evaluation(NamedTuple):
    """The batch loss at one ``z`` and its gradient (means over the runs with a finite one)."""

    loss: float
    grad: np.ndarray          # (P,) d loss / d z
    soft_rmse: float
    soft_divergence: float
    dropped: int              # runs whose loss or gradient was not finite


#: Fewest training runs per device before a second device is used.
RUNS_PER_DEVICE = 16


class Evaluator:
    """The training batch's loss and gradient at any ``z``: the batch is cut into one slice
    per device, one program compiled once and loaded on each device, run side by side."""

    def __init__(self, spec: TuneSpec):
        import jax

        from mcjax import engine

        self.spec = spec
        self.fn = batch_function(spec)
        keys = train_keys(spec)
        n = spec.train_seeds
        # one device per RUNS_PER_DEVICE runs at least (a small batch compiles once)
        self.devs = engine.devices()[:max(1, min(len(engine.devices()), n // RUNS_PER_DEVICE))]
        size = -(-n // len(self.devs))
        self.slices = [(i * size, min(n, (i + 1) * size)) for i in range(len(self.devs)) if i * size < n]
        self.devs = self.devs[:len(self.slices)]
        # every slice padded to one size (repeating its last key), so one program serves all
        self.keys = []
        for a, b in self.slices:
            k = keys[a:b]
            if b - a < size:
                k = jax.numpy.concatenate([k, jax.numpy.repeat(k[-1:], size - (b - a), axis=0)])
            self.keys.append(k)
        self.programs = None

    def __call__(self, z) -> Evaluation:
        import jax

        from mcjax import engine

        z = np.asarray(z, np.float64)
        base = self.spec.sweep.base_params
        if self.programs is None:
            self.programs = engine.programs(self.fn, (z, self.keys[0], base), self.devs)
        outs = [prog(jax.device_put(z, d), jax.device_put(k, d), jax.device_put(base, d))
                for prog, d, k in zip(self.programs, self.devs, self.keys)]
        parts = [[np.asarray(x)[:b - a] for x in o] for o, (a, b) in zip(outs, self.slices)]
        loss, grad, rmse, div = (np.concatenate([p[i] for p in parts]) for i in range(4))
        ok = np.isfinite(loss) & np.all(np.isfinite(grad), axis=1)
        if not ok.any():
            return Evaluation(math.nan, np.full(len(z), np.nan), math.nan, math.nan, int(len(loss)))
        return Evaluation(float(loss[ok].mean()), grad[ok].mean(0), float(rmse[ok].mean()), float(div[ok].mean()),
                          int((~ok).sum()))


# ------------------------------------------------------------------ optimisation with resume

STATE_FILE = "tune_state.npz"
TRACE_FILE = "trace.parquet"
IDENTITY_FILE = "tune.json"


def make_optimizer(spec: TuneSpec):
    import optax

    return getattr(optax, spec.optimizer)(spec.learning_rate)


def trace_columns(spec: TuneSpec) -> list[str]:
    return ["step", "loss", "soft_rmse", "soft_divergence", *spec.names, *[f"z_{n}" for n in spec.names],
            "grad_norm", *[f"grad_{n}" for n in spec.names], "dropped_runs", "wall_s"]


def _atomic_write(path: Path, write: Callable[[Path], None]) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    write(tmp)
    with open(tmp, "rb") as fh:
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def save_state(out_dir: Path, step: int, z, opt_state, trace: pd.DataFrame) -> None:
    """The optimiser's state after ``step`` completed steps, atomically (temporary file, then
    rename): ``z``, every leaf of the optax state, and the trace so far (also as Parquet)."""
    import jax

    leaves = [np.asarray(a) for a in jax.tree.leaves(opt_state)]
    arrays = {"step": np.asarray(step), "z": np.asarray(z, np.float64),
              **{f"leaf_{i}": a for i, a in enumerate(leaves)}}

    def npz(tmp):
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)

    _atomic_write(out_dir / TRACE_FILE, lambda tmp: trace.to_parquet(tmp, index=False))
    _atomic_write(out_dir / STATE_FILE, npz)


def load_state(out_dir: Path, spec: TuneSpec):
    """``(step, z, opt_state, trace)`` saved by :func:`save_state`, or None if there is none."""
    import jax

    path = out_dir / STATE_FILE
    if not path.is_file():
        return None
    opt = make_optimizer(spec)
    z0 = to_unconstrained(spec.bounds, spec.initial())
    template = opt.init(jax.numpy.asarray(z0))
    with np.load(path) as data:
        step = int(data["step"])
        z = np.array(data["z"])
        leaves = [jax.numpy.asarray(data[f"leaf_{i}"]) for i in range(len(jax.tree.leaves(template)))]
    trace = pd.read_parquet(out_dir / TRACE_FILE) if (out_dir / TRACE_FILE).is_file() else pd.DataFrame()
    trace = trace[trace["step"] < step] if len(trace) else trace
    return step, z, jax.tree.unflatten(jax.tree.structure(template), leaves), trace


def optimise(spec: TuneSpec, out_dir: Path, *, evaluator: Evaluator | None = None,
             progress: Callable[[dict], None] | None = None,
             should_stop: Callable[[], bool] | None = None) -> pd.DataFrame:
    """Run the optimisation from the saved state in ``out_dir`` (or from the initial Params),
    saving the state after every completed step; return the trace. Row ``k`` of the trace is
    the loss and gradient at the Params *before* update ``k`` (row 0: the initial Params); a
    last row ``step = steps`` holds the final Params (their loss evaluated too).
    ``should_stop()`` is asked after each step."""
    import jax
    import optax

    opt = make_optimizer(spec)
    saved = load_state(out_dir, spec)
    if saved is None:
        z = to_unconstrained(spec.bounds, spec.initial())
        opt_state = opt.init(jax.numpy.asarray(z))
        step, rows = 0, []
    else:
        step, z, opt_state, trace = saved
        rows = trace.to_dict("records")
    evaluator = evaluator or Evaluator(spec)
    update = jax.jit(lambda g, s, z: _apply(opt, g, s, z))
    while step <= spec.steps:
        t0 = time.perf_counter()
        ev = evaluator(z)
        x = np.asarray(from_unconstrained(spec.bounds, jax.numpy.asarray(z)))
        row = {"step": step, "loss": ev.loss, "soft_rmse": ev.soft_rmse, "soft_divergence": ev.soft_divergence,
               **{n: float(v) for n, v in zip(spec.names, x)}, **{f"z_{n}": float(v) for n, v in zip(spec.names, z)},
               "grad_norm": float(np.linalg.norm(ev.grad)),
               **{f"grad_{n}": float(g) for n, g in zip(spec.names, ev.grad)},
               "dropped_runs": ev.dropped}
        if step < spec.steps:
            g = np.where(np.isfinite(ev.grad), ev.grad, 0.0)
            z_new, opt_state = update(jax.numpy.asarray(g), opt_state, jax.numpy.asarray(z))
            z = np.asarray(z_new)
        row["wall_s"] = time.perf_counter() - t0
        rows.append(row)
        step += 1
        trace = pd.DataFrame(rows, columns=trace_columns(spec))
        save_state(out_dir, step, z, opt_state, trace)
        if progress is not None:
            progress(row)
        if should_stop is not None and should_stop() and step <= spec.steps:
            break
    return pd.DataFrame(rows, columns=trace_columns(spec))


def _apply(opt, g, state, z):
    import optax

    updates, state = opt.update(g, state, z)
    return optax.apply_updates(z, updates), state


def finished(spec: TuneSpec, trace: pd.DataFrame) -> bool:
    return len(trace) > 0 and int(trace["step"].max()) >= spec.steps


# ------------------------------------------------------------------ evaluation and figure


def final_values(spec: TuneSpec, trace: pd.DataFrame) -> np.ndarray:
    row = trace[trace["step"] == spec.steps].iloc[0]
    return np.array([row[n] for n in spec.names])


def evaluation_spec(spec: TuneSpec, final) -> SweepSpec:
    """The held-out evaluation as a sweep: the tuned Params zipped over two points (point 0 =
    the initial values, point 1 = the final ones) on ``heldout_seeds`` seeds of
    ``heldout_base_seed``, exact simulation. Params whose value did not change are left at it
    (not an axis); if none changed, one point."""
    data = {k: v for k, v in spec.source.items() if k != "tune"}
    data["params"] = dict(data.get("params", {}))
    zipped = {}
    for b, v in zip(spec.bounds, np.asarray(final, np.float64)):
        data["params"].pop(b.name, None)
        if float(v) != b.initial:
            zipped[b.name] = [b.initial, float(v)]
        else:
            data["params"][b.name] = b.initial
    if zipped:
        data["zip"] = zipped
    data["seeds"] = spec.heldout_seeds
    data["base_seed"] = spec.heldout_base_seed
    data["description"] = (data.get("description", "") + " — held-out evaluation of mcjax tune: point 0 = "
                           "initial, point 1 = tuned Params").strip(" —")
    return build_spec(data, Path(spec.base_dir))


def plot_trace(spec: TuneSpec, trace: pd.DataFrame, path: Path) -> Path:
    """The optimisation trace as a PNG: the loss (and its two parts) per step, and each tuned
    Param per step (log axis for a log-scaled one)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(spec.bounds)
    fig, axes = plt.subplots(1, n + 1, figsize=(4.2 * (n + 1), 3.4))
    ax = axes[0]
    ax.plot(trace["step"], trace["loss"], "o-", label="loss")
    ax.plot(trace["step"], trace["soft_rmse"] / spec.loss.error_scale, ".--", label="soft RMSE / c")
    ax.plot(trace["step"], spec.loss.divergence_weight * trace["soft_divergence"], ".:", label="w x soft divergence")
    ax.set_xlabel("optimisation step")
    ax.set_title(f"training loss ({spec.train_seeds} runs)")
    ax.legend(fontsize=7)
    for ax, b in zip(axes[1:], spec.bounds):
        ax.plot(trace["step"], trace[b.name], "o-")
        ax.axhline(b.low, color="grey", lw=0.5)
        ax.axhline(b.high, color="grey", lw=0.5)
        if b.scale == "log":
            ax.set_yscale("log")
        ax.set_xlabel("optimisation step")
        ax.set_title(b.name)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# ------------------------------------------------------------------ output folder


def identity(spec: TuneSpec) -> dict:
    """What makes two tunes the same for ``--resume``: the spec as written."""
    return json.loads(json.dumps({"spec": spec.source}, default=str))


def prepare_tune_output(spec: TuneSpec, out_dir: str | Path, *, resume: bool = False, force: bool = False,
                        spec_file: str | Path | None = None, keep: list = ()) -> None:
    """Make ``out_dir`` ready: a fresh tune needs a missing or empty folder (``force`` replaces
    one holding a previous tune, ``tune.json``); ``resume`` needs the same spec in
    ``tune.json``. Writes ``tune.json``. :class:`~mcjax.sweep.OutputError` otherwise, before
    anything is written."""
    import shutil

    from mcjax.sweep import OutputError, _check_replaceable

    out_dir = Path(out_dir)
    state = out_dir / IDENTITY_FILE
    if resume and force:
        raise OutputError("--resume and --force exclude each other")
    try:
        if resume:
            if not state.is_file():
                raise OutputError(f"nothing to resume in {out_dir}: no {IDENTITY_FILE} (start the tune without --resume)")
            try:
                saved = json.loads(state.read_text(encoding="utf-8"))
            except (UnicodeDecodeError, ValueError) as exc:
                raise OutputError(f"{state} is damaged ({exc}); start again with --force") from None
            if not isinstance(saved, dict) or saved.get("spec") != identity(spec)["spec"]:
                raise OutputError(f"{out_dir} holds a different tune (its spec differs); --resume needs the same spec")
            for tmp in out_dir.glob(".*.tmp"):
                tmp.unlink()
            return
        if out_dir.exists() and not out_dir.is_dir():
            raise OutputError(f"output folder {out_dir} is a file; choose another --out")
        if out_dir.exists() and any(out_dir.iterdir()):
            if not force:
                raise OutputError(f"output folder {out_dir} is not empty; pass --resume to finish it, --force to "
                                  f"replace it, or choose another --out")
            _check_replaceable(out_dir, list(keep), IDENTITY_FILE, "tune")
            shutil.rmtree(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        saved = {**identity(spec), "spec_file": None if spec_file is None else str(Path(spec_file).resolve())}
        _atomic_write(state, lambda tmp: tmp.write_text(json.dumps(saved, indent=1), encoding="utf-8"))
    except OSError as exc:
        raise OutputError(f"output folder {out_dir}: {exc.strerror or exc}") from None


def prepare_evaluation(ev: SweepSpec, out_dir: str | Path, *, spec_file: str | Path | None = None):
    """Ready ``out_dir`` for the held-out evaluation sweep ``ev``: write its ``sweep.json`` (as
    ``mcjax sweep`` does, so ``mcjax report`` reads the folder), or, when one for the same
    evaluation is there, return the chunks still missing (a resumed evaluation). None: all."""
    import shutil

    from mcjax import results
    from mcjax.sweep import IDENTITY_FILE as SWEEP_FILE, check_parts
    from mcjax.sweep import identity as sweep_identity

    out_dir = Path(out_dir)
    ident = sweep_identity(ev)
    path = out_dir / SWEEP_FILE
    if path.is_file():
        try:
            saved = json.loads(path.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, ValueError):
            saved = None
        if isinstance(saved, dict) and {k: saved.get(k) for k in ident} == ident:
            results.clean_staging(out_dir)
            return check_parts(ev, out_dir)[0]
    for folder in ("runs", results.STAGING_DIR):
        if (out_dir / folder).exists():
            shutil.rmtree(out_dir / folder)
    saved = {**ident, "set": {}, "spec_file": None if spec_file is None else str(Path(spec_file).resolve()),
             "tune": True}
    _atomic_write(path, lambda tmp: tmp.write_text(json.dumps(saved, indent=1), encoding="utf-8"))
    return None
