"""What a dataset's metadata says about its runs table: the :class:`Schema` (which column holds
the error metric, the divergence flag, the graph statistics — by their declared *role* —, the
filters' display order, the declarations), the swept axes, a column's unit, label and display
unit (and a summary's axes in the tables' units: :func:`in_table_units`), the filters in display order. Read from the metadata alone (the scenario's declarations,
:mod:`mcjax.contract`); nothing names a scenario, a filter or a unit. No JAX, no matplotlib."""

from __future__ import annotations

import math
from typing import Any, Iterable, Mapping, NamedTuple, Sequence

import numpy as np
import pandas as pd

from mcjax.base.units import display_unit

#: The roles a dataset may declare besides ``"error"``.
OPTIONAL_ROLES = ("divergence", "nonfinite", "connectivity_mean", "connectivity_min",
                   "disconnected_steps", "nees", "nis", "floor")

NO_OUTPUTS = ("the dataset's metadata declares no outputs (no 'outputs' entry): it was written "
              "by an older mcjax, before scenarios declared their outputs. Re-run the sweep with "
              "this mcjax (`mcjax sweep SPEC --out OUT --force`) to write a dataset the report "
              "can read")


class Schema(NamedTuple):
    """What a dataset's metadata says about its runs table (see :func:`schema`)."""

    scenario: str
    title: str
    error: str                       # column of the error metric (role "error")
    divergence: str | None           # column of the divergence flag, if declared
    nonfinite: str | None            # column of the non-finite flag, if declared
    connectivity_mean: str | None    # per-run mean graph connectivity, if declared
    connectivity_min: str | None     # per-run minimum graph connectivity, if declared
    disconnected_steps: str | None   # per-run count of disconnected steps, if declared
    filters: tuple[str, ...]         # display order of the filter column's values
    outputs: Mapping[str, Mapping[str, Any]]
    params: Mapping[str, Mapping[str, Any]]
    spec: Mapping[str, Any]          # the sweep spec (its grid and zip tables)
    nees: str | None = None          # per-run average NEES per filter (dof in its declaration), if declared
    nis: str | None = None           # per-run average NIS per filter, if declared
    floor: str | None = None         # per-run error floor (the PCRB's RMSE, the error's unit), if declared

    @property
    def connectivity(self) -> tuple[str, ...]:
        """The declared graph-statistics columns (empty without a graph)."""
        return tuple(c for c in (self.connectivity_mean, self.connectivity_min,
                                 self.disconnected_steps) if c is not None)


def schema(metadata: Mapping[str, Any] | Schema, columns: Iterable[str] | None = None) -> Schema:
    """The :class:`Schema` of a dataset's metadata (as :func:`mcjax.base.parquet.read_metadata`
    returns it); a :class:`Schema` is returned unchanged.

    With ``columns``, every column named by a role must be one of them.

    Raises:
        ValueError: no ``outputs`` in the metadata (an older dataset; the message says what
            to do), not exactly one output with role ``"error"``, a role declared twice, or
            a role's column missing from ``columns``.
        TypeError: ``metadata`` is not a dict.
    """
    if isinstance(metadata, Schema):
        sch = metadata
    else:
        if not isinstance(metadata, Mapping):
            raise TypeError(f"metadata must be a dict, got {type(metadata).__name__}")
        outputs = metadata.get("outputs")
        if not outputs:
            raise ValueError(NO_OUTPUTS)
        if not isinstance(outputs, Mapping):
            raise ValueError(f"metadata 'outputs' must be a table of declarations, got {outputs!r}")
        roles: dict[str, str] = {}
        for name, decl in outputs.items():
            role = decl.get("role") if isinstance(decl, Mapping) else None
            if role is None:
                continue
            if role in roles:
                raise ValueError(f"outputs {roles[role]!r} and {name!r} both declare role {role!r}; "
                                 "a role names one column")
            roles[role] = str(name)
        if "error" not in roles:
            raise ValueError("no output declares role 'error' (the metric the report leads with); "
                             f"declared outputs: {', '.join(map(str, outputs))}")
        params = metadata.get("params") or {}
        spec = metadata.get("spec") or {}
        sch = Schema(
            scenario=str(metadata.get("scenario") or ""),
            title=str(metadata.get("title") or ""),
            error=roles["error"],
            **{r: roles.get(r) for r in OPTIONAL_ROLES},
            filters=tuple(str(f) for f in (metadata.get("filters") or ())),
            outputs=dict(outputs),
            params=dict(params) if isinstance(params, Mapping) else {},
            spec=spec if isinstance(spec, Mapping) else {},
        )
    if columns is not None:
        cols = set(columns)
        missing = [c for c in (sch.error, *(getattr(sch, r) for r in OPTIONAL_ROLES))
                   if c is not None and c not in cols]
        if missing:
            raise ValueError(f"declared output column(s) {missing} are not in the runs table; "
                             f"it has {sorted(map(str, cols))}")
    return sch


def swept_axes(metadata: Mapping[str, Any] | Schema | None, columns: Iterable[str]) -> list[str]:
    """Swept axes of a sweep: keys of ``metadata["spec"]["grid"]`` then of ``["zip"]``
    (a table, or a list of tables), in spec order, restricted to ``columns``."""
    spec = metadata.spec if isinstance(metadata, Schema) else ((metadata or {}).get("spec") or {})
    if not isinstance(spec, Mapping):
        return []
    names: list[str] = []
    tables: list[Any] = [spec.get("grid") or {}]
    zipped = spec.get("zip") or {}
    tables.extend(zipped if isinstance(zipped, list) else [zipped])
    for table in tables:
        if isinstance(table, Mapping):
            names.extend(k for k in table if k not in names)
    cols = set(columns)
    return [n for n in names if n in cols]


def declarations(metadata: Mapping[str, Any] | Schema) -> tuple[Mapping, Mapping]:
    if isinstance(metadata, Schema):
        return metadata.outputs, metadata.params
    return (metadata.get("outputs") or {}), (metadata.get("params") or {})


def declaration(name: str, metadata: Mapping[str, Any] | Schema) -> Mapping[str, Any]:
    outputs, params = declarations(metadata)
    decl = outputs.get(name) if name in outputs else params.get(name)
    return decl if isinstance(decl, Mapping) else {}


def unit(name: str, metadata: Mapping[str, Any] | Schema) -> str:
    """Declared unit of an output or parameter column (``""`` if none or undeclared)."""
    return str(declaration(name, metadata).get("unit") or "")


def label(name: str, metadata: Mapping[str, Any] | Schema) -> str:
    """``"name [unit]"`` for an output or parameter column; just ``name`` without a unit."""
    u = unit(name, metadata)
    return f"{name} [{u}]" if u else name


def display(name: str, metadata: Mapping[str, Any] | Schema) -> tuple[str, float]:
    """``(unit, factor)`` a parameter column is shown in on plots: the display unit its
    declaration names (``display_unit`` / ``display_factor`` in the metadata), else
    :func:`mcjax.base.units.display_unit` of its declared unit (degrees for radians); an
    output column keeps its unit (factor 1)."""
    _, params = declarations(metadata)
    decl = params.get(name) if isinstance(params, Mapping) else None
    u = unit(name, metadata)
    if not isinstance(decl, Mapping):
        return u, 1.0
    shown, factor = decl.get("display_unit"), decl.get("display_factor")
    if isinstance(shown, str) and isinstance(factor, (int, float)) and not isinstance(factor, bool) \
            and math.isfinite(factor) and factor > 0:
        return shown, float(factor)
    try:
        return display_unit(u)
    except ValueError:
        return u, 1.0


def scaled(value: Any, factor: float) -> Any:
    """A value (a number, or a per-agent tuple of them) times ``factor``: an axis's value in its
    display unit (:func:`display`); anything else as it is."""
    if isinstance(value, (tuple, list)):
        return tuple(scaled(v, factor) for v in value)
    if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_)) \
            and factor != 1.0:
        return value * factor
    return value


def table_unit(name: str, metadata: Mapping[str, Any] | Schema) -> tuple[str, float]:
    """``(unit, factor)`` a column is printed in by the summary tables: an angle in degrees
    (:data:`mcjax.base.units.DEFAULT_DISPLAY`, as the plots and the page show it: radians are read
    by no one), every other unit as declared (metres as the spec writes them; the plots may show
    km: :func:`display`)."""
    u = unit(name, metadata)
    try:
        return display_unit(u)
    except ValueError:
        return u, 1.0


def in_table_units(summary: pd.DataFrame, metadata: Mapping[str, Any] | Schema,
                   axes: Sequence[str]) -> pd.DataFrame:
    """``summary`` with each of ``axes`` in its :func:`table_unit` (an angle in degrees); the same
    object when none changes. What the printed table and the page's full table show (a CSV keeps
    the dataset's units)."""
    out = summary
    for a in axes:
        factor = table_unit(a, metadata)[1]
        if factor != 1.0 and a in summary.columns:
            out = out.copy() if out is summary else out
            out[a] = summary[a].map(lambda v, f=factor: scaled(v, f))
    return out


def axis_label(name: str, metadata: Mapping[str, Any] | Schema) -> str:
    """``"name [display unit]"`` (see :func:`display`); just ``name`` without a unit."""
    u = display(name, metadata)[0]
    return f"{name} [{u}]" if u else name


def filter_rank(order: Sequence[str]):
    def rank(value: Any) -> tuple[int, str]:
        s = str(value)
        return (order.index(s), "") if s in order else (len(order), s)
    return rank


def ordered_filters(values: Iterable[Any], order: Sequence[str]) -> list[Any]:
    """The distinct ``values`` of a filter column: those in ``order`` (the metadata's
    ``filters``) in that order, then the others alphabetically."""
    return sorted(pd.unique(pd.Series(list(values), dtype=object)), key=filter_rank(list(order)))


def resolve_axes(metadata: Mapping[str, Any] | Schema, columns: Iterable[str],
                 axes: str | Sequence[str] | None = None) -> list[str]:
    """The columns to group by: the metadata's swept axes when ``axes`` is None, else
    ``axes`` (a name or a list of distinct names), each checked to be in ``columns``."""
    columns = list(columns)
    if axes is None:
        return swept_axes(metadata, columns)
    out = [axes] if isinstance(axes, str) else list(axes)
    for a in out:
        if not isinstance(a, str):
            raise TypeError(f"axes must be column names (str), got {a!r}")
    if len(set(out)) != len(out):
        raise ValueError(f"axes contain duplicates: {out}")
    missing = [a for a in out if a not in columns]
    if missing:
        raise ValueError(f"axis column(s) {missing} not in the runs table; it has {columns}")
    return out
