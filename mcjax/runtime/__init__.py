"""Process-wide JAX settings and the engine's program store.

Nothing here happens at import: :func:`configure` (``mcjax.configure()``) applies the settings,
once per process; the CLI and the engine's entry points call it.

* **64-bit mode.** JAX's ``jax_enable_x64``: computations run in the dtype of their input,
  float64 by default, float32 where a Config or caller asks for it (docs/architecture.md,
  "Precision"). A library function called without it says so once
  (:func:`mcjax.tracking.numerics.require_x64`) rather than computing silently in float32.
* **Every CPU core.** XLA runs one compiled program on one CPU device mostly on one thread, so
  mcjax asks JAX for one CPU device per core and the engine sends consecutive batches of a
  chunk to the devices in turn (:func:`mcjax.engine.run_chunks`). Each device runs the same
  compiled batch program (compiled once, loaded on each device:
  :func:`mcjax.runtime.jaxcompat.deserialise`), so results are bit-identical to a one-device run.
  ``MCJAX_CPU_DEVICES=N`` sets the count (``1``: one device, the old behaviour). If JAX's
  backend already runs when :func:`configure` is first called (a program that computed with
  JAX before), the count cannot change any more: mcjax then uses the devices JAX has, and
  says nothing. :func:`settings` tells what applies.
* **A program store.** The engine stores its compiled batch programs whole (:func:`load_executable`;
  one file, loaded on every device), keyed on mcjax's source code, the JAX version, the CPU,
  ``XLA_FLAGS``, the scenario (a user's file or plugin scenario: its source files' content),
  its Config and the input shapes — a second sweep of the same spec loads them (~1 s, both
  devices in parallel) instead of compiling them (~18 s for Sun et al. 2011's closed loop). The
  folder is ``$MCJAX_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/mcjax/jax`` (default
  ``~/.cache/mcjax/jax``); ``MCJAX_CACHE_DIR=off`` turns it off; it is safe to delete at any
  time. The stored programs are kept under ``$MCJAX_CACHE_MAX_GB`` gigabytes (default 2; a
  program of the closed loop is ~8 MB): past it, the least recently used ones are deleted when
  a new one is stored. The folder is made readable by you alone (0700, files 0600), and a
  stored program is loaded only when its file is yours, writable by no one else, and its
  content hashes to the SHA-256 its name carries (written with it): anything else — a file
  another user put there, a group-writable one, an altered one — is not unpickled (unpickling
  runs code), one warning line names it and the program is compiled afresh
  (:func:`trusted_read`). (JAX's own persistent compilation cache is not used: it traces and
  lowers a program before it can look it up, so a warm sweep started in 7-10 s against the
  store's 3-4 s, and with two devices every warm sweep failed, "NOT_FOUND: Function … not
  found", jax 0.10.2: docs/benchmarks.md, 2026-12-02.)
"""

from __future__ import annotations

import hashlib
import io
import os
import pickle
import platform
import stat
import sys
import threading
import warnings
from functools import lru_cache
from pathlib import Path

import jax

from mcjax.base import envvars
from mcjax.base.files import atomic_write
from mcjax.runtime import jaxcompat

OFF = ("off", "none", "0", "")
#: Guards :func:`configure`, :func:`prepare_loading` and :data:`STATS` (the engine's loading threads).
_LOCK = threading.Lock()


def _device_count() -> int:
    return envvars.cpu_devices() or max(1, os.cpu_count() or 1)


def cache_dir() -> Path | None:
    """The program store's folder (``$MCJAX_CACHE_DIR``), or None when turned off."""
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


_CONFIGURED = False


def configure() -> None:
    """Switch JAX's 64-bit mode on and ask for one CPU device per core (``MCJAX_CPU_DEVICES``;
    kept as they are when JAX's backend already runs). Once per process: later calls do
    nothing. ``mcjax.configure()`` is this function."""
    global _CONFIGURED
    if _CONFIGURED:
        return
    with _LOCK:
        if _CONFIGURED:
            return
        try:
            jax.config.update("jax_num_cpu_devices", _device_count())
        except RuntimeError:
            pass  # the backend already runs: keep its devices
        jax.config.update("jax_enable_x64", True)
        _CONFIGURED = True


def settings() -> dict:
    """What applies in this process (after :func:`configure`): CPU devices in use, the program
    store's folder (or None) and 64-bit mode."""
    configure()
    return {"x64": bool(jax.config.jax_enable_x64), "cpu_devices": len(jax.devices("cpu")), "cache_dir": cache_dir()}


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


def _executable_stem(key: str) -> tuple[Path, str] | None:
    """The store's folder and the name prefix of the program stored under ``key`` (its file is
    ``<prefix>-<sha256 of its content>.pkl``), or None when the store is off."""
    folder = cache_dir()
    if folder is None:
        return None
    return folder / "mcjax-programs", hashlib.sha256(f"{_code_version()}|{key}".encode()).hexdigest()[:40]


def private_folder(folder: Path) -> Path:
    """``folder``, created readable by its owner alone (0700); an existing one of yours that
    others may read or write is made so. Returns ``folder``."""
    folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    st = folder.stat()
    if st.st_uid == os.getuid() and stat.S_IMODE(st.st_mode) & 0o077:
        os.chmod(folder, 0o700)
    return folder


def write_private(path: Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (:func:`mcjax.base.files.atomic_write`), the file readable
    and writable by its owner alone (0600)."""
    def write(tmp: Path) -> None:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o600)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)

    return atomic_write(path, write, durable=False)  # a cache: a lost file is built again


def content_name(stem: str, data: bytes, suffix: str) -> str:
    """The file name that records ``data``'s SHA-256: ``<stem>-<hex digest><suffix>``."""
    return f"{stem}-{hashlib.sha256(data).hexdigest()}{suffix}"


def trusted_read(path: Path) -> tuple[bytes | None, str]:
    """The bytes of a cached file that is safe to load as code (a pickled program, a shared
    library), or ``(None, why)``: the file must be a regular file (not a symbolic link), owned
    by this user, not writable by group or others, in a folder owned by this user (or root) that
    group and others cannot write, and its content must hash to the SHA-256 at the end of its
    name (:func:`content_name`, recorded when it was written). The checks and the hash are of
    the open file itself (no one can swap it in between)."""
    try:
        folder = path.parent.stat()
        if folder.st_uid not in (os.getuid(), 0) or stat.S_IMODE(folder.st_mode) & 0o022:
            return None, f"is in a folder {path.parent} that may be written by another user"
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    except OSError as exc:
        return None, f"cannot be opened ({exc.strerror or exc})"
    with os.fdopen(fd, "rb") as fh:
        st = os.fstat(fh.fileno())
        if not stat.S_ISREG(st.st_mode):
            return None, "is not a regular file"
        if st.st_uid != os.getuid():
            return None, f"belongs to another user (uid {st.st_uid})"
        if stat.S_IMODE(st.st_mode) & 0o022:
            return None, f"may be written by group or others (mode {stat.S_IMODE(st.st_mode):o})"
        data = fh.read()
    digest = path.name.rsplit(".", 1)[0].rpartition("-")[2]
    if len(digest) != 64 or hashlib.sha256(data).hexdigest() != digest:
        return None, "does not match the hash recorded when it was written"
    return data, ""


_WARNED: set = set()


def distrust(path: Path, why: str, what: str = "stored program") -> None:
    """One warning line on standard error naming a cached file that is not loaded, and why
    (once per file and process)."""
    with _LOCK:
        if str(path) in _WARNED:
            return
        _WARNED.add(str(path))
    try:
        sys.stderr.write(f"warning: not loading the {what} {path}: it {why}; building it afresh\n")
        sys.stderr.flush()
    except (OSError, ValueError):
        pass


#: Programs loaded from and stored to the disk cache in this process.
STATS = {"loaded": 0, "stored": 0}


def prepare_loading() -> frozenset:
    """Do now what :func:`load_executable` must do once per process before a stored program
    runs (set up LAPACK, ~0.1 s: :func:`mcjax.runtime.jaxcompat.lapack_targets`), even when several
    threads ask; returns the library kernels set up. The engine calls it while its threads
    deserialise."""
    with _LOCK:
        return jaxcompat.lapack_targets()


class _Pickler(pickle.Pickler):
    """Pickles the classes of module ``local`` (a user's scenario file, imported under a name
    of its own in each process) by their name in it, not by the module's name."""

    def __init__(self, file, local):
        super().__init__(file)
        self.local = local

    def persistent_id(self, obj):
        if self.local is not None and isinstance(obj, type) and obj.__module__ == self.local.__name__:
            return ("local", obj.__qualname__)
        return None


class _Unpickler(pickle.Unpickler):
    def __init__(self, file, local):
        super().__init__(file)
        self.local = local

    def persistent_load(self, pid):
        if pid[0] != "local" or self.local is None:
            raise pickle.UnpicklingError(f"no module to find {pid!r} in")
        obj = self.local
        for part in pid[1].split("."):
            obj = getattr(obj, part)
        return obj


def load_executable(key: str, device, local=None):
    """The program stored under ``key`` (:func:`store_executable`), loaded on ``device``, or
    None when there is none, the cache is off, the file cannot be loaded, or the program calls
    a library kernel this process has not set up (then the caller compiles it again). A file
    that fails :func:`trusted_read` is not unpickled: one warning line names it.
    ``local``: the module the program's Params and outputs classes were stored from
    (:func:`store_executable`)."""
    stem = _executable_stem(key)
    if stem is None:
        return None
    folder, prefix = stem
    for path in sorted(folder.glob(f"{prefix}-*.pkl")):
        data, why = trusted_read(path)
        if data is None:
            distrust(path, why)
            continue
        try:
            blob, in_tree, out_tree, targets = _Unpickler(io.BytesIO(data), local).load()
            program = jaxcompat.deserialise((blob, in_tree, out_tree), device)
            if not set(targets) <= prepare_loading():
                return None
            with _LOCK:
                STATS["loaded"] += 1
            try:
                os.utime(path)  # recently used: the last to be pruned
            except OSError:
                pass
            return program
        except Exception:  # a file of another version of this program: compile again and overwrite it
            return None
    return None


def store_executable(key: str, data: tuple | None, targets: frozenset, local=None) -> None:
    """Store a compiled one-device program, as :func:`mcjax.runtime.jaxcompat.serialise` gave it, for
    :func:`load_executable` (on any device), with the custom-call ``targets`` its lowering
    calls (atomically; failures are ignored: the cache is an optimisation). The classes of
    module ``local`` in its input and output trees (a scenario file's Params, State …) are
    stored by their name in that module, which the loading process passes again."""
    stem = _executable_stem(key)
    if stem is None:
        return
    limit = envvars.cache_max_bytes()  # a bad MCJAX_CACHE_MAX_GB is the user's to see, not swallowed below
    if data is None:
        return
    try:
        buffer = io.BytesIO()
        _Pickler(buffer, local).dump((*data, tuple(sorted(targets))))
        folder, prefix = stem
        blob = buffer.getvalue()
        path = write_private(private_folder(folder) / content_name(prefix, blob, ".pkl"), blob)
        STATS["stored"] += 1
        for other in folder.glob(f"{prefix}-*.pkl"):  # an older or untrusted copy of the same program
            if other != path:
                other.unlink(missing_ok=True)
        _prune(folder, limit, keep=path)
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
