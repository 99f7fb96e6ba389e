"""Provenance of a dataset: the versions of the packages that made it, the git revision of mcjax and
when it was made, written into every part's schema metadata (:func:`environment_metadata`). No JAX."""

from __future__ import annotations

import platform
import subprocess
from datetime import datetime, timezone
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any

_VERSIONED_PACKAGES = ("jax", "jaxlib", "numpy", "pandas", "pyarrow", "optax", "mcjax")


def _package_version(name: str) -> str:
    try:
        return importlib_metadata.version(name)
    except importlib_metadata.PackageNotFoundError:
        if name == "mcjax":  # source checkout on PYTHONPATH, not pip-installed
            try:
                from mcjax import __version__

                return str(__version__)
            except ImportError:
                pass
        return "not installed"


def _git(args: list[str], cwd: Path) -> str | None:
    try:
        proc = subprocess.run(
            ["git", *args],
            cwd=cwd,
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    if proc.returncode != 0:
        return None
    return proc.stdout


def environment_metadata() -> dict[str, Any]:
    """Provenance of the current process, suitable as ``metadata`` for :func:`mcjax.base.parquet.write_part`.

    Keys: ``python`` (version string), ``jax``, ``jaxlib``, ``numpy``, ``pandas``,
    ``pyarrow``, ``optax``, ``mcjax`` (distribution versions from
    :func:`importlib.metadata.version`, ``"not installed"`` if missing; ``mcjax`` falls back
    to ``mcjax.__version__`` when run from a source checkout), ``git_revision``
    (``git rev-parse HEAD`` in the mcjax package directory, or ``"unknown"``),
    ``git_dirty`` (only when git status is known: ``True`` if there are uncommitted or
    untracked, non-ignored files) and ``created_utc`` (ISO 8601, UTC).  Nothing here
    imports JAX.
    """
    env: dict[str, Any] = {"python": platform.python_version()}
    for name in _VERSIONED_PACKAGES:
        env[name] = _package_version(name)

    pkg_dir = Path(__file__).resolve().parent
    head = _git(["rev-parse", "HEAD"], pkg_dir)
    env["git_revision"] = head.strip() if head and head.strip() else "unknown"
    status = _git(["status", "--porcelain"], pkg_dir)
    if status is not None:
        env["git_dirty"] = bool(status.strip())
    env["created_utc"] = datetime.now(timezone.utc).isoformat(timespec="seconds")
    return env
