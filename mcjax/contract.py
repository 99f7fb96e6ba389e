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


def _bad(allowed: str, value) -> str:
    return f"must be {allowed}; got {value!r}"


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
        """None if ``value`` is allowed, else ``"must be …; got …"``."""
        if self.many:
            ok = isinstance(value, tuple) and len(value) > 0 and len(set(value)) == len(value)
            unknown = [v for v in value if v not in self.choices] if isinstance(value, tuple) else []
            if ok and not unknown:
                return None
            return _bad(self.allowed(), value) + (f" (unknown: {', '.join(map(repr, unknown))})" if unknown else "")
        if self.choices is not None:
            return None if value in self.choices else _bad(self.allowed(), value)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return _bad("a number" if not self.integer else "an integer", value)
        if self.integer and not isinstance(value, int):
            return _bad(self.allowed(), value)
        if not math.isfinite(value) or not _in_range(np.asarray(value), self.low, self.high, self.low_open):
            return _bad(self.allowed() + (f" {self.unit}" if self.unit else ""), value)
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

    def allowed(self) -> str:
        if self.choices is not None:
            return " or ".join(_num(c) for c in self.choices)
        return _range_text(self.low, self.high, self.low_open, self.integer)

    def default_value(self, cfg):
        return self.default(cfg) if callable(self.default) else self.default

    def problem(self, value, n_agents: int | None = None) -> str | None:
        """None if ``value`` is allowed (for ``n_agents`` agents, when given: shapes are then
        checked too), else ``"must be …; got …"``."""
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            return _bad("a number or a list of numbers", value)
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

    def as_json(self) -> dict:
        return {"unit": self.unit, "description": self.description, "per_agent": self.per_agent,
                "allowed": self.allowed()}


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
            msg = s.problem(value)
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
    cls = NamedTuple(name, [(k, Any) for k in table])
    cls.__module__ = module
    cls.TABLE = dict(table)
    return cls


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
