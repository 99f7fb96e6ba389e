"""A tune spec: a sweep spec (``base``, ``[config]``, ``[params]``, ``chunk_size``,
``description``; no ``[grid]``, ``[zip]``, ``seeds`` or ``base_seed``) with a ``[tune]`` table
(see :mod:`mcjax.tune`), read and validated (:mod:`mcjax.base.validation`) into a :class:`TuneSpec`,
and the bounded transform of the tuned Params (:class:`Bound`)."""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from mcjax import scenarios
from mcjax.base.plugins import absolute_reference
from mcjax.base.validation import check_keys, choice, count, number, read_toml, show
from mcjax.contract.relaxation import problem as smooth_problem
from mcjax.contract.relaxation import relaxation_key
from mcjax.contract.relaxation import smooth_params
from mcjax.study import MAX_BASE_SEED, MAX_SEEDS, SpecError, Study, build_spec, is_config_file

#: optax optimisers a spec may name (each is called as ``optax.NAME(learning_rate)``).
OPTIMIZERS = ("adam", "adamw", "sgd", "rmsprop", "adagrad", "adabelief", "lamb", "lion", "nadam", "radam",
              "yogi", "adamax", "amsgrad", "novograd")
SCALES = ("linear", "log")
TUNE_KEYS = ("optimizer", "learning_rate", "steps", "train_seeds", "train_base_seed", "heldout_seeds",
             "heldout_base_seed", "gradient", "gradient_window", "checkpoint_every", "params", "loss", "relaxation", "smoothing")
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
    """A validated tune spec: the shared sweep part (:class:`~mcjax.study.Study`, its
    ``base_params`` holding the initial values) and the ``[tune]`` table."""

    study: Study
    bounds: tuple
    loss: Loss
    temperatures: Any
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


def _tune_table(where: str, table: dict, key: str) -> dict:
    value = table.get(key, {})
    if not isinstance(value, dict):
        raise SpecError(f"{where}{key}: must be a table ([{where}{key}]); got {show(value)}")
    return value


def _bound(scenario, cfg, base_params, name: str, table) -> Bound:
    where = f"tune.params.{name}"
    problem = smooth_problem(scenario, cfg, name)
    if problem is not None:
        raise SpecError(f"{where}: {problem}")
    p = scenario.params_table[name]
    if np.ndim(getattr(base_params, name)) != 0:
        raise SpecError(f"{where}: {name} is an array here; only Params with one number can be tuned")
    if not isinstance(table, dict):
        raise SpecError(f"{where}: must be a table {{low = ..., high = ..., scale = \"linear\"|\"log\"}}; "
                        f"got {show(table)}")
    check_keys(f"{where}.", table, BOUND_KEYS)
    for k in ("low", "high"):
        if k not in table:
            raise SpecError(f"{where}.{k}: missing; give the bounds low < high")
    low, high = number(f"{where}.low", table["low"]), number(f"{where}.high", table["high"])
    if not low < high:
        raise SpecError(f"{where}: bounds reversed or empty: low must be < high; got low = {low:g}, high = {high:g}")
    for k, v in (("low", low), ("high", high)):
        msg = p.problem(v)
        if msg:
            raise SpecError(f"{where}.{k}: {msg} (the Param's allowed range)")
    scale = choice(f"{where}.scale", table.get("scale", "linear"), SCALES)
    if scale == "log" and low <= 0:
        raise SpecError(f"{where}.low: must be > 0 for scale = \"log\"; got {low:g}")
    if "initial" in table:
        initial = number(f"{where}.initial", table["initial"])
        origin = f"{where}.initial: must lie"
    else:
        initial = float(getattr(base_params, name))
        origin = f"{where}: the initial value (params.{name} or the base config's) must lie"
    if not low < initial < high:
        raise SpecError(f"{origin} strictly inside (low, high) = ({low:g}, {high:g}); got {initial:g}")
    return Bound(name, low, high, scale, initial)


def continuous_params(scenario, cfg) -> list[str]:
    """The Params a tune spec may name (:func:`mcjax.contract.relaxation.smooth_params`)."""
    return smooth_params(scenario, cfg)


def build_tune_spec(data: dict, base_dir: str | Path) -> TuneSpec:
    """Validate a tune spec given as a dict; :class:`~mcjax.study.SpecError` names the key."""
    data = json.loads(json.dumps(data))
    check_keys("", data, (*SHARED_KEYS, "tune"))
    if "tune" not in data:
        raise SpecError("tune: missing; a tune spec needs a [tune] table (see docs/tune.md)")
    tune = data["tune"]
    if not isinstance(tune, dict):
        raise SpecError(f"tune: must be a table; got {show(tune)}")
    check_keys("tune.", tune, TUNE_KEYS)
    shared = {k: v for k, v in data.items() if k != "tune"}
    spec = build_spec(shared, base_dir, seeds=1)
    scenario, cfg = spec.scenario, spec.config
    if scenario.relaxation is None:
        raise SpecError(f"scenario: {scenario.name} has no relaxation switch (Scenario.relaxation), which "
                        f"mcjax tune needs; tunable built-in scenarios: "
                        f"{', '.join(n for n, s in scenarios.BUILTIN.items() if s.relaxation is not None)}")
    optimizer = choice("tune.optimizer", tune.get("optimizer", "adam"), OPTIMIZERS, hint=True)
    lr = number("tune.learning_rate", tune.get("learning_rate", 0.1), positive=True)
    steps = count("tune.steps", tune.get("steps", 30), 1, MAX_STEPS)
    train_seeds = count("tune.train_seeds", tune.get("train_seeds", 128), 1, MAX_TRAIN_SEEDS)
    train_base = count("tune.train_base_seed", tune.get("train_base_seed", 1), 0, MAX_BASE_SEED)
    heldout = count("tune.heldout_seeds", tune.get("heldout_seeds", 1000), 1, MAX_SEEDS)
    heldout_base = count("tune.heldout_base_seed", tune.get("heldout_base_seed", 0), 0, MAX_BASE_SEED)
    if heldout_base == train_base:
        raise SpecError(f"tune.heldout_base_seed: must differ from tune.train_base_seed = {train_base} (held-out "
                        f"seeds are not training seeds)")
    block = count("tune.checkpoint_every", tune.get("checkpoint_every", min(10, cfg.n_steps)), 1, cfg.n_steps)
    mode = choice("tune.gradient", tune.get("gradient", "forward"), GRADIENT_MODES)
    window = count("tune.gradient_window", tune.get("gradient_window", 0), 0, cfg.n_steps)
    params_table = _tune_table("tune.", tune, "params")
    if not params_table:
        raise SpecError("tune.params: must name at least one Param to tune ([tune.params.NAME] with low, high)")
    bounds = tuple(_bound(scenario, cfg, spec.base_params, k, v) for k, v in params_table.items())
    lt = _tune_table("tune.", tune, "loss")
    check_keys("tune.loss.", lt, LOSS_KEYS)
    filt = absolute_reference(lt.get("filter", cfg.filters[0]), base_dir)  # a filter file as the config names it
    if filt not in cfg.filters:
        raise SpecError(f"tune.loss.filter: must be one of the config's filters ({', '.join(cfg.filters)}); "
                        f"got {show(filt)}")
    D = float(cfg.divergence_threshold)
    loss = Loss(filt,
                number("tune.loss.error_scale", lt.get("error_scale", D), positive=True),
                number("tune.loss.divergence_weight", lt.get("divergence_weight", 1.0), nonneg=True),
                number("tune.loss.divergence_temperature", lt.get("divergence_temperature", D / 5), positive=True),
                number("tune.loss.max_temperature", lt.get("max_temperature", D / 50), positive=True),
                D, int(cfg.warmup_steps))
    Temperatures = scenario.relaxation.Temperatures
    key = relaxation_key("tune", tune)
    st = _tune_table("tune.", tune, key)
    check_keys(f"tune.{key}.", st, list(Temperatures._fields))
    temperatures = Temperatures(**{k: number(f"tune.{key}.{k}", v, positive=True) for k, v in st.items()})
    for b in bounds:  # checks across fields (e.g. the horizon) at both bounds
        for v in (b.low, b.high):
            if scenario.check_params is not None:
                values = {**{k: v2 for k, v2 in spec.source.get("params", {}).items()}, b.name: v}
                for name, allowed in scenario.check_params(cfg, values):
                    if name == b.name:
                        raise SpecError(f"tune.params.{b.name}: must be {allowed} over its bounds")
    return TuneSpec(spec, bounds, loss, temperatures, optimizer, lr, steps, train_seeds, train_base, heldout,
                    heldout_base, block, mode, window, data, str(Path(base_dir).resolve()))


def load_tune_spec(path: str | Path) -> TuneSpec:
    """Read and validate a tune spec file (``base`` relative to its folder)."""
    path = Path(path)
    data = read_toml(path, "tune spec")
    if is_config_file(data):
        raise SpecError(f"{path} is a config file (it names a scenario, no base), not a tune spec: name it as "
                        f"`base` in a tune spec with a [tune] table")
    return build_tune_spec(data, path.parent)

