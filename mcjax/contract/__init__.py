"""The scenario contract: what a scenario provides, and the declarations everything else reads.

A scenario is a :class:`Scenario`, a frozen record of functions and declarations (not a base
class); the layers above use a scenario only through it and name no scenario, filter or unit:

* ``Config`` (:func:`config_type`, one :class:`Setting` per field): what fixes shapes or the
  compiled program; every Config has ``n_agents``, ``n_steps`` and ``filters`` (display order:
  a per-filter output has one value per filter, in this order);
* ``Params`` (:func:`params_type`, one :class:`Param` per field): a NamedTuple of arrays of
  what a sweep may vary without recompiling;
* ``init``, ``step`` (:class:`Init`, :class:`Step`; pure, jittable) and one ``summary``
  (:data:`Summary`) declaring each :class:`Output` once, next to its value (:func:`declare`),
  ``(F,)`` per filter, ``()`` per run; the record derives ``reduce(cfg, records, params)``
  (:class:`Reduce`) and ``outputs(cfg)`` from it, and ``timeseries`` / ``timeseries_outputs``
  from an optional ``series``; optionally ``check_params``, ``relaxation``
  (:class:`mcjax.contract.relaxation.Relaxation`), ``compiler_options`` (:data:`FAST_COMPILE`, or a function
  of the Config returning such a mapping, where a team's size calls for other options) and
  ``headlines`` (pairs of filter kinds, the one expected lower first: the comparisons its report leads with).

Validation is :mod:`mcjax.base.validation`'s (the declarations' ``problem`` methods call it): it reads
values as a spec (TOML) writes them — kinds are exact (:meth:`Param.problem` with
``exact=True``) and integer Config fields without an upper bound get a :func:`ceiling`. Display
units are :mod:`mcjax.base.units`' (:func:`~mcjax.base.units.display_unit`).
Output roles (:data:`ROLES`) tell the layers above what a column means: ``"error"`` (exactly
one: the metric the report leads with), ``"divergence"``, ``"nonfinite"`` and the graph
statistics, ``"nees"`` and ``"nis"`` (a filter's average NEES / NIS, with its χ² degrees of freedom
in ``dof``) and ``"floor"`` (the error floor, the posterior Cramér–Rao bound's RMSE, in the error's
unit) (optional; each role at most once). ``Scenario(...)`` checks the declarations of
``Config()`` when it is built (ValueError, one line).

This module is a leaf: it imports only the leaves :mod:`mcjax.base.validation` and :mod:`mcjax.base.units`
and no JAX, so every layer (the scenarios too) may use it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Callable, Mapping, NamedTuple, Protocol

import numpy as np

from mcjax.base import validation
from mcjax.base.units import display_unit
# COUNT_CEILING(S) and ceiling: the count limits, also read from here (docs/cli.md, tests/product/test_hardening_corpus.py)
from mcjax.base.validation import COUNT_CEILING, COUNT_CEILINGS, ceiling, setting_problem, show  # noqa: F401

#: Roles an output may declare (see the module docstring).
ROLES = ("error", "divergence", "nonfinite", "connectivity_mean", "connectivity_min", "disconnected_steps",
         "nees", "nis", "floor")


class Output(NamedTuple):
    """Declaration of one summary or timeseries field."""

    unit: str                 # "m", "m/s", "" for counts, flags and dimensionless numbers
    description: str          # one line
    per_filter: bool = True   # one value per filter (else one per run)
    role: str | None = None   # one of ROLES, or None
    dof: int | None = None    # a NEES or NIS: the degrees of freedom of its χ² (the report's band)

    def as_json(self) -> dict:
        return self._asdict()


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
    plugins: str | None = None    # a ``many`` field's members may also be plugins of this entry-point group
    refuses: tuple | None = None  # (entry-point group, why): a plugin of that group is refused with this reason

    def allowed(self) -> str:
        return validation.setting_allowed(self)

    def problem(self, value) -> str | None:
        """None if ``value`` is allowed, else ``"must be …; got …"`` (:func:`mcjax.base.validation.setting_value_problem`)."""
        return validation.setting_value_problem(self, value)


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
    display: str | None = None    # the unit plots show it in (e.g. "km" for "m"; see mcjax.base.units.DISPLAY_UNITS)
    label: str | None = None      # the words the report's sentences name it by (e.g. "comm radius"; None: its name)

    def allowed(self) -> str:
        return validation.param_allowed(self)

    def default_value(self, cfg):
        return self.default(cfg) if callable(self.default) else self.default

    def scalar(self, cfg) -> bool:
        """Whether the field takes one number: no ``shape``, not per agent, and a scalar
        default (for ``cfg``). A field with an array default and no ``shape`` takes any
        shape (its scenario's ``check_params`` checks it)."""
        return self.shape is None and not self.per_agent and np.ndim(self.default_value(cfg)) == 0

    def integral(self) -> bool:
        """Takes integers only: an integer field, or one whose choices are all integers."""
        return self.integer or (self.choices is not None and all(validation.is_int(c) for c in self.choices))

    def expected(self, n_agents: int | None = None, cfg=None) -> str:
        """What the field takes, in words (:func:`mcjax.base.validation.param_expected`)."""
        return validation.param_expected(self, n_agents, cfg)

    def problem(self, value, n_agents: int | None = None, *, exact: bool = False, cfg=None) -> str | None:
        """None if ``value`` is allowed, else ``"must be …; got …"``; ``exact=True`` reads
        ``value`` as a spec gives it (:func:`mcjax.base.validation.param_problem`)."""
        return validation.param_problem(self, value, n_agents, exact=exact, cfg=cfg)

    def display_unit(self) -> tuple[str, float]:
        """``(unit, factor)``: the unit plots show this field in, and the factor to it (:func:`display_unit`)."""
        return display_unit(self.unit, self.display)

    def as_json(self) -> dict:
        shown, factor = self.display_unit()
        out = {"unit": self.unit, "description": self.description, "per_agent": self.per_agent,
               "allowed": self.allowed(), "display_unit": shown, "display_factor": factor}
        return out if self.label is None else {**out, "label": self.label}


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


#: The value a scenario gives its ``compiler_options`` (kept here, beside the field, so a scenario
#: needs nothing but the contract; it is a mapping, and JAX reads it only in the engine):
#: XLA's older CPU fusion code generator: the closed loop of Sun et al. 2011 compiled with ~35–45 %
#: less CPU time, running as fast; Ren & Lv 2017's IMM-UKF ran ~10 % slower (docs/benchmarks.md).
FAST_COMPILE: Mapping[str, Any] = MappingProxyType({"xla_cpu_use_fusion_emitters": False})


class Init(Protocol):
    """``init(cfg, params, key) -> State``: the state before step 0 (pure, jittable)."""
    def __call__(self, cfg: Any, params: Any, key: Any) -> Any: ...


class Step(Protocol):
    """``step(cfg, params, state, key) -> (State, Record)``: one time step (pure, jittable); a
    scenario with a relaxation switch (:class:`mcjax.contract.relaxation.Relaxation`) also takes ``temperatures``
    (None: exact)."""
    def __call__(self, cfg: Any, params: Any, state: Any, key: Any, temperatures: Any = None) -> tuple[Any, Any]: ...


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
            raise ValueError(f"output {name!r} must be (Output(...), a function of no arguments); got {show(item)}")
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
            raise ValueError(f"{where} must be an Output(unit, description, per_filter, role); got {show(o)}")
        for field, kind in (("unit", str), ("description", str), ("per_filter", bool)):
            if not isinstance(getattr(o, field), kind):
                raise ValueError(f"{where}: {field} must be a {kind.__name__}; got {show(getattr(o, field))}")
        if o.role is not None and o.role not in ROLES:
            raise ValueError(f"{where} has the unknown role {show(o.role)}; allowed roles: {', '.join(ROLES)}, None")
        if o.role in ("nees", "nis") and not (isinstance(o.dof, int) and o.dof >= 1):
            raise ValueError(f"{where}: a {o.role} output needs dof, its χ² degrees of freedom (an integer >= 1); "
                             f"got {show(o.dof)}")
        if o.role is not None and seen.setdefault(o.role, name) != name:
            raise ValueError(f"{where}: the role {o.role!r} is declared twice (also by {seen[o.role]!r})")
    if error_role and "error" not in seen:
        raise ValueError(f"{what}: no output has the role 'error' (exactly one must)")


#: Fields of the contract before ``summary=`` / ``series=`` (CHANGELOG.md), and what replaced each.
FORMER_FIELDS = {"reduce": "summary=", "outputs": "summary=", "timeseries": "series=", "timeseries_outputs": "series="}


@dataclass(frozen=True, eq=False)
class Scenario:
    """One simulated system (module docstring), hashed by identity (compiled once per Config).
    Outputs are declared one way: ``summary`` (and optionally ``series``), each output next to its
    value (:func:`declare`); ``reduce`` and ``outputs`` (``timeseries`` and
    ``timeseries_outputs``) derive from them and are what the layers above call."""

    name: str
    title: str                      # one line: the system, and the paper it comes from
    Config: type
    Params: type
    init: Init
    step: Step
    summary: Summary | None = None       # the outputs of a run: each declared once, next to its value
    series: Summary | None = None        # optional: the per-step outputs, declared the same way
    check_params: Callable[[Any, dict], list] | None = None
    relaxation: Any = None               # its relaxation switch, a mcjax.contract.relaxation.Relaxation (optional)
    #: XLA options of its programs (optional): a mapping, or ``cfg -> mapping`` (options by Config)
    compiler_options: Mapping[str, Any] | Callable[[Any], Mapping[str, Any] | None] | None = None
    filter_words: Mapping[str, str] | None = None  # each filter kind in plain words (the report's glossary)
    filter_names: Mapping[str, str] | None = None  # each filter kind's short name in sentences ("modified ICF")
    #: its programs run on one CPU device (True where two running at once deadlock in XLA's CPU runtime)
    one_device: bool = False
    #: the comparisons its report leads with: pairs of filter kinds, the one expected lower first
    headlines: tuple[tuple[str, str], ...] = ()
    # derived from summary / series (not given):
    reduce: Reduce | None = dataclasses.field(init=False, default=None)
    outputs: Callable[[Any], Mapping[str, Output]] | None = dataclasses.field(init=False, default=None)
    timeseries: Reduce | None = dataclasses.field(init=False, default=None)
    timeseries_outputs: Callable[[Any], Mapping[str, Output]] | None = dataclasses.field(init=False, default=None)

    def __post_init__(self):
        me = f"scenario {self.name!r}"
        if not callable(self.summary):
            raise ValueError(f"{me}: summary is missing (a function (cfg, records, params) -> declare(...))")
        for summary, pair in ((self.summary, ("reduce", "outputs")), (self.series, ("timeseries", "timeseries_outputs"))):
            if summary is not None:
                object.__setattr__(self, pair[0], FromSummary(summary, True))
                object.__setattr__(self, pair[1], FromSummary(summary, False))
        for field in ("n_agents", "n_steps", "filters"):  # a Config built by config_type has SETTINGS
            if field not in getattr(self.Config, "SETTINGS", {}):
                raise ValueError(f"{me}: Config must declare {field!r}")
        kinds = tuple(self.settings["filters"].choices or ())
        pairs = _headline_pairs(self.headlines, kinds)
        if pairs is None:
            raise ValueError(f"{me}: headlines must be pairs (expected lower, higher) of two different filter kinds "
                             f"of its Config ({', '.join(kinds) or 'any'}); got {show(self.headlines)}")
        object.__setattr__(self, "headlines", pairs)
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
        names = self.filter_names or {}
        if names:
            out["filter_names"] = {f: names[f] for f in cfg.filters if f in names}
        headlines = [list(p) for p in self.headlines if set(p) <= set(cfg.filters)]
        if headlines:
            out["headlines"] = headlines
        return out


def _headline_pairs(headlines, kinds: tuple) -> tuple[tuple[str, str], ...] | None:
    """``headlines`` as a tuple of pairs of two different filter kinds (of ``kinds``, when given), else None."""
    if not isinstance(headlines, (tuple, list)):
        return None
    pairs = tuple(tuple(p) if isinstance(p, (tuple, list)) else p for p in headlines)
    ok = all(isinstance(p, tuple) and len(p) == 2 and p[0] != p[1]
             and all(isinstance(f, str) and (not kinds or f in kinds) for f in p) for p in pairs)
    return pairs if ok else None


def _naming_former_fields(init):
    """The dataclass's ``__init__``, and a one-line ValueError (not a TypeError) for a field of the contract
    before ``summary=`` (:data:`FORMER_FIELDS`); ``smooth=`` is still read as ``relaxation=``."""
    def __init__(self, *args, **fields):
        name = fields.get("name", args[0] if args else "?")
        gone = [k for k in FORMER_FIELDS if k in fields]
        if gone:
            now = " and ".join(sorted({FORMER_FIELDS[k] for k in gone}))
            raise ValueError(f"scenario {name!r}: {' and '.join(k + '=' for k in gone)} "
                             f"{'is no longer a field' if len(gone) == 1 else 'are no longer fields'} of Scenario: declare each output "
                             f"once, next to its value, with {now} (docs/library.md, 'Writing a scenario'; CHANGELOG.md)")
        if "smooth" in fields:
            if "relaxation" in fields:
                raise ValueError(f"scenario {name!r}: smooth= is the former name of relaxation=; give one of them")
            fields["relaxation"] = fields.pop("smooth")
        init(self, *args, **fields)

    return __init__


Scenario.__init__ = _naming_former_fields(Scenario.__init__)
