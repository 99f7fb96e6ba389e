"""The environment variables mcjax reads that need checking, parsed in one place and without
JAX (``MCJAX_CACHE_DIR``, a folder or ``off``, is read by :func:`mcjax.runtime.cache_dir`): the
CLI checks them all before JAX starts (one line, exit 2: :func:`check`), and :mod:`mcjax.runtime` and
:mod:`mcjax.tracking.filters.native` read them through the same functions, so a value means the same
thing everywhere and a bad one gets the same message.
"""

from __future__ import annotations

import math
import os

DEVICES_ENV = "MCJAX_CPU_DEVICES"
CACHE_ENV = "MCJAX_CACHE_DIR"
CACHE_MAX_ENV = "MCJAX_CACHE_MAX_GB"
NATIVE_ENV = "MCJAX_NATIVE"
#: The program store's size limit when ``MCJAX_CACHE_MAX_GB`` is not set, in gigabytes.
CACHE_MAX_GB = 2.0


def cpu_devices() -> int | None:
    """``$MCJAX_CPU_DEVICES``: the CPU devices to use, or None when unset (one per core)."""
    raw = os.environ.get(DEVICES_ENV)
    if raw is None:
        return None
    if not (raw.strip().isdigit() and int(raw) >= 1):
        raise ValueError(f"{DEVICES_ENV} must be a positive integer (CPU devices to use; unset = one per core); "
                         f"got {raw!r}")
    return int(raw)


def cache_max_bytes() -> int:
    """``$MCJAX_CACHE_MAX_GB`` in bytes: the program store's size limit (default
    :data:`CACHE_MAX_GB`)."""
    raw = os.environ.get(CACHE_MAX_ENV)
    if raw is None:
        return int(CACHE_MAX_GB * 1e9)
    try:
        gb = float(raw)
    except ValueError:
        gb = math.nan
    if not (math.isfinite(gb) and gb > 0):
        raise ValueError(f"{CACHE_MAX_ENV} must be a positive number of gigabytes (the stored programs' size "
                         f"limit; unset = {CACHE_MAX_GB:g}), e.g. 2 or 0.5; got {raw!r}")
    return int(gb * 1e9)


def native_on() -> bool:
    """``$MCJAX_NATIVE``: False for ``off``, True for ``on`` or unset (run_filter's native kernels)."""
    raw = os.environ.get(NATIVE_ENV)
    if raw is not None and raw.strip().lower() not in ("on", "off"):
        raise ValueError(f"{NATIVE_ENV} must be 'on' or 'off'; got {raw!r}")
    return raw is None or raw.strip().lower() == "on"


def check() -> None:
    """Every variable above parsed once: ValueError naming the first bad one."""
    cpu_devices()
    cache_max_bytes()
    native_on()
