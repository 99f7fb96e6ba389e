"""Native CPU kernels of the local EKF and the modified ICF for :func:`mcjax.tracking.filters.run_filter`,
through XLA's FFI (``native_kernels.cc``, the equations of :mod:`mcjax.tracking.filters.batched`).

XLA runs the structure-of-arrays kernels of :mod:`.batched` as dozens of elementwise loops per
step, each reading the state again, on one thread; a compiled loop keeps 8 lanes' state (8
(run, agent) pairs or 8 runs) in vector registers and uses every core (docs/filter_speed.md).
So when the machine has a C++ compiler, the first call builds ``native_kernels.cc`` into a
shared library (``c++ -O3 -march=native -fno-math-errno``, with glibc's vector math library
where it links; a few seconds), keeps it in mcjax's cache folder (keyed on the source, the
compiler and the CPU; safe to delete; loaded only when the file is yours alone and unaltered
since it was built: :func:`load_library`), and registers its two handlers with XLA; the same
library checks ``run_filter``'s adjacency (:func:`adjacency_bytes`). Without a compiler, or
with ``MCJAX_NATIVE=off``, :func:`available` is False and ``run_filter`` uses the pure-JAX
kernels and numpy checks; the kernels are also the ones for float32 and for gradients. Both
give the same numbers to round-off (tests/tracking/filters/test_filters.py checks 1e-8).
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
from functools import lru_cache
from pathlib import Path

import jax
import numpy as np

from mcjax import runtime

from mcjax.base import envvars
SOURCE = Path(__file__).with_name("native_kernels.cc")
TARGETS = {"local": ("mcjax_local_ekf", "McjaxLocalEkf"), "modified_icf": ("mcjax_modified_icf", "McjaxModifiedIcf")}
WEIGHT_CODES = {"eq11": 0, "metropolis": 1, "max_degree": 2}
#: The modified ICF's kernel keeps a run's graph on the stack: at most this many agents
#: (``kMaxAgents`` in the C++); larger teams run in the pure-JAX kernel.
MAX_AGENTS = 64
#: Why the native kernels are not in use in this process ("" when they are).
STATUS = {"reason": "not tried yet"}
_LIB: list = []  # the loaded library, once :func:`available` has succeeded


def _compiler() -> str | None:
    return next((c for c in (os.environ.get("CXX"), "c++", "g++", "clang++") if c and shutil.which(c)), None)


def _library_stem(cxx: str) -> tuple[Path, str]:
    """The cache folder of the built library and its name's prefix (keyed on the source, the
    compiler, the CPU and JAX); the file is ``<prefix>-<sha256 of its content>.so``."""
    version = subprocess.run([cxx, "--version"], capture_output=True, text=True, timeout=30).stdout
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            cpu += "".join(line for line in f if line.startswith(("model name", "flags")))[:4000]
    except OSError:
        pass
    key = hashlib.sha256(SOURCE.read_bytes() + version.encode() + cpu.encode() + jax.__version__.encode())
    folder = runtime.cache_dir()
    folder = (folder / "mcjax-native") if folder is not None else Path(tempfile.gettempdir()) / f"mcjax-native-{os.getuid()}"
    return folder, f"filters-{key.hexdigest()[:24]}"


def _build(cxx: str, folder: Path, prefix: str) -> Path:
    """Compile, with glibc's vector math library (libmvec: a vectorised atan2) where it links,
    else without it, into ``folder`` (made 0700), the file 0600 and named after its content's
    SHA-256 (:func:`mcjax.runtime.content_name`), written atomically: a concurrent process sees
    the whole library or none. Returns its path."""
    runtime.private_folder(folder)
    with tempfile.TemporaryDirectory(dir=folder, prefix=".build-") as work:
        out = Path(work) / "lib.so"
        cmd = [cxx, "-O3", "-march=native", "-fno-math-errno", "-std=c++17", "-shared", "-fPIC", "-pthread",
               f"-I{jax.ffi.include_dir()}", str(SOURCE), "-o", str(out)]
        for extra in (["-DMCJAX_LIBMVEC", "-lmvec"], []):
            done = subprocess.run(cmd + extra, capture_output=True, text=True, timeout=300)
            if done.returncode == 0:
                break
        else:
            raise RuntimeError(f"{' '.join(cmd)} failed: {done.stderr.strip()[-500:]}")
        data = out.read_bytes()
    return runtime.write_private(folder / runtime.content_name(prefix, data, ".so"), data)


def load_library(folder: Path, prefix: str):
    """The built library of ``prefix`` in ``folder``, loaded, or None when there is none that
    passes :func:`mcjax.runtime.trusted_read` (a shared library runs code when it is loaded: one
    yours alone, unaltered since it was built); a file that fails is named in one warning line
    and not loaded. The library is loaded by its content-hashed name once its bytes are checked again."""
    for path in sorted(folder.glob(f"{prefix}-*.so")):
        data, why = runtime.trusted_read(path)
        if data is None:
            runtime.distrust(path, why, "native kernels' library")
            continue
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
        try:
            if hashlib.sha256(os.pread(fd, len(data) + 1, 0)).digest() != hashlib.sha256(data).digest():
                continue  # replaced since it was checked
            # by its own, content-hashed name in the checked private folder: the dynamic loader keeps a
            # library per name, so a reused /proc/self/fd/N name could hand back another library
            return ctypes.cdll.LoadLibrary(str(path))
        finally:
            os.close(fd)
    return None


@lru_cache(maxsize=1)
def available() -> bool:
    """Build (once per machine), load and register the native kernels; False (with the reason in
    :data:`STATUS`) if ``MCJAX_NATIVE=off``, there is no C++ compiler, or the build fails.
    Another value of ``MCJAX_NATIVE`` raises ValueError naming it."""
    if not envvars.native_on():  # ``off``: never build or use them in this process
        STATUS["reason"] = f"{envvars.NATIVE_ENV}=off"
        return False
    cxx = _compiler()
    if cxx is None:
        STATUS["reason"] = "no C++ compiler (c++, g++, clang++ or $CXX) on PATH"
        return False
    try:
        folder, prefix = _library_stem(cxx)
        lib = load_library(folder, prefix)
        if lib is None:
            lib = load_library(_build(cxx, folder, prefix).parent, prefix)
        if lib is None:
            raise RuntimeError(f"the library just built in {folder} does not load")
        for name, symbol in TARGETS.values():
            jax.ffi.register_ffi_target(name, jax.ffi.pycapsule(getattr(lib, symbol)), platform="cpu")
        lib.mcjax_adjacency_bytes.restype = ctypes.c_int
        lib.mcjax_adjacency_bytes.argtypes = [ctypes.c_void_p, ctypes.c_int64, ctypes.c_int64, ctypes.c_void_p,
                                              ctypes.c_int64]
        _LIB[:] = [lib]
    except Exception as exc:  # noqa: BLE001 — any failure means: use the pure-JAX kernels
        STATUS["reason"] = f"build or load failed: {exc}"
        return False
    STATUS["reason"] = ""
    return True


def _threads() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))


def adjacency_bytes(a: np.ndarray) -> tuple[np.ndarray, int]:
    """The 0/1 bytes of a float64 adjacency (…, n, n) (1 where it is 1) and a bit set of what
    is wrong with it (1: an entry other than 0 or 1, NaN included; 2: not symmetric; 4: a nonzero
    diagonal — these two judged on the bytes; 0: valid): run_filter's checks in one pass over
    the CPU's threads instead of numpy's five.
    Call only when :func:`available`."""
    a = np.ascontiguousarray(a, np.float64)
    n = a.shape[-1]
    out = np.empty(a.shape, np.uint8)
    mats = a.size // (n * n) if n else 0
    bad = _LIB[0].mcjax_adjacency_bytes(a.ctypes.data, mats, n, out.ctypes.data, _threads()) if mats else 0
    return out, int(bad)


def run_batch(kind, opts, z, s, a, x0, P0, F, Q, R):
    """``kind`` over B recorded runs in the native kernels: ``"local"``, the EKF in moment form
    (docs/equations.md §5.1), or ``"modified_icf"``, Sun et al. 2011 eqs. 8–12 with ``opts``'
    consensus steps, weights and contribution rule. ``z``, ``s`` float64 (B, T, n, 2), ``a`` the
    0/1 adjacency (B, T, n, n) (read as bytes; not read by ``"local"``). Returns C-ordered numpy
    estimates (B, T, n, 4) and covariances (B, T, n, 4, 4). Call only when :func:`available`."""
    B, T, n = z.shape[:3]
    threads = _threads()
    out = (jax.ShapeDtypeStruct((B, T, n, 4), np.float64), jax.ShapeDtypeStruct((B, T, n, 4, 4), np.float64))
    consts = [np.asarray(v, np.float64) for v in (x0, P0, F, Q, R)]
    call = jax.ffi.ffi_call(TARGETS[kind][0], out)
    if kind == "local":
        xs, Ps = call(z, s, *consts, threads=np.int64(threads))
    else:
        xs, Ps = call(z, s, np.asarray(a, np.uint8), *consts, threads=np.int64(threads),
                      steps=np.int64(opts.consensus_steps), weights=np.int64(WEIGHT_CODES[opts.weights]),
                      component=opts.contribution != "one")
    return np.asarray(xs), np.asarray(Ps)
