"""Every filter by its name: the built-in records (:data:`BUILTIN`), those installed packages declare under
the entry-point group ``mcjax.filters``, and references ``"file.py:ATTRIBUTE"`` / ``"package.module:ATTRIBUTE"``
(:func:`get`). A filter is a :class:`mcjax.contract.filter.Filter`; nothing else knows what a filter is.

Three ways to name a filter in a config's ``filters`` list:

* a built-in name (:data:`FILTER_KINDS`);
* the name a plugin registers: another installed package declares, in its ``pyproject.toml``,
  ``[project.entry-points."mcjax.filters"] my_filter = "my_pkg.module:FILTER"``;
* a reference ``"path/to/file.py:FILTER"`` or ``"some.module:FILTER"``. A config or spec file's relative file
  path is read against that file's folder, a command line's against the current folder (both made absolute
  when the file is read: :func:`mcjax.base.plugins.absolute_reference`); here, against ``base_dir`` or the
  current folder.

A filter is shown by its record's name (:attr:`mcjax.contract.filter.Filter.name`) wherever a built-in's name
appears — the datasets' ``filter`` column, the tables, the report's sentences — and where it came from (the
file, module or plugin) once, in the dataset's metadata (:func:`shown_name`, :func:`sources`); a config's
``filters`` keeps what was written, the reference. Two filters of one config with one record name are refused
(:func:`same_names`).
"""

from __future__ import annotations

import sys
from importlib.metadata import entry_points
from pathlib import Path

from mcjax.base.plugins import absolute_reference, import_reference, module_file
from mcjax.base.validation import near_name
from mcjax.contract.filter import Filter
from mcjax.tracking.filters.consensus import CIF, ICF, KCF, LOCAL, MODIFIED_ICF
from mcjax.tracking.filters.robust_consensus import CI, HCMCI

#: Entry-point group of third-party filters.
ENTRY_POINT_GROUP = "mcjax.filters"

BUILTIN: dict[str, Filter] = {f.name: f for f in (CIF, ICF, MODIFIED_ICF, KCF, LOCAL, CI, HCMCI)}
#: The built-in filters' names, in this order.
FILTER_KINDS = tuple(BUILTIN)

#: Filters resolved from a plugin or a reference, by the name they were asked for, and where they came from.
_FOUND: dict[str, tuple[Filter, str]] = {}


def _plugin_points() -> dict:
    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def known() -> list[str]:
    """Names of every filter: the built-in ones, then the installed plugins'."""
    return [*BUILTIN, *sorted(n for n in _plugin_points() if n not in BUILTIN)]


def _checked(obj, ref: str, plugin: str | None = None) -> Filter:
    """``obj`` when it is a Filter whose name is its own: not a built-in's, nor (for a file or a module named by
    reference) an installed plugin's other than this very record (``plugin``: the entry point it was loaded by)."""
    if not isinstance(obj, Filter):
        raise ValueError(f"filter {ref!r} is a {type(obj).__name__}, not an mcjax.contract.filter.Filter")
    if obj.name in BUILTIN and BUILTIN[obj.name] is not obj:
        raise ValueError(f"filter {ref!r} is named {obj.name!r}, the name of a built-in filter; give it another name")
    points = _plugin_points()
    if plugin is None and obj.name in points:
        try:
            same = points[obj.name].load() is obj
        except Exception:  # noqa: BLE001 - a plugin that does not load is not this record
            same = False
        if not same:
            raise ValueError(f"filter {ref!r} is named {obj.name!r}, the name of the installed plugin "
                             f"{points[obj.name].value}; give it another name (the datasets show a filter by its name)")
    return obj


def _key(name: str, base_dir) -> str:
    """What a filter asked for as ``name`` is kept under: a relative ``FILE.py:ATTR`` made absolute (against
    ``base_dir``, else the current folder), so that one name read from two folders is two files."""
    return absolute_reference(name, Path.cwd() if base_dir is None else base_dir)


def did_you_mean(name: str, names) -> str:
    """``"; did you mean 'X'?"`` for the name of ``names`` one typo away from ``name``
    (:func:`mcjax.base.validation.near_name`), else ``""``."""
    close = near_name(name, names)
    return f"; did you mean {close!r}?" if close else ""


def get(name: str, base_dir: str | Path | None = None) -> Filter:
    """The filter called ``name`` (module docstring); a one-line ValueError otherwise (an unknown name with
    the known ones and a did-you-mean, a plugin, file or module that fails to import, an object that is not a
    Filter, a reference to a record named like a built-in or an installed plugin). A built-in name is always
    the built-in: an installed plugin whose entry point takes one is refused by :func:`clashes`, not resolved.
    Plugins and references are imported once per process (a relative file by its absolute path)."""
    if not isinstance(name, str):
        raise ValueError(f"filter must be a name, one of {', '.join(known())} (or 'file.py:ATTRIBUTE'); got {name!r}")
    if name in BUILTIN:
        return BUILTIN[name]
    key = _key(name, base_dir)
    if key in _FOUND:
        return _FOUND[key][0]
    plugins = _plugin_points()
    if name in plugins:
        point = plugins[name]
        try:
            obj = point.load()
        except Exception as exc:  # its one line, not a traceback
            raise ValueError(f"filter {name!r}: the plugin {point.value} failed to import: "
                             f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}") from None
        found = (_checked(obj, name, point.value),
                 f"plugin {point.value}{module_file(sys.modules.get(point.module))}")
    elif ":" in name:
        obj, source = import_reference(name, None if base_dir is None else Path(base_dir), "filter", one_line=True)
        found = (_checked(obj, name), source)
    else:
        raise ValueError(f"filter must be one of {', '.join(known())} (or 'file.py:ATTRIBUTE'); got {name!r}"
                         f"{did_you_mean(name, known())}")
    _FOUND[key] = found
    return found[0]


def clashes() -> list[str]:
    """One line per installed plugin whose entry point takes a built-in filter's name (it would be shadowed,
    or shadow the built-in, in silence): the commands that run filters refuse to start on any (exit 2), and
    ``mcjax list filters`` shows them."""
    return [f"filter {name!r}: the installed plugin {point.value}{_distribution(point)} declares the name of a "
            f"built-in filter (entry-point group {ENTRY_POINT_GROUP}); rename its entry point or uninstall it"
            for name, point in _plugin_points().items() if name in BUILTIN]


def _distribution(point) -> str:
    dist = getattr(point, "dist", None)
    return f" in the distribution {dist.name}" if dist is not None and getattr(dist, "name", None) else ""


def origin(name: str) -> str | None:
    """Where the filter asked for as ``name`` came from (a plugin, a file, a module); None for a built-in."""
    key = _key(name, None)
    return _FOUND[key][1] if key in _FOUND else None


def shown_name(name: str, own=()) -> str:
    """The name the datasets, tables and pages show for the filter a config names ``name``: the record's name
    (a built-in's and any of ``own``, a scenario's own filter kinds, is ``name`` itself); ``name`` when it
    names no filter record."""
    if name in BUILTIN or name in own:
        return name
    try:
        return get(name).name
    except ValueError:
        return name


def sources(names, own=()) -> dict[str, str]:
    """Shown name → where the filter came from (:func:`origin`: a plugin, a file, a module), for each of
    ``names`` that is neither built in nor one of ``own``: what a dataset's metadata keeps of the reference."""
    out = {}
    for name in names:
        if name in BUILTIN or name in own:
            continue
        shown = shown_name(name, own)  # resolves it (get), so that origin knows it
        if origin(name) is not None:
            out[shown] = origin(name)
    return out


def same_names(names, own=()) -> str | None:
    """A one-line refusal when two of ``names`` (a config's ``filters``) are shown by one name — two files'
    records both named 'my_ekf', a record named like an installed plugin the config also runs — else None."""
    seen: dict[str, str] = {}
    for name in names:
        shown = shown_name(name, own)
        if shown in seen and seen[shown] != name:
            return (f"filters: {seen[shown]!r} and {name!r} are both named {shown!r} (the name the datasets show); "
                    f"rename one of the two records")
        seen.setdefault(shown, name)
    return None
