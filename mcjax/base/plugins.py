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


class ImportFailed(ValueError):
    """A referenced file or module that failed to import (its code raised, or a module it needs is missing),
    in one line: the reference, what was imported, the exception's type, its first line and the line of the
    file it was raised at."""


def failure(exc: BaseException, path: str | None = None) -> str:
    """``"TYPE: first line (line N)"`` of an exception raised while importing: N is the line of ``path`` (a
    file imported by reference) it was raised at, or the line a SyntaxError names; for a module, the deepest
    frame outside Python's import machinery, as ``(FILE, line N)``."""
    text = str(exc).splitlines()[0] if str(exc) else ""
    if isinstance(exc, SyntaxError) and exc.lineno is not None:
        text = exc.msg
        where = f" (line {exc.lineno})" if path is None or exc.filename in (None, path) else \
            f" ({exc.filename}, line {exc.lineno})"
        return f"{type(exc).__name__}: {text}{where}"
    frames = []
    tb = exc.__traceback__
    while tb is not None:
        frames.append((tb.tb_frame.f_code.co_filename, tb.tb_lineno))
        tb = tb.tb_next
    mine = [f for f in frames if path is not None and f[0] == path]
    outside = [f for f in frames if "importlib" not in f[0] and not f[0].startswith("<frozen")
               and not f[0].endswith("plugins.py")]
    if mine:
        where = f" (line {mine[-1][1]})"
    elif outside:
        where = f" ({outside[-1][0]}, line {outside[-1][1]})"
    else:
        where = ""
    return f"{type(exc).__name__}: {text}{where}"


def import_reference(ref: str, base_dir: Path | None, kind: str, *, one_line: bool = False) -> tuple[Any, str]:
    """``(object, where it came from)`` for ``ref`` (``FILE.py:ATTR`` or ``MODULE:ATTR``); ``kind`` (a
    scenario, a filter) names it in the one-line ValueError of a missing file or attribute. A file is
    imported once per process under a name of its own; one whose code fails is not left half-imported.
    ``one_line``: a file or module whose import fails is an :class:`ImportFailed` of one line
    (``"filter 'x.py:F': importing /abs/x.py failed: NameError: name 'foo' is not defined (line 3)"``), not
    the exception its code raised."""
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
            except BaseException as exc:  # not half a module for the next call to find: it fails the same way
                del sys.modules[name]
                if one_line and isinstance(exc, Exception):
                    raise ImportFailed(f"{kind} {ref!r}: importing {path} failed: {failure(exc, str(path))}") from None
                raise
        source = str(path)
    else:
        try:
            module = importlib.import_module(where)
        except Exception as exc:
            if not one_line:
                raise
            raise ImportFailed(f"{kind} {ref!r}: importing module {where} failed: {failure(exc)}") from None
        source = f"module {where}{module_file(module)}"
    if not hasattr(module, attr):
        raise ValueError(f"{kind} {ref!r}: {where} has no attribute {attr!r}")
    return getattr(module, attr), source
