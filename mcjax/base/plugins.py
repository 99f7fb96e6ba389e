"""Code a config names: a reference ``"path/to/file.py:ATTRIBUTE"`` (relative to a base folder) or
``"package.module:ATTRIBUTE"`` (an importable module), imported and its attribute returned — how a
scenario or a filter of one's own is found (:mod:`mcjax.scenarios`, :mod:`mcjax.tracking.filters.registry`).
Running it runs that code (docs/cli.md, "What a spec may run"). No JAX of its own.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
from pathlib import Path
from typing import Any


def absolute_reference(ref, base_dir: str | Path):
    """``ref`` with a relative ``FILE.py`` made absolute against ``base_dir`` (the folder of the file that
    wrote it, or the current folder for the command line), so that it names the same file from any folder
    and on any worker; anything else (a name, a ``module:ATTR``, an absolute path, not a string) unchanged."""
    if not isinstance(ref, str):
        return ref
    where, sep, attr = ref.rpartition(":")
    if sep and where.endswith(".py") and not Path(where).is_absolute():
        return f"{(Path(base_dir) / where).resolve()}:{attr}"
    return ref


def module_file(module) -> str:
    """`` (FILE)`` of an imported module, or ``""`` for one without a file."""
    where = getattr(module, "__file__", None)
    return f" ({where})" if where else ""


def import_reference(ref: str, base_dir: Path | None, kind: str) -> tuple[Any, str]:
    """``(object, where it came from)`` for ``ref`` (``FILE.py:ATTR`` or ``MODULE:ATTR``); ``kind`` (a
    scenario, a filter) names it in the one-line ValueError of a missing file or attribute. A file is
    imported once per process under a name of its own; one whose code fails is not left half-imported."""
    where, _, attr = ref.rpartition(":")
    if where.endswith(".py"):
        path = Path(where)
        if not path.is_absolute() and base_dir is not None:
            path = base_dir / path
        path = path.resolve()
        if not path.is_file():
            raise ValueError(f"{kind} file not found: {path}")
        name = f"mcjax_user_{kind}_{abs(hash(str(path)))}"
        module = sys.modules.get(name)
        if module is None:
            spec = importlib.util.spec_from_file_location(name, path)
            module = importlib.util.module_from_spec(spec)
            sys.modules[name] = module  # before exec: its dataclasses look their module up
            try:
                spec.loader.exec_module(module)
            except BaseException:  # not half a module for the next call to find: it fails the same way
                del sys.modules[name]
                raise
        source = str(path)
    else:
        module = importlib.import_module(where)
        source = f"module {where}{module_file(module)}"
    if not hasattr(module, attr):
        raise ValueError(f"{kind} {ref!r}: {where} has no attribute {attr!r}")
    return getattr(module, attr), source
