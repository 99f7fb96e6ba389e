"""The scenario contract: what a scenario provides, and the declarations everything else reads.

A scenario is a :class:`Scenario`, a frozen record of functions and declarations (not a base
class); the layers above use a scenario only through it and name no scenario, filter or unit:

* ``Config`` (:func:`config_type`, one :class:`Setting` per field): what fixes shapes or the
  compiled program; every Config has ``n_agents``, ``n_steps`` and ``filters`` (display order:
  a per-filter output has one value per filter, in this order);
* ``Params`` (:func:`params_type`, one :class:`Param` per field): a NamedTuple of arrays of
  what a sweep may vary without recompiling;
* ``init``, ``step`` (:class:`Init`, :class:`Step`; pure, jittable) and ``reduce``
  (:class:`Reduce`) to the :class:`Output` fields ``outputs(cfg)`` declares, ``(F,)`` per
  filter, ``()`` per run — or both from one ``summary`` declaring each output once, next to
  its value (:func:`declare`); optionally ``timeseries`` / ``timeseries_outputs`` (or one
  ``series``), ``check_params``, ``smooth`` (:class:`mcjax.smoothing.Smooth`) and ``compiler_options`` (:data:`FAST_COMPILE`).

Validation reads values as a spec (TOML) writes them: kinds are exact (:meth:`Param.problem`
with ``exact=True``) and integer Config fields without an upper bound get :func:`ceiling`.
Output roles (:data:`ROLES`) tell the layers above what a column means: ``"error"`` (exactly
one: the metric the report leads with), ``"divergence"``, ``"nonfinite"`` and the graph
statistics (optional; each role at most once). ``Scenario(...)`` checks the declarations of
``Config()`` when it is built (ValueError, one line).

This module is a leaf: it imports nothing from mcjax and no JAX, so every layer may use it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Callable, Mapping, NamedTuple, Protocol

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


def _show(value) -> str:
    """``repr(value)`` on one line, cut to a readable length."""
    text = repr(value.tolist() if isinstance(value, np.ndarray) else value).replace("\n", " ")
    return text if len(text) <= 120 else text[:100] + f"... ({len(text)} characters)"


def _bad(allowed: str, value) -> str:
    return f"must be {allowed}; got {_show(value)}"


def _shape_text(shape, n_agents=None) -> str:
    """A declared shape as ``n_agentsx2`` (or, given ``n_agents``, its numbers: ``5x2``)."""
    return "x".join(("n_agents" if n_agents is None else str(n_agents)) if d == "n" else str(d) for d in shape)


# Exact kinds of values, as TOML has them: a boolean is no number, a float no integer, a string or
# a table no list (numpy scalars count as their Python kinds).

def _is_bool(v) -> bool:
    return isinstance(v, (bool, np.bool_))


def _is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not _is_bool(v)


def _is_real(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not _is_bool(v)


def _same(value, choice) -> bool:
    """``value`` is ``choice`` in kind and in value: true is not 1, 1.0 is not 1, "1" is not 1."""
    for kind in (lambda v: isinstance(v, str), _is_bool, _is_int, _is_real):
        if kind(choice):
            return kind(value) and value == choice
    return type(value) is type(choice) and value == choice


def _leaves(value):
    """The leaves of a nested list (a value itself if it is no list); None if a leaf is a
    table, a string, a boolean or anything but a number."""
    if isinstance(value, np.ndarray):
        return [value] if value.dtype.kind in "iuf" else None
    if isinstance(value, (list, tuple)):
        subs = [_leaves(v) for v in value]
        return None if any(sub is None for sub in subs) else [leaf for sub in subs for leaf in sub]
    return [value] if _is_real(value) else None


def _integral_leaves(leaves) -> bool:
    """Every leaf is an integer in kind (an integer-typed array counts; a float never does)."""
    return all(_is_int(v) or (isinstance(v, np.ndarray) and v.dtype.kind in "iu") for v in leaves)


def _within(value, low, high, low_open):
    """A range check (element-wise for an array) that also holds for integers beyond float range."""
    ok = True if low is None else (value > low if low_open else value >= low)
    return ok & (True if high is None else value <= high)


#: Upper bounds of the integer Config fields that declare none (agents, steps; every other count:
#: COUNT_CEILING), so no spec asks for more than a machine holds (the study plan's memory check refines them).
COUNT_CEILINGS = {"n_agents": 1_000, "n_steps": 1_000_000}
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
        low, unit = setting.low if setting.low is not None else -math.inf, f" {setting.unit}" if setting.unit else ""
        return _bad(_range_text(low, top, setting.low_open, True) + unit, value)
    return msg


#: Units a value may be shown in: (declared unit, shown unit) -> factor (shown = factor x declared).
DISPLAY_UNITS = {("m", "km"): 1e-3, ("rad", "deg"): 180.0 / math.pi, ("rad/s", "deg/s"): 180.0 / math.pi,
                 ("s", "min"): 1.0 / 60.0, ("s", "h"): 1.0 / 3600.0, ("m/s", "km/h"): 3.6}
#: The shown unit of a declared unit when a Param names none: angles in degrees.
DEFAULT_DISPLAY = {"rad": "deg", "rad/s": "deg/s"}


def display_unit(unit: str, display: str | None = None) -> tuple[str, float]:
    """``(shown unit, factor)`` for a value declared in ``unit``: ``display`` when given (it
    must be ``unit`` or a pair of :data:`DISPLAY_UNITS`, else ValueError), else
    :data:`DEFAULT_DISPLAY`, else ``unit`` unchanged (factor 1)."""
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
            return _bad(self.allowed(), value) if len(value) == 0 or len(set(value)) != len(value) else None
        if self.choices is not None:
            return None if any(_same(value, c) for c in self.choices) else _bad(self.allowed(), value)
        unit = f" {self.unit}" if self.unit else ""
        if not _is_real(value) or (self.integer and not _is_int(value)):
            return _bad(self.allowed() + ("" if self.integer else unit), value)
        finite = _is_int(value) or math.isfinite(value)
        return None if finite and _within(value, self.low, self.high, self.low_open) else _bad(self.allowed() + unit, value)


class Param(NamedTuple):
    """Declaration of one Params field (a sweep may vary it without recompiling). ``default``: a
    value or a function of the Config; ``shape``: the required shape, ``"n"`` for the number of
    agents (None: any); a ``per_agent`` field takes a scalar (every agent) or one value per agent."""

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

    def integral(self) -> bool:
        """Takes integers only: an integer field, or one whose choices are all integers."""
        return self.integer or (self.choices is not None and all(_is_int(c) for c in self.choices))

    def expected(self, n_agents: int | None = None, cfg=None) -> str:
        """What the field takes, in words: its form (a number, one per agent, a shape) and
        its allowed values, e.g. ``"a number or a list of n_agents = 5 numbers, >= 0 m"``."""
        kind = "integer" if self.integral() else "number"
        one = f"a{'n' if kind == 'integer' else ''} {kind}"
        if self.shape is not None:
            want = "" if n_agents is None else f" ({_shape_text(self.shape, n_agents)})"
            form = f"an array of {kind}s of shape {_shape_text(self.shape)}{want}"
        elif self.per_agent:
            form = f"{one} or a list of {'n_agents' if n_agents is None else f'n_agents = {n_agents}'} {kind}s"
        else:
            form = one if cfg is not None and self.scalar(cfg) else f"{one} or a rectangular list of {kind}s"
        if self.choices is not None:
            return f"{form}, {self.allowed()}"
        rng = _range_text(self.low, self.high, self.low_open, False)
        return form if rng == "any number" else f"{form}, {rng}" + (f" {self.unit}" if self.unit else "")

    def problem(self, value, n_agents: int | None = None, *, exact: bool = False, cfg=None) -> str | None:
        """None if ``value`` is allowed (for ``n_agents`` agents, when given: shapes are then
        checked too), else ``"must be …; got …"``; a boolean, string, table or ragged list is no
        number. ``exact=True`` reads ``value`` as a spec gives it: an integer field (or one with
        integer choices) takes integers only (``5.0`` is a float), and with ``cfg`` (which also
        sets ``n_agents``) a :meth:`scalar` field takes one number only."""
        if cfg is not None:
            n_agents = cfg.n_agents
        leaves = _leaves(value)
        if leaves is None:
            return _bad(self.expected(n_agents, cfg) if exact else "a number or a list of numbers", value)
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):  # ragged, or an integer beyond float range
            return _bad(self.expected(n_agents, cfg) if exact else "a number or a list of numbers", value)
        if exact and self.integral() and not _integral_leaves(leaves):
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
        elif not np.all(_within(arr, self.low, self.high, self.low_open)):
            return _bad(self.allowed() + (f" {self.unit}" if self.unit else ""), value)
        if n_agents is not None:
            if self.per_agent and arr.shape not in ((), (n_agents,)):
                return _bad(f"a number or a list of n_agents = {n_agents} numbers", value)
            if self.shape is not None:
                if arr.shape != tuple(n_agents if d == "n" else d for d in self.shape):
                    return _bad(f"of shape {_shape_text(self.shape)} ({_shape_text(self.shape, n_agents)})", value)
        return None

    def display_unit(self) -> tuple[str, float]:
        """``(unit, factor)``: the unit plots show this field in, and the factor to it (:func:`display_unit`)."""
        return display_unit(self.unit, self.display)

    def as_json(self) -> dict:
        shown, factor = self.display_unit()
        return {"unit": self.unit, "description": self.description, "per_agent": self.per_agent,
                "allowed": self.allowed(), "display_unit": shown, "display_factor": factor}


def config_type(name: str, settings: Mapping[str, Setting], module: str,
                check: Callable[[Any], None] | None = None) -> type:
    """A frozen dataclass with one field per :class:`Setting` (in order; kept as ``SETTINGS``) whose
    construction validates every field (ValueError naming it and its allowed values; a list for a
    ``many`` field becomes a tuple), then runs ``check(cfg)`` across fields. ``module``: the
    defining module's ``__name__`` (so configs pickle)."""

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


#: XLA's older CPU fusion code generator: the closed loop of Sun et al. 2011 compiled with ~35–45 %
#: less CPU time, running as fast; Ren & Lv 2017's IMM-UKF ran ~10 % slower (docs/benchmarks.md).
FAST_COMPILE: Mapping[str, Any] = MappingProxyType({"xla_cpu_use_fusion_emitters": False})


class Init(Protocol):
    """``init(cfg, params, key) -> State``: the state before step 0 (pure, jittable)."""
    def __call__(self, cfg: Any, params: Any, key: Any) -> Any: ...


class Step(Protocol):
    """``step(cfg, params, state, key) -> (State, Record)``: one time step (pure, jittable); a
    scenario with a smoothing switch (:class:`mcjax.smoothing.Smooth`) also takes ``smoothing``
    (None: exact)."""
    def __call__(self, cfg: Any, params: Any, state: Any, key: Any, smoothing: Any = None) -> tuple[Any, Any]: ...


class Reduce(Protocol):
    """``reduce(cfg, records, params) -> {name: array}``: one run's records (stacked over time)
    to its declared outputs; ``timeseries`` has the same form."""
    def __call__(self, cfg: Any, records: Any, params: Any) -> Mapping[str, Any]: ...


#: ``summary(cfg, records, params) -> declare(...)``: each output's :class:`Output` next to the
#: thunk computing it; called with ``records = params = None`` for the declarations alone.
Summary = Callable[[Any, Any, Any], Mapping[str, "tuple[Output, Callable[[], Any]]"]]


def declare(**items: tuple[Output, Callable[[], Any]]) -> Mapping[str, tuple[Output, Callable[[], Any]]]:
    """``{name: (Output, thunk)}`` from ``name=(Output(...), lambda: value)``, in order, each checked
    (ValueError naming it). A value shared by outputs goes in a ``functools.cache``-d thunk."""
    for name, item in items.items():
        if not (isinstance(item, tuple) and len(item) == 2 and isinstance(item[0], Output) and callable(item[1])):
            raise ValueError(f"output {name!r} must be (Output(...), a function of no arguments); got {_show(item)}")
    return MappingProxyType(items)


class FromSummary(NamedTuple):
    """A :class:`Summary` as ``outputs(cfg)`` (``values`` False: the declarations) or as
    ``reduce(cfg, records, params)`` (True: every thunk's value), in declaration order."""

    summary: Summary
    values: bool

    def __call__(self, cfg, records=None, params=None):
        items = self.summary(cfg, records, params).items()
        return {k: v() for k, (_, v) in items} if self.values else {k: o for k, (o, _) in items}


def check_outputs(declared, what: str, *, error_role: bool) -> None:
    """Each an :class:`Output` (str unit and description, bool per_filter, role in :data:`ROLES`
    or None), no role twice, one ``"error"`` with ``error_role``; else a one-line ValueError."""
    seen: dict = {}
    for name, o in declared.items():
        where = f"{what}: output {name!r}"
        if not isinstance(o, Output):
            raise ValueError(f"{where} must be an Output(unit, description, per_filter, role); got {_show(o)}")
        for field, kind in (("unit", str), ("description", str), ("per_filter", bool)):
            if not isinstance(getattr(o, field), kind):
                raise ValueError(f"{where}: {field} must be a {kind.__name__}; got {_show(getattr(o, field))}")
        if o.role is not None and o.role not in ROLES:
            raise ValueError(f"{where} has the unknown role {_show(o.role)}; allowed roles: {', '.join(ROLES)}, None")
        if o.role is not None and seen.setdefault(o.role, name) != name:
            raise ValueError(f"{where}: the role {o.role!r} is declared twice (also by {seen[o.role]!r})")
    if error_role and "error" not in seen:
        raise ValueError(f"{what}: no output has the role 'error' (exactly one must)")


@dataclass(frozen=True, eq=False)
class Scenario:
    """One simulated system (module docstring), hashed by identity (compiled once per Config).
    ``summary`` gives ``reduce`` and ``outputs``; ``series`` ``timeseries`` and its outputs."""

    name: str
    title: str                      # one line: the system, and the paper it comes from
    Config: type
    Params: type
    init: Init
    step: Step
    reduce: Reduce | None = None
    outputs: Callable[[Any], Mapping[str, Output]] | None = None
    timeseries: Reduce | None = None
    timeseries_outputs: Callable[[Any], Mapping[str, Output]] | None = None
    check_params: Callable[[Any, dict], list] | None = None
    smooth: Any = None                   # its smoothing switch, a mcjax.smoothing.Smooth (optional)
    compiler_options: Mapping[str, Any] | None = None  # XLA options of its programs (optional)
    summary: Summary | None = None       # reduce and outputs in one
    series: Summary | None = None        # timeseries and timeseries_outputs in one
    filter_words: Mapping[str, str] | None = None  # each filter kind in plain words (the report's glossary)
    #: its programs run on one CPU device (True where two running at once deadlock in XLA's CPU runtime)
    one_device: bool = False

    def __post_init__(self):
        me = f"scenario {self.name!r}"
        for summary, pair in ((self.summary, ("reduce", "outputs")), (self.series, ("timeseries", "timeseries_outputs"))):
            if summary is not None:
                if any(not isinstance(getattr(self, f), (FromSummary, type(None))) for f in pair):  # (derived: replaced)
                    raise ValueError(f"{me}: give {' and '.join(pair)} or a summary of both, not both")
                object.__setattr__(self, pair[0], FromSummary(summary, True))
                object.__setattr__(self, pair[1], FromSummary(summary, False))
        for field in ("reduce", "outputs"):
            if not callable(getattr(self, field)):
                raise ValueError(f"{me}: {field} is missing (give {field}, or summary)")
        for field in ("n_agents", "n_steps", "filters"):  # a Config built by config_type has SETTINGS
            if field not in getattr(self.Config, "SETTINGS", {}):
                raise ValueError(f"{me}: Config must declare {field!r}")
        if (self.timeseries is None) != (self.timeseries_outputs is None):
            raise ValueError(f"{me}: timeseries and timeseries_outputs go together")
        cfg = self.Config()
        check_outputs(self.outputs(cfg), f"{me}: outputs(Config())", error_role=True)
        if self.timeseries_outputs is not None:
            check_outputs(self.timeseries_outputs(cfg), f"{me}: timeseries_outputs(Config())", error_role=False)

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
        words = self.filter_words or {}
        out["filter_descriptions"] = {f: words[f] for f in cfg.filters if f in words}
        return out
