"""Process-wide JAX settings, applied once when mcjax is imported (before JAX starts its backend).

* **Every CPU core.** XLA runs one compiled program on one CPU device mostly on one thread, so
  mcjax asks JAX for one CPU device per core and the engine sends consecutive batches of a
  chunk to the devices in turn (:func:`mcjax.engine.run_chunks`). Each device runs the same
  compiled batch program (compiled once, loaded on each device: :func:`deserialise`), so
  results are bit-identical to a one-device run.
  ``MCJAX_CPU_DEVICES=N`` sets the count (``1``: one device, the old behaviour).
* **A persistent compilation cache.** Compiled programs are kept on disk, so a second sweep of
  the same spec (or any run of the same Config) skips compilation. The folder is
  ``$MCJAX_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/mcjax/jax`` (default ``~/.cache/mcjax/jax``);
  ``MCJAX_CACHE_DIR=off`` turns it off. It is safe to delete at any time. For the built-in
  scenarios the engine stores its batch programs whole (:func:`load_executable`; one file,
  loaded on every device), keyed on mcjax's source code, the JAX version, the CPU, the
  scenario, its Config and the input shapes — a second sweep of the same spec loads them
  (~1 s, both devices in parallel) instead of compiling them (~18 s for Sun et al. 2011's
  closed loop). A user's own scenario (a file or a plugin) is
  compiled every time: its code is not in the key. (JAX's own persistent cache is not used:
  loading from it failed in some runs, see :func:`_apply`.) The stored programs are kept under
  ``$MCJAX_CACHE_MAX_GB`` gigabytes (default 2; a program of the closed loop is ~8 MB): past
  it, the least recently used ones are deleted when a new one is stored.

If JAX's backend is already running when mcjax is first imported (a program that computed with
JAX before importing mcjax), the device count cannot change any more: mcjax then uses the
devices JAX has, and says nothing. Call :func:`settings` to see what applies.
"""

from __future__ import annotations

import hashlib
import io
import os
import pickle
import platform
import re
import threading
import warnings
from functools import lru_cache
from pathlib import Path

import jax
import numpy as np

from mcjax import envvars

OFF = ("off", "none", "0", "")


def _device_count() -> int:
    return envvars.cpu_devices() or max(1, os.cpu_count() or 1)


def cache_dir() -> Path | None:
    """The persistent compilation cache's folder, or None when turned off."""
    raw = os.environ.get(envvars.CACHE_ENV)
    if raw is not None:
        return None if raw.strip().lower() in OFF else Path(raw).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "mcjax" / "jax"


def _prune(folder: Path, limit: int, keep: Path) -> None:
    """Delete the least recently used programs (oldest modification time: loading one touches
    it) until the folder's ``*.pkl`` files total at most ``limit`` bytes; never ``keep``."""
    files = []
    for f in folder.glob("*.pkl"):
        try:
            st = f.stat()
        except OSError:  # deleted meanwhile by another process
            continue
        files.append((st.st_mtime, st.st_size, f))
    total = sum(size for _, size, _ in files)
    for _, size, f in sorted(files, key=lambda item: item[0]):
        if total <= limit:
            break
        if f == keep:
            continue
        try:
            f.unlink()
            total -= size
        except OSError:
            pass


def _apply() -> None:
    try:
        jax.config.update("jax_num_cpu_devices", _device_count())
    except RuntimeError:
        pass  # the backend already runs: keep its devices
    # JAX's own persistent compilation cache is not switched on: with it, runs that loaded a
    # cached program failed with "NOT_FOUND: Function convert_convert_fusion not found" (2 of 3
    # runs of the default sweep, jax 0.10.2, CPU). Only the engine's program store is used.


def settings() -> dict:
    """What applies in this process: CPU devices in use and the cache folder (or None)."""
    return {"cpu_devices": len(jax.devices("cpu")), "cache_dir": cache_dir()}


@lru_cache(maxsize=1)
def _code_version() -> str:
    """A hash of mcjax's source files, JAX's version, the CPU and ``XLA_FLAGS`` (the compiler's
    options: the test suite compiles with cheaper ones): what a stored program depends on
    besides its own key."""
    h = hashlib.sha256()
    root = Path(__file__).resolve().parent
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            cpu += next((line for line in f if line.startswith(("model name", "flags"))), "")
    except OSError:
        pass
    h.update(f"{jax.__version__}|{cpu}|{os.environ.get('XLA_FLAGS', '')}".encode())
    return h.hexdigest()


def _executable_path(key: str) -> Path | None:
    folder = cache_dir()
    if folder is None:
        return None
    digest = hashlib.sha256(f"{_code_version()}|{key}".encode()).hexdigest()[:40]
    return folder / "mcjax-programs" / f"{digest}.pkl"


#: Programs loaded from and stored to the disk cache in this process.
STATS = {"loaded": 0, "stored": 0}
_TARGET = re.compile(r"custom_call @([A-Za-z0-9_.]+)")


def custom_call_targets(lowered) -> frozenset:
    """The custom-call targets (library kernels, e.g. LAPACK's) a lowered program calls."""
    return frozenset(_TARGET.findall(lowered.as_text()))


#: Guards :func:`_ready_targets` and :data:`STATS` against the engine's loading threads.
_LOCK = threading.Lock()


def prepare_loading() -> None:
    """Do now what :func:`load_executable` must do once per process before a stored program
    runs (set up LAPACK, ~0.1 s): the engine calls it while its threads deserialise."""
    _ready_targets()


def _ready_targets() -> frozenset:
    """:func:`_lapack_targets`, computed once per process even when several threads ask."""
    with _LOCK:
        return _lapack_targets()


@lru_cache(maxsize=1)
def _lapack_targets() -> frozenset:
    """Set up JAX's LAPACK kernels in this process and return their custom-call targets: the
    library kernels a stored program may call without being lowered again. (JAX registers the
    targets when it is imported but binds LAPACK's functions only when it first lowers a call
    to one, ``jaxlib.lapack.prepare_lapack_call``; a program loaded from disk is not lowered,
    so it is done here. That is a call into jaxlib's internals: if it is missing, a small
    program of the dense linear algebra mcjax uses is lowered instead, which does the same in
    ~0.5 s.)"""
    try:
        from jaxlib import lapack

        lapack._lapack.initialize()
        return frozenset(name for name, *_ in lapack.registrations()["cpu"])
    except Exception:  # noqa: BLE001 — another jaxlib: fall back on lowering
        return _lowered_targets()


@lru_cache(maxsize=1)
def _lowered_targets() -> frozenset:
    """Lower (not compile) a small program of the dense linear algebra mcjax uses, in float32
    and float64, and return the custom-call targets it calls. Lowering is what makes JAX set
    up those kernels in a process (LAPACK's are bound at their first lowering); a stored
    program that calls only these can run without being lowered again."""
    import jax.numpy as jnp
    from jax.scipy.linalg import solve_triangular

    def zoo(a, b):
        return [(jnp.linalg.eigvalsh(x), jnp.linalg.cholesky(x), jnp.linalg.solve(x, x),
                 solve_triangular(x, x, lower=True)) for x in (a, b)]

    return custom_call_targets(jax.jit(zoo).lower(jnp.eye(2, dtype=jnp.float32), jnp.eye(2, dtype=jnp.float64)))


def serialise(compiled) -> tuple | None:
    """A compiled one-device program as ``(bytes, in_tree, out_tree)`` for :func:`deserialise`
    (JAX's ``serialize_executable``), or None if JAX cannot serialise it."""
    from jax.experimental import serialize_executable

    try:
        return serialize_executable.serialize(compiled)
    except Exception:  # noqa: BLE001 — e.g. a program JAX does not serialise
        return None


def deserialise(data: tuple, device):
    """The program :func:`serialise` gave, loaded to run on ``device`` — whichever device it
    was compiled for: XLA's machine code does not depend on the device, only the program's
    device assignment does, and that is replaced here (one device, one replica). So a
    program is compiled once and loaded on every CPU device (~1 s each) instead of being
    compiled once per device. Raises if this JAX cannot do it (the caller then compiles).

    This goes beyond JAX's public ``deserialize_and_load`` (which keeps the device the
    program was compiled for): its unpickler is given the target device for every device it
    names, and the executable is deserialised with compile options assigning it there. A JAX
    without those internals gets the public function (the device it was compiled for only)."""
    from jax.experimental import serialize_executable

    blob, in_tree, out_tree = data
    try:
        from jax._src import compiler

        unpickler, compile_options = serialize_executable._JaxPjrtUnpickler, compiler.get_compile_options
    except (ImportError, AttributeError):
        return serialize_executable.deserialize_and_load(blob, in_tree, out_tree, execution_devices=[device])

    class OnDevice(unpickler):
        def persistent_load(self, pid):
            if pid[0] == "device":
                return device
            if pid[0] == "exec":
                options = compile_options(1, 1, device_assignment=np.array([[device]]), backend=self.backend)
                return self.backend.deserialize_executable(pid[1], executable_devices=self.execution_devices,
                                                           compile_options=options)
            return super().persistent_load(pid)

    unloaded, args_info, no_kwargs = OnDevice(io.BytesIO(blob), device.client, [device]).load()
    return jax.stages.Compiled(unloaded.load(), [], in_tree.unflatten(args_info), out_tree, no_kwargs=no_kwargs)


def load_executable(key: str, device):
    """The program stored under ``key`` (:func:`store_executable`), loaded on ``device``, or
    None when there is none, the cache is off, the file cannot be loaded, or the program calls
    a library kernel this process has not set up (then the caller compiles it again)."""
    path = _executable_path(key)
    if path is None or not path.is_file():
        return None
    try:
        blob, in_tree, out_tree, targets = pickle.loads(path.read_bytes())
        program = deserialise((blob, in_tree, out_tree), device)
        if not set(targets) <= _ready_targets():
            return None
        with _LOCK:
            STATS["loaded"] += 1
        try:
            os.utime(path)  # recently used: the last to be pruned
        except OSError:
            pass
        return program
    except Exception:  # a damaged or foreign file: compile again and overwrite it
        return None


def store_executable(key: str, data: tuple | None, targets: frozenset) -> None:
    """Store a compiled one-device program, as :func:`serialise` gave it, for
    :func:`load_executable` (on any device), with the custom-call ``targets`` its lowering
    calls (atomically; failures are ignored: the cache is an optimisation)."""
    path = _executable_path(key)
    if path is None:
        return
    limit = envvars.cache_max_bytes()  # a bad MCJAX_CACHE_MAX_GB is the user's to see, not swallowed below
    if data is None:
        return
    try:
        blob = pickle.dumps((*data, tuple(sorted(targets))))
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_bytes(blob)
        os.replace(tmp, path)
        STATS["stored"] += 1
        _prune(path.parent, limit, keep=path)
    except Exception:
        pass


def known_compiler_options(options) -> dict | None:
    """The XLA options of ``options`` (a mapping, or None) that this JAX knows, for
    ``jax.jit(..., compiler_options=…)``; an unknown one is dropped, with a RuntimeWarning naming
    it once per process (the program is then compiled with XLA's default for it), rather than
    failing every compilation."""
    return _known_options(tuple(sorted((options or {}).items())))


@lru_cache(maxsize=None)
def _known_options(items: tuple) -> dict | None:
    known = {}
    for name, value in items:
        try:  # a one-line program, compiled once per option and process
            jax.jit(lambda x: x + 1, compiler_options={name: value}).lower(0.0).compile()
        except Exception:  # noqa: BLE001 — jaxlib's error for an unknown option ("No such compile option")
            warnings.warn(f"this JAX ({jax.__version__}) does not know the XLA compiler option {name}={value!r}: "
                          "programs are compiled without it", RuntimeWarning, stacklevel=2)
            continue
        known[name] = value
    return known or None


_apply()
