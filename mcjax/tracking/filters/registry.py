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
"""

from __future__ import annotations

import difflib
import sys
from importlib.metadata import entry_points
from pathlib import Path

from mcjax.base.plugins import import_reference, module_file
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


def _checked(obj, ref: str) -> Filter:
    if not isinstance(obj, Filter):
        raise ValueError(f"filter {ref!r} is a {type(obj).__name__}, not an mcjax.contract.filter.Filter")
    if obj.name in BUILTIN and BUILTIN[obj.name] is not obj:
        raise ValueError(f"filter {ref!r} is named {obj.name!r}, the name of a built-in filter; give it another name")
    return obj


def get(name: str, base_dir: str | Path | None = None) -> Filter:
    """The filter called ``name`` (module docstring); a one-line ValueError otherwise (an unknown name with
    the known ones and a did-you-mean, a plugin that fails to import, an object that is not a Filter, a
    reference to a record named like a built-in). A built-in name is always the built-in: an installed plugin
    whose entry point takes one is refused by :func:`clashes`, not resolved. Plugins and
    references are imported once per process."""
    if not isinstance(name, str):
        raise ValueError(f"filter must be a name, one of {', '.join(known())} (or 'file.py:ATTRIBUTE'); got {name!r}")
    if name in BUILTIN:
        return BUILTIN[name]
    if name in _FOUND:
        return _FOUND[name][0]
    plugins = _plugin_points()
    if name in plugins:
        point = plugins[name]
        try:
            obj = point.load()
        except Exception as exc:  # its one line, not a traceback
            raise ValueError(f"filter {name!r}: the plugin {point.value} failed to import: "
                             f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}") from None
        found = (_checked(obj, name), f"plugin {point.value}{module_file(sys.modules.get(point.module))}")
    elif ":" in name:
        obj, source = import_reference(name, None if base_dir is None else Path(base_dir), "filter")
        found = (_checked(obj, name), source)
    else:
        close = difflib.get_close_matches(name, known(), n=1, cutoff=0.75)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ValueError(f"filter must be one of {', '.join(known())} (or 'file.py:ATTRIBUTE'); got {name!r}{hint}")
    _FOUND[name] = found
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
    return _FOUND[name][1] if name in _FOUND else None
