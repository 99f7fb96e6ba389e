"""The scenario contract: what a scenario provides, and the declarations everything else reads.

A scenario is a :class:`Scenario` record of functions and declarations (a frozen dataclass of
functions — not a base class to inherit from). The engine, the sweep, the CLI, the results and
the report use a scenario only through this record; nothing above the scenarios names a
scenario, a filter or a unit.

What a scenario provides:

* ``Config`` — a frozen, hashable dataclass of everything that fixes array shapes or the
  compiled program, built by :func:`config_type` from one :class:`Setting` per field (default,
  unit, allowed values, description). Validation and ``mcjax list`` derive from the settings.
  Every Config has ``n_agents``, ``n_steps`` and ``filters`` (the filter names in display
  order; every per-filter output has one value per filter, in this order).
* ``Params`` — a NamedTuple of arrays (a pytree) of everything a sweep may vary without
  recompiling, built by :func:`params_type` from one :class:`Param` per field (default,
  unit, allowed range, per-agent or not, shape, description). Sweep validation, ``mcjax
  list``, report axis labels and the Parquet metadata derive from it.
* ``init(cfg, params, key) -> State`` and ``step(cfg, params, state, key) -> (State, Record)``,
  pure and jittable; ``reduce(cfg, records, params) -> {name: array}`` reduces one run's
  records (stacked over time) to the declared :class:`Output` fields of ``outputs(cfg)``:
  ``(F,)`` for a per-filter output, ``()`` for a per-run one.
* optionally ``timeseries(cfg, records, params) -> {name: array}``, per-step series declared
  by ``timeseries_outputs(cfg)``: ``(T, F)`` per filter, ``(T,)`` per run;
* optionally ``check_params(cfg, values) -> [(field, allowed), …]``: checks across fields
  (e.g. the horizon against ``Config.max_horizon``); single-field checks come from the table.
* optionally ``compiler_options``: XLA options for the scenario's batch programs
  (``jax.jit(..., compiler_options=…)``), e.g. :data:`FAST_COMPILE`; an option this JAX does
  not know is dropped (the program is then compiled with XLA's defaults).

Validation reads values as a spec writes them (TOML): kinds are exact — a boolean is no
number, a float no integer (:meth:`Param.problem` with ``exact=True``), a string or a table no
list — and integer Config fields without a declared upper bound get the contract's
:func:`ceiling` (:data:`COUNT_CEILINGS`), so a spec cannot ask for more than a machine holds.

Output roles tell the layers above what a column means: ``"error"`` (exactly one: the error
metric the report leads with), ``"divergence"`` (the divergence flag), ``"nonfinite"`` and
the graph statistics ``"connectivity_mean"``, ``"connectivity_min"`` and
``"disconnected_steps"`` (all optional: a single agent has no graph).

This module is a leaf: it imports nothing from mcjax and no JAX, so every layer may use it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Callable, Mapping, NamedTuple

import numpy as np

#: Roles an output may declare (see the module docstring).
ROLES = ("error", "divergence", "nonfinite", "connectivity_mean", "connectivity_min", "disconnected_steps")


class Output(NamedTuple):
    """Declaration of one summary or timeseries field."""

    unit: str                 # "m", "m/s", "" for counts, flags and dimensionless numbers
    description: str          # one line
    per_filter: bool = True   # one value per filter (else one per run)
    role: str | None = None   # one of ROLES, or None

    def as_json(self) -> dict:
        return self._asdict()


def _num(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _range_text(low, high, low_open, integer) -> str:
    kind = "an integer " if integer else ""
    lo_ok, hi_ok = low is not None and low > -math.inf, high is not None and high < math.inf
    if lo_ok and hi_ok:
        return f"{kind}in {'(' if low_open else '['}{_num(low)}, {_num(high)}]"
    if lo_ok:
        return f"{kind}{'>' if low_open else '>='} {_num(low)}"
    if hi_ok:
        return f"{kind}<= {_num(high)}"
    return "an integer" if integer else "any number"


def _in_range(arr, low, high, low_open) -> bool:
    ok = np.ones(arr.shape, bool)
    if low is not None:
        ok &= (arr > low) if low_open else (arr >= low)
    if high is not None:
        ok &= arr <= high
    return bool(np.all(ok))


def _show(value) -> str:
    """``repr(value)`` on one line, cut to a readable length."""
    text = repr(value.tolist() if isinstance(value, np.ndarray) else value).replace("\n", " ")
    return text if len(text) <= 120 else text[:100] + f"... ({len(text)} characters)"


def _bad(allowed: str, value) -> str:
    return f"must be {allowed}; got {_show(value)}"


# ------------------------------------------------------------------ exact kinds of values
# A spec is TOML, whose values have exact kinds: a boolean is not a number, a float is not
# an integer, a string is not a list, a table is not a list. These helpers hold that line
# (numpy scalars count as their Python kinds, so code may pass them too).

def _is_bool(v) -> bool:
    return isinstance(v, (bool, np.bool_))


def _is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not _is_bool(v)


def _is_real(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not _is_bool(v)


def _same(value, choice) -> bool:
    """``value`` is ``choice`` in kind and in value: true is not 1, 1.0 is not 1, "1" is not 1."""
    if isinstance(choice, str):
        return isinstance(value, str) and value == choice
    if _is_bool(choice):
        return _is_bool(value) and value == choice
    if _is_int(choice):
        return _is_int(value) and value == choice
    if _is_real(choice):
        return _is_real(value) and value == choice
    return type(value) is type(choice) and value == choice


def _leaves(value):
    """The leaves of a nested list (a value itself if it is no list); None if a leaf is a
    table, a string, a boolean or anything but a number."""
    if isinstance(value, np.ndarray):
        return [value] if value.dtype.kind in "iuf" else None
    if isinstance(value, (list, tuple)):
        out = []
        for v in value:
            sub = _leaves(v)
            if sub is None:
                return None
            out += sub
        return out
    return [value] if _is_real(value) else None


def _integral_leaves(leaves) -> bool:
    """Every leaf is an integer in kind (an integer-typed array counts; a float never does)."""
    return all(_is_int(v) or (isinstance(v, np.ndarray) and v.dtype.kind in "iu") for v in leaves)


def _within(value, low, high, low_open) -> bool:
    """A scalar range check that also holds for integers beyond float range."""
    if low is not None and not (value > low if low_open else value >= low):
        return False
    return high is None or value <= high


#: Upper bounds of the integer Config fields that declare none, so that no spec can ask
#: for more than one machine holds before the sweep even sizes its batches: the agents
#: and steps every Config has, and any other count (iterations, samples, grid cells,
#: sub-steps, attempts). The sweep's memory check (mcjax.sweep) refines these per program.
COUNT_CEILINGS = {"n_agents": 1_000, "n_steps": 1_000_000}
#: The bound of every other integer Config field without a declared upper bound.
COUNT_CEILING = 100_000


def ceiling(name: str, setting: "Setting") -> int | None:
    """The upper bound :func:`config_type` enforces on an integer Setting that declares no
    ``high`` (:data:`COUNT_CEILINGS`, else :data:`COUNT_CEILING`); None for other fields."""
    if not setting.integer or setting.choices is not None or (setting.high is not None and setting.high < math.inf):
        return None
    return COUNT_CEILINGS.get(name, COUNT_CEILING)


def setting_problem(name: str, setting: "Setting", value) -> str | None:
    """:meth:`Setting.problem`, then the field's :func:`ceiling`."""
    msg = setting.problem(value)
    top = ceiling(name, setting)
    if msg is None and top is not None and value > top:
        low = setting.low if setting.low is not None else -math.inf
        return _bad(_range_text(low, top, setting.low_open, True) + (f" {setting.unit}" if setting.unit else ""),
                    value)
    return msg


#: Units a value may be shown in: (declared unit, shown unit) -> factor (shown = factor x declared).
DISPLAY_UNITS = {
    ("m", "km"): 1e-3,
    ("rad", "deg"): 180.0 / math.pi,
    ("rad/s", "deg/s"): 180.0 / math.pi,
    ("s", "min"): 1.0 / 60.0,
    ("s", "h"): 1.0 / 3600.0,
    ("m/s", "km/h"): 3.6,
}
#: The shown unit of a declared unit when a Param names none: angles in degrees.
DEFAULT_DISPLAY = {"rad": "deg", "rad/s": "deg/s"}


def display_unit(unit: str, display: str | None = None) -> tuple[str, float]:
    """``(shown unit, factor)`` for a value declared in ``unit``: ``display`` when given (it
    must be ``unit`` itself or a pair of :data:`DISPLAY_UNITS`), else :data:`DEFAULT_DISPLAY`,
    else ``unit`` unchanged (factor 1).

    Raises:
        ValueError: ``display`` is neither ``unit`` nor a known conversion from it.
    """
    unit = unit or ""
    if display is None:
        display = DEFAULT_DISPLAY.get(unit, unit)
    if display == unit:
        return unit, 1.0
    try:
        return display, DISPLAY_UNITS[(unit, display)]
    except KeyError:
        known = [b for a, b in DISPLAY_UNITS if a == unit]
        raise ValueError(f"display unit {display!r} for a value in {unit!r}: allowed "
                         f"{', '.join(repr(k) for k in [unit, *known])}") from None


class Setting(NamedTuple):
    """Declaration of one Config field (changing it recompiles)."""

    default: Any
    description: str
    unit: str = ""
    choices: tuple | None = None  # allowed values (for a ``many`` field: allowed members)
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    integer: bool = False
    many: bool = False            # a non-empty tuple of distinct choices (e.g. ``filters``)

    def allowed(self) -> str:
        if self.many:
            return "a non-empty list of distinct values from " + ", ".join(map(str, self.choices))
        if self.choices is not None:
            return "one of " + ", ".join(map(str, self.choices))
        return _range_text(self.low, self.high, self.low_open, self.integer)

    def problem(self, value) -> str | None:
        """None if ``value`` is allowed, else ``"must be …; got …"``. Kinds are exact: a
        boolean is no number, a float no integer, a string no list."""
        if self.many:
            if not isinstance(value, (tuple, list)):
                return _bad(self.allowed(), value)
            unknown = [v for v in value if not any(_same(v, c) for c in self.choices)]
            if unknown:
                return _bad(self.allowed(), value) + f" (unknown: {', '.join(map(_show, unknown))})"
            if len(value) == 0 or len(set(value)) != len(value):
                return _bad(self.allowed(), value)
            return None
        if self.choices is not None:
            return None if any(_same(value, c) for c in self.choices) else _bad(self.allowed(), value)
        unit = f" {self.unit}" if self.unit else ""
        if not _is_real(value) or (self.integer and not _is_int(value)):
            return _bad(self.allowed() + ("" if self.integer else unit), value)
        if not _is_int(value) and not math.isfinite(value):
            return _bad(self.allowed() + unit, value)
        if not _within(value, self.low, self.high, self.low_open):
            return _bad(self.allowed() + unit, value)
        return None


class Param(NamedTuple):
    """Declaration of one Params field (a sweep may vary it without recompiling).

    ``default`` is a value or a function of the Config (e.g. one position per agent).
    ``shape`` is the required shape, with ``"n"`` for the number of agents (None: any);
    a ``per_agent`` field takes a scalar (the same for every agent) or one value per agent.
    """

    default: Any
    unit: str
    description: str
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    integer: bool = False
    per_agent: bool = False
    shape: tuple | None = None
    choices: tuple | None = None  # allowed values, e.g. (0, 1) for an alive flag
    display: str | None = None    # the unit plots show it in (e.g. "km" for "m"; see DISPLAY_UNITS)

    def allowed(self) -> str:
        if self.choices is not None:
            return " or ".join(_num(c) for c in self.choices)
        return _range_text(self.low, self.high, self.low_open, self.integer)

    def default_value(self, cfg):
        return self.default(cfg) if callable(self.default) else self.default

    def scalar(self, cfg) -> bool:
        """Whether the field takes one number: no ``shape``, not per agent, and a scalar
        default (for ``cfg``). A field with an array default and no ``shape`` takes any
        shape (its scenario's ``check_params`` checks it)."""
        return self.shape is None and not self.per_agent and np.ndim(self.default_value(cfg)) == 0

    def _integral(self) -> bool:
        return self.integer or (self.choices is not None and all(_is_int(c) for c in self.choices))

    def expected(self, n_agents: int | None = None, cfg=None) -> str:
        """What the field takes, in words: its form (a number, one per agent, a shape) and
        its allowed values, e.g. ``"a number or a list of n_agents = 5 numbers, >= 0 m"``."""
        kind = "integer" if self._integral() else "number"
        if self.shape is not None:
            shown = "x".join("n_agents" if d == "n" else str(d) for d in self.shape)
            want = "" if n_agents is None else " (" + "x".join(str(n_agents if d == "n" else d)
                                                           for d in self.shape) + ")"
            form = f"an array of {kind}s of shape {shown}{want}"
        elif self.per_agent:
            agents = "n_agents" if n_agents is None else f"n_agents = {n_agents}"
            form = f"a{'n' if kind == 'integer' else ''} {kind} or a list of {agents} {kind}s"
        elif cfg is not None and self.scalar(cfg):
            form = f"a{'n' if kind == 'integer' else ''} {kind}"
        else:
            form = f"a{'n' if kind == 'integer' else ''} {kind} or a rectangular list of {kind}s"
        if self.choices is not None:
            return f"{form}, {self.allowed()}"
        rng = _range_text(self.low, self.high, self.low_open, False)
        return form if rng == "any number" else f"{form}, {rng}" + (f" {self.unit}" if self.unit else "")

    def problem(self, value, n_agents: int | None = None, *, exact: bool = False, cfg=None) -> str | None:
        """None if ``value`` is allowed (for ``n_agents`` agents, when given: shapes are then
        checked too), else ``"must be …; got …"``. A boolean, a string or a table is never a
        number, nor is a ragged list an array.

        ``exact=True`` reads ``value`` as a spec gives it: an integer field (or one whose
        choices are integers) takes integers only (``5.0`` is a float), and with ``cfg`` (the
        Config; it also sets ``n_agents``) a :meth:`scalar` field takes one number only."""
        if cfg is not None:
            n_agents = cfg.n_agents
        leaves = _leaves(value)
        if leaves is None:
            return _bad(self.expected(n_agents, cfg) if exact else "a number or a list of numbers", value)
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):  # ragged, or an integer beyond float range
            return _bad(self.expected(n_agents, cfg) if exact else "a number or a list of numbers", value)
        if exact and self._integral() and not _integral_leaves(leaves):
            return _bad(self.expected(n_agents, cfg), value)
        if exact and cfg is not None and self.scalar(cfg) and arr.ndim != 0:
            return _bad(self.expected(n_agents, cfg), value)
        if not np.all(np.isfinite(arr)):
            return _bad("finite", value)
        if self.choices is not None:
            if not np.all(np.isin(arr, self.choices)):
                return _bad(self.allowed(), value)
        elif self.integer and np.any(arr != np.round(arr)):
            return _bad(self.allowed(), value)
        elif not _in_range(arr, self.low, self.high, self.low_open):
            return _bad(self.allowed() + (f" {self.unit}" if self.unit else ""), value)
        if n_agents is not None:
            if self.per_agent and arr.shape not in ((), (n_agents,)):
                return _bad(f"a number or a list of n_agents = {n_agents} numbers", value)
            if self.shape is not None:
                want = tuple(n_agents if d == "n" else d for d in self.shape)
                if arr.shape != want:
                    shown = "x".join("n_agents" if d == "n" else str(d) for d in self.shape)
                    return _bad(f"of shape {shown} ({'x'.join(map(str, want))})", value)
        return None

    def display_unit(self) -> tuple[str, float]:
        """``(unit, factor)``: the unit plots show this field in and the factor from its
        declared unit to it (:func:`display_unit`)."""
        return display_unit(self.unit, self.display)

    def as_json(self) -> dict:
        shown, factor = self.display_unit()
        return {"unit": self.unit, "description": self.description, "per_agent": self.per_agent,
                "allowed": self.allowed(), "display_unit": shown, "display_factor": factor}


def config_type(name: str, settings: Mapping[str, Setting], module: str,
                check: Callable[[Any], None] | None = None) -> type:
    """A frozen dataclass with one field per :class:`Setting` (in order), whose construction
    validates every field (ValueError naming it and its allowed values; a list given for a
    ``many`` field becomes a tuple) and then runs ``check(cfg)`` for checks across fields.
    The settings are kept as ``Config.SETTINGS``. ``module`` is the defining module's
    ``__name__`` (so configs pickle)."""

    def __post_init__(self):
        for field, s in settings.items():
            value = getattr(self, field)
            if s.many and isinstance(value, list):
                object.__setattr__(self, field, tuple(value))
                value = tuple(value)
            msg = setting_problem(field, s, value)
            if msg:
                raise ValueError(f"{field} {msg}")
        if check is not None:
            check(self)

    fields = [(k, Any, dataclasses.field(default=s.default)) for k, s in settings.items()]
    cls = dataclasses.make_dataclass(name, fields, frozen=True, namespace={"__post_init__": __post_init__})
    cls.__module__ = module
    cls.SETTINGS = dict(settings)
    return cls


def params_type(name: str, table: Mapping[str, Param], module: str) -> type:
    """A NamedTuple (a JAX pytree) with one field per :class:`Param`, in order; the table is
    kept as ``Params.TABLE``."""
    for k, p in table.items():
        try:
            p.display_unit()
        except ValueError as exc:
            raise ValueError(f"{name}.{k}: {exc}") from None
    cls = NamedTuple(name, [(k, Any) for k in table])
    cls.__module__ = module
    cls.TABLE = dict(table)
    return cls


class Surrogate(NamedTuple):
    """A scenario's smooth stand-in for training by gradient through the closed loop (``mcjax
    tune``, :mod:`mcjax.tune`): the exact simulation with its hard switches (a sensing gate,
    the comm graph's links) replaced by smooth forms, so the gradient is informative.

    * ``step(cfg, params, state, key, smoothing) -> (State, errors)``: one step, with the same
      random draws as ``Scenario.step``; ``errors`` (F, n) the error of every filter and agent;
    * ``weights(cfg, params) -> (n,)``: each agent's weight in the training loss (alive: 1);
    * ``Smoothing``: a NamedTuple of the temperatures, with defaults (its fields are the keys
      of a tune spec's ``[tune.smoothing]`` table)."""

    step: Callable
    weights: Callable
    Smoothing: type


#: XLA's older fusion code generator on the CPU (``xla_cpu_use_fusion_emitters = False``):
#: measured on the 2-core VM (2026-12-02, docs/benchmarks.md) it compiles the closed loop of
#: Sun et al. 2011 with ~35–45 % less CPU time than the default (newer) emitters, the program
#: running as fast; for Ren & Lv 2017's IMM-UKF it ran ~10 % slower, so that scenario keeps
#: the default.
FAST_COMPILE: Mapping[str, Any] = MappingProxyType({"xla_cpu_use_fusion_emitters": False})


@dataclass(frozen=True, eq=False)
class Scenario:
    """One simulated system (see the module docstring). Hashed by identity, so the engine
    compiles it once per Config."""

    name: str
    title: str                      # one line: the system, and the paper it comes from
    Config: type
    Params: type
    init: Callable
    step: Callable
    reduce: Callable
    outputs: Callable[[Any], Mapping[str, Output]]
    timeseries: Callable | None = None
    timeseries_outputs: Callable[[Any], Mapping[str, Output]] | None = None
    check_params: Callable[[Any, dict], list] | None = None
    surrogate: Surrogate | None = None   # smooth stand-in for ``mcjax tune`` (optional)
    compiler_options: Mapping[str, Any] | None = None  # XLA options of its programs (optional)

    def __post_init__(self):
        for field in ("n_agents", "n_steps", "filters"):
            if field not in self.Config.SETTINGS:
                raise TypeError(f"scenario {self.name!r}: Config must declare {field!r}")
        if (self.timeseries is None) != (self.timeseries_outputs is None):
            raise TypeError(f"scenario {self.name!r}: timeseries and timeseries_outputs go together")

    @property
    def settings(self) -> dict[str, Setting]:
        return self.Config.SETTINGS

    @property
    def params_table(self) -> dict[str, Param]:
        return self.Params.TABLE

    def default_params(self, cfg=None, **overrides):
        """Params from the declared defaults with ``overrides`` applied, every field a
        float64 numpy array; an unknown field is a ValueError listing the known ones."""
        cfg = self.Config() if cfg is None else cfg
        unknown = set(overrides) - set(self.params_table)
        if unknown:
            raise ValueError(f"unknown Params field(s) {sorted(unknown)}; allowed: {', '.join(self.params_table)}")
        values = {k: overrides[k] if k in overrides else p.default_value(cfg) for k, p in self.params_table.items()}
        return self.Params(**{k: np.asarray(v, dtype=np.float64) for k, v in values.items()})

    def metadata(self, cfg) -> dict:
        """The declarations written into every Parquet part's schema metadata, so a dataset
        describes itself (``mcjax report`` needs nothing else)."""
        out = {"scenario": self.name, "title": self.title, "filters": list(cfg.filters),
               "outputs": {k: o.as_json() for k, o in self.outputs(cfg).items()},
               "params": {k: p.as_json() for k, p in self.params_table.items()}}
        if self.timeseries_outputs is not None:
            out["timeseries_outputs"] = {k: o.as_json() for k, o in self.timeseries_outputs(cfg).items()}
        return out
