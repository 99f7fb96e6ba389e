"""Every use mcjax makes of JAX's internals, in one place, each with a fallback on public API.

mcjax loads one compiled program on every CPU device and from its program store
(:mod:`mcjax.runtime`, :mod:`mcjax.engine`). JAX's public API cannot quite do that, so this
module reaches into JAX's internals — and nothing else in mcjax does (``tests/engine/test_compilation.py``
walks the package and fails on any other module that imports ``jax._src``, a private name of
``jaxlib``, a private attribute of a JAX module, or calls the ``jax.stages.Compiled``
constructor). The internals used:

=======================  ===========================================  ===================================
function                 internals                                    fallback (when one is missing)
=======================  ===========================================  ===================================
:func:`deserialise`      ``serialize_executable._JaxPjrtUnpickler``,  JAX's public ``deserialize_and_load``:
                         ``jax._src.compiler.get_compile_options``,   the program runs only on the device
                         the client's ``deserialize_executable``,     it was compiled for, so the engine
                         the ``jax.stages.Compiled`` constructor      compiles once per other device
                                                                      (~18 s each for the closed loop)
:func:`lapack_targets`   ``jaxlib.lapack._lapack.initialize``,        lower a small program of the dense
                         ``jaxlib.lapack.registrations``              linear algebra mcjax uses (~0.5 s
                                                                      once per process)
=======================  ===========================================  ===================================

JAX is pinned to the range these were tested with (``pyproject.toml``); :func:`missing` names
the internals the installed JAX lacks (each then costs what its fallback costs, and the
results stay the same bits). Every fallback is run by ``tests/engine/test_compilation.py``.
"""

from __future__ import annotations

import io
import re
from functools import lru_cache

import jax
import numpy as np

_TARGET = re.compile(r"custom_call @([A-Za-z0-9_.]+)")
#: What a missing or changed internal raises.
_MISSING = (ImportError, AttributeError, TypeError)


def custom_call_targets(lowered) -> frozenset:
    """The custom-call targets (library kernels, e.g. LAPACK's) a lowered program calls."""
    return frozenset(_TARGET.findall(lowered.as_text()))


def serialise(compiled) -> tuple | None:
    """A compiled one-device program as ``(bytes, in_tree, out_tree)`` for :func:`deserialise`
    (JAX's public ``serialize_executable.serialize``), or None if JAX cannot serialise it."""
    from jax.experimental import serialize_executable

    try:
        return serialize_executable.serialize(compiled)
    except Exception:  # noqa: BLE001 — e.g. a program JAX does not serialise
        return None


def deserialise(data: tuple, device):
    """The program :func:`serialise` gave, loaded to run on ``device`` — whichever device it
    was compiled for: XLA's machine code does not depend on the device, only the program's
    device assignment does, and that is replaced here (one device, one replica). So a program
    is compiled once and loaded on every CPU device (~1 s each) instead of being compiled once
    per device. Raises if this JAX cannot do it (the caller then compiles).

    This goes beyond JAX's public ``deserialize_and_load`` (which keeps the device the program
    was compiled for): JAX's unpickler is given the target device for every device it names,
    and the executable is deserialised with compile options assigning it there. A JAX without
    those internals gets the public function (the device it was compiled for only)."""
    try:
        return _deserialise_on(data, device)
    except _MISSING:
        from jax.experimental import serialize_executable

        return serialize_executable.deserialize_and_load(*data, execution_devices=[device])


def _deserialise_on(data: tuple, device):
    from jax._src import compiler
    from jax.experimental import serialize_executable

    blob, in_tree, out_tree = data
    unpickler, compile_options = serialize_executable._JaxPjrtUnpickler, compiler.get_compile_options

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


@lru_cache(maxsize=1)
def lapack_targets() -> frozenset:
    """Set up JAX's LAPACK kernels in this process and return their custom-call targets: the
    library kernels a stored program may call without being lowered again. (JAX registers the
    targets when it is imported but binds LAPACK's functions only when it first lowers a call
    to one; a program loaded from disk is not lowered, so it is done here, through jaxlib's
    internals. Without them, a small program of the dense linear algebra mcjax uses is lowered
    instead, which does the same in ~0.5 s: :func:`lowered_targets`.) Not thread-safe the
    first time: :func:`mcjax.runtime.prepare_loading` calls it under a lock."""
    try:
        from jaxlib import lapack

        lapack._lapack.initialize()
        return frozenset(name for name, *_ in lapack.registrations()["cpu"])
    except Exception:  # noqa: BLE001 — another jaxlib: fall back on lowering
        return lowered_targets()


@lru_cache(maxsize=1)
def lowered_targets() -> frozenset:
    """Lower (not compile) a small program of the dense linear algebra mcjax uses, in float32
    and float64, and return the custom-call targets it calls. Lowering is what makes JAX set
    up those kernels in a process (LAPACK's are bound at their first lowering); a stored
    program that calls only these can run without being lowered again. Public API only
    (float64 needs 64-bit mode: :func:`mcjax.configure`, which the engine calls first)."""
    import jax.numpy as jnp
    from jax.scipy.linalg import solve_triangular

    def zoo(a, b):
        return [(jnp.linalg.eigvalsh(x), jnp.linalg.cholesky(x), jnp.linalg.solve(x, x),
                 solve_triangular(x, x, lower=True)) for x in (a, b)]

    return custom_call_targets(jax.jit(zoo).lower(jnp.eye(2, dtype=jnp.float32), jnp.eye(2, dtype=jnp.float64)))


def missing() -> list[str]:
    """The internals this JAX lacks (their fallbacks are in use); empty on the tested JAX."""
    out = []
    try:
        from jax._src import compiler

        compiler.get_compile_options  # noqa: B018
    except _MISSING:
        out.append("jax._src.compiler.get_compile_options")
    from jax.experimental import serialize_executable

    if not hasattr(serialize_executable, "_JaxPjrtUnpickler"):
        out.append("jax.experimental.serialize_executable._JaxPjrtUnpickler")
    try:
        from jaxlib import lapack

        lapack._lapack.initialize  # noqa: B018
    except _MISSING:
        out.append("jaxlib.lapack._lapack.initialize")
    if "jaxlib.lapack._lapack.initialize" not in out and not hasattr(lapack, "registrations"):
        out.append("jaxlib.lapack.registrations")
    return out
