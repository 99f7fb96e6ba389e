"""Writing files so that no reader ever sees a torn one: :func:`atomic_write`, the one helper
every module that writes a file uses (part files, identity files, tune state, the report's
page, stored programs).

This module is a leaf: it imports nothing from mcjax and no JAX.
"""

from __future__ import annotations

import json
import os
import uuid
from pathlib import Path
from typing import Callable


def fsync_dir(path: str | os.PathLike) -> None:
    """Best-effort fsync of a folder (makes a rename in it durable on POSIX)."""
    if os.name != "posix":
        return
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write(path: str | os.PathLike, write: Callable[[Path], None] | bytes | str, *,
                 staging: str | os.PathLike | None = None, durable: bool = True) -> Path:
    """Write ``path`` whole or not at all: ``write(tmp)`` (or the bytes / UTF-8 text given)
    writes a uniquely named temporary file — beside ``path``, hidden, or in the folder
    ``staging`` (on the same file system) —, which is fsynced and renamed onto ``path``
    (:func:`os.replace`, atomic), and the folder fsynced (``durable``). If anything fails the
    temporary file is removed and the exception re-raised; ``path`` is then unchanged.
    Returns ``path``."""
    path = Path(path)
    folder = Path(staging) if staging is not None else path.parent
    folder.mkdir(parents=True, exist_ok=True)
    tmp = folder / f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:12]}.tmp"
    try:
        if isinstance(write, bytes):
            tmp.write_bytes(write)
        elif isinstance(write, str):
            tmp.write_text(write, encoding="utf-8")
        else:
            write(tmp)
        if durable:
            with open(tmp, "rb") as fh:
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            tmp.unlink()
        except OSError:
            pass
        raise
    if durable:
        fsync_dir(path.parent)
    return path


def read_json_object(path: str | os.PathLike) -> dict:
    """The JSON object in ``path``; ``{}`` when the file is missing, unreadable, damaged or holds
    anything but an object (an identity or state file a command only consults)."""
    try:
        saved = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return {}
    return saved if isinstance(saved, dict) else {}
