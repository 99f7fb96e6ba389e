"""Process-wide JAX settings, applied once when mcjax is imported (before JAX starts its backend).

* **Every CPU core.** XLA runs one compiled program on one CPU device mostly on one thread, so
  mcjax asks JAX for one CPU device per core and the engine sends consecutive batches of a
  chunk to the devices in turn (:func:`mcjax.engine.run_chunks`). Each device runs the same
  compiled batch program, so results are bit-identical to a one-device run.
  ``MCJAX_CPU_DEVICES=N`` sets the count (``1``: one device, the old behaviour).
* **A persistent compilation cache.** Compiled programs are kept on disk, so a second sweep of
  the same spec (or any run of the same Config) skips compilation. The folder is
  ``$MCJAX_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/mcjax/jax`` (default ``~/.cache/mcjax/jax``);
  ``MCJAX_CACHE_DIR=off`` turns it off. It is safe to delete at any time.

If JAX's backend is already running when mcjax is first imported (a program that computed with
JAX before importing mcjax), the device count cannot change any more: mcjax then uses the
devices JAX has, and says nothing. Call :func:`settings` to see what applies.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax

#: Environment variables read here.
DEVICES_ENV = "MCJAX_CPU_DEVICES"
CACHE_ENV = "MCJAX_CACHE_DIR"
OFF = ("off", "none", "0", "")


def _device_count() -> int:
    raw = os.environ.get(DEVICES_ENV)
    if raw is None:
        return max(1, os.cpu_count() or 1)
    try:
        n = int(raw)
    except ValueError:
        raise ValueError(f"{DEVICES_ENV} must be a positive integer; got {raw!r}") from None
    if n < 1:
        raise ValueError(f"{DEVICES_ENV} must be a positive integer; got {raw!r}")
    return n


def cache_dir() -> Path | None:
    """The persistent compilation cache's folder, or None when turned off."""
    raw = os.environ.get(CACHE_ENV)
    if raw is not None:
        return None if raw.strip().lower() in OFF else Path(raw).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "mcjax" / "jax"


def _apply() -> None:
    try:
        jax.config.update("jax_num_cpu_devices", _device_count())
    except RuntimeError:
        pass  # the backend already runs: keep its devices
    folder = cache_dir()
    if folder is not None:
        jax.config.update("jax_compilation_cache_dir", str(folder))
        # cache every program that took a second or more to compile (JAX's default threshold)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


def settings() -> dict:
    """What applies in this process: CPU devices in use and the cache folder (or None)."""
    return {"cpu_devices": len(jax.devices("cpu")), "cache_dir": cache_dir()}


_apply()
