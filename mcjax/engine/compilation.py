"""Compiled programs: the jitted simulation of a scenario and config (defined once per
process), the one bounded in-process cache of jitted functions and compiled programs, a batch
program compiled once and copied to every device, the devices a sweep uses, and the labels
that name a program in the program store on disk (:mod:`mcjax.runtime`)."""

from __future__ import annotations

import hashlib
import inspect
import sys
import threading
from collections import OrderedDict
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Callable, Hashable

import jax
import numpy as np

from mcjax import runtime
from mcjax.contract import Scenario
from mcjax.engine.loop import simulate
from mcjax.runtime import jaxcompat


def compiled(scenario: Scenario, cfg, records: bool = False, timeseries: bool = False,
             sensitivity=None) -> Callable:
    """The jitted :func:`simulate` for one scenario and config (defined once per process,
    however the flags are spelled: positionally, by keyword or left at their defaults),
    compiled with the scenario's :func:`compiler_options` when called (or lowered) on arrays;
    inside a transformation of your own (``jit``, ``grad``) it is the same without them."""
    runtime.configure()
    records, timeseries = bool(records), bool(timeseries)
    return cached(("jit", scenario, cfg, records, timeseries, sensitivity),
                  lambda: _compiled(scenario, cfg, records, timeseries, sensitivity))


def _compiled(scenario: Scenario, cfg, records: bool, timeseries: bool, sensitivity) -> Callable:
    def run(params, keys):
        return simulate(scenario, cfg, params, keys, records=records, timeseries=timeseries, sensitivity=sensitivity)

    options = compiler_options(scenario, cfg)
    top = jax.jit(run, compiler_options=options)
    return top if options is None else _Program(top, jax.jit(run))


class _Program:
    """A jitted function with compiler options (``top``) that, called on tracers — inside a
    caller's ``jit``, ``make_jaxpr`` or ``grad``, where JAX allows no options — runs ``nested``,
    the same function without them. Everything else (``lower``, ``trace``, …) is ``top``'s."""

    def __init__(self, top, nested):
        self._top, self._nested = top, nested

    def __call__(self, params, keys):
        traced = any(isinstance(a, jax.core.Tracer) for a in jax.tree.leaves((params, keys)))
        return (self._nested if traced else self._top)(params, keys)

    def __getattr__(self, name):
        return getattr(self._top, name)


def compiler_options(scenario: Scenario, cfg=None) -> dict | None:
    """The scenario's XLA options (:attr:`mcjax.contract.Scenario.compiler_options`) for ``cfg``
    (default ``scenario.Config()``; read only where the scenario gives its options as a function
    of the Config) that this JAX knows; an unknown one is dropped (with a RuntimeWarning) rather
    than failing every compilation."""
    options = scenario.compiler_options
    if callable(options):
        options = options(scenario.Config() if cfg is None else cfg)
    return runtime.known_compiler_options(options)


def devices(scenario: Scenario | None = None) -> list:
    """The devices a sweep's batches are spread over: JAX's default backend's (on the CPU, one
    per core: :mod:`mcjax.runtime`); the first alone for a scenario that declares ``one_device``."""
    runtime.configure()
    return jax.local_devices()[:1] if scenario is not None and scenario.one_device else jax.local_devices()


#: The in-process cache (:func:`cached`): ``("jit", scenario, cfg, flags…)``, ``("programs", fn,
#: input signature, devices)``; other layers add their own kinds (e.g. tune's batch functions).
_CACHE: OrderedDict = OrderedDict()
CACHE_MAX = 96  # the two caches it replaced held 32 jitted functions and 64 programs
_CACHE_LOCK = threading.Lock()


def cached(key: Hashable, make: Callable):
    """What this process keeps under ``key`` (a tuple starting with its kind), made by
    ``make()`` the first time (outside the lock: two threads may both make it, the first to
    finish is kept). The least recently used entry goes past :data:`CACHE_MAX`. The one
    in-process cache of jitted functions and compiled programs (on disk: :mod:`mcjax.runtime`)."""
    with _CACHE_LOCK:
        if key in _CACHE:
            _CACHE.move_to_end(key)
            return _CACHE[key]
    value = make()
    with _CACHE_LOCK:
        value = _CACHE.setdefault(key, value)
        while len(_CACHE) > CACHE_MAX:
            _CACHE.popitem(last=False)
    return value


def forget(kind: str | None = None) -> None:
    """Drop what :func:`cached` keeps: everything, or the entries of one kind (``"jit"``, …)."""
    with _CACHE_LOCK:
        for key in [k for k in _CACHE if kind is None or k[0] == kind]:
            del _CACHE[key]


def cached_programs(fn) -> list:
    """The lists of program futures :func:`program_futures` built for the jitted ``fn`` in this
    process (oldest first), e.g. to read a compiled program's ``memory_analysis()``."""
    with _CACHE_LOCK:
        return [v for k, v in _CACHE.items() if k[0] == "programs" and k[1] is fn]


def programs(fn, args: tuple, devs, label: str | None = None) -> list:
    """``fn`` (jitted) compiled ahead of time for arguments shaped as ``args`` on each device of
    ``devs`` (:func:`program_futures`, waiting for every device's)."""
    return [f.result() for f in program_futures(fn, args, devs, label)]


def program_futures(fn, args: tuple, devs, label: str | None = None, local=None) -> list:
    """Futures of ``fn`` compiled ahead of time for arguments shaped as ``args`` (e.g. a batch's
    Params and keys) for each device of ``devs``: the same program on every device, compiled
    once and loaded on the other devices (~1 s each,
    :func:`mcjax.runtime.jaxcompat.deserialise`; should that fail, the device compiles its own). With a
    ``label`` (what names the program: :func:`store_label`), the program is also stored on
    disk and loaded from there next time (:func:`mcjax.runtime.load_executable`; ``local``: a
    user's scenario module, whose classes in ``args`` are stored by their name in it).

    The first device's program is ready when this returns; the others' may still be loading
    in background threads (the engine's thread for a device waits for its own), so the first
    device starts computing as soon as its program is there."""
    runtime.configure()
    shapes = (str(jax.tree.structure(args)),
              tuple((np.shape(a), np.asarray(a).dtype.str) for a in jax.tree.leaves(args)))
    sig = ("programs", fn, shapes, tuple(devs))
    disk_key = None if label is None else f"{label}|{shapes}"
    futures = cached(sig, lambda: _build(fn, args, devs, disk_key, local))

    def forget_if_failed(f):  # a program that failed to build is not kept: the next call tries again
        if f.exception() is not None:
            with _CACHE_LOCK:
                if _CACHE.get(sig) is futures:
                    del _CACHE[sig]

    for f in futures:  # (on a future already done, the check runs at once)
        f.add_done_callback(forget_if_failed)
    return futures


def _build(fn, args: tuple, devs, disk_key: str | None, local) -> list:
    """:func:`program_futures`' futures, built: loaded from the store, or compiled once."""

    def compile_for(i):  # the last resort: device i compiles its own
        return fn.lower(*jax.device_put(args, devs[i])).compile()

    def copy_to(i, first, data=None):
        try:
            program = jaxcompat.deserialise(data if data is not None else jaxcompat.serialise(first), devs[i])
        except Exception:  # noqa: BLE001 — this JAX cannot load it on another device
            program = None
        return program if program is not None else compile_for(i)

    pool = ThreadPoolExecutor(len(devs), thread_name_prefix="mcjax-program")
    futures = None
    if disk_key is not None:  # one thread per device: deserialising runs outside the GIL
        loading = [pool.submit(runtime.load_executable, disk_key, d, local) for d in devs]
        runtime.prepare_loading()  # meanwhile, on this otherwise idle thread
        first = loading[0].result()
        if first is not None:
            futures = [loading[0], *(_or_else(f, lambda i=i: copy_to(i, first)) for i, f in enumerate(loading) if i)]
    if futures is None:
        lowered = fn.lower(*jax.device_put(args, devs[0]))
        first = lowered.compile()
        data = jaxcompat.serialise(first) if disk_key is not None or len(devs) > 1 else None
        if disk_key is not None:
            runtime.store_executable(disk_key, data, jaxcompat.custom_call_targets(lowered), local)
        done = Future()
        done.set_result(first)
        futures = [done, *(pool.submit(copy_to, i, first, data) for i in range(1, len(devs)))]
    pool.shutdown(wait=False)  # the copies still loading finish in the background
    return futures


def _or_else(future: Future, make: Callable) -> Future:
    """A future of ``future``'s result, or of ``make()`` (run where ``future`` finished) when
    that result is None."""
    out = Future()

    def settle(f):
        try:
            result = f.result()
            out.set_result(result if result is not None else make())
        except BaseException as e:  # noqa: BLE001 — handed to whoever waits for the program
            out.set_exception(e)

    future.add_done_callback(settle)
    return out


def store_label(scenario: Scenario, cfg, records: bool, timeseries: bool, sensitivity=None) -> str | None:
    """What names a batch program in the program store (:func:`mcjax.runtime.load_executable`,
    whose key adds mcjax's own source, JAX's version, the CPU and ``XLA_FLAGS``): the scenario,
    its Config, the flags, the sensitivities, the compiler options, and — for a scenario defined outside mcjax (a
    file or a plugin) — the content of its source files (:func:`_source_digest`). None (not
    stored) when those files cannot be read."""
    module = getattr(scenario.init, "__module__", "") or ""
    where = module if module.startswith("mcjax.") else _source_digest(scenario)
    if where is None:
        return None
    text = f"{scenario.name}|{where}|{cfg!r}|{bool(records)}|{bool(timeseries)}|{compiler_options(scenario, cfg)}"
    return text if sensitivity is None else f"{text}|{sensitivity!r}"


def user_module(scenario: Scenario):
    """The module of a scenario defined outside mcjax (None for a built-in one): a scenario file
    is imported under another name in each process, so its classes are stored by their name in
    it (:func:`mcjax.runtime.store_executable`)."""
    module = getattr(scenario.init, "__module__", None) or ""
    return None if module.startswith("mcjax.") else sys.modules.get(module)


def _source_digest(scenario: Scenario) -> str | None:
    """A hash of the source files of a scenario defined outside mcjax: the files of its
    functions (``init``, ``step``, ``summary`` or ``reduce``, ``series`` or ``timeseries``),
    every ``.py`` file of the package they belong to (a plugin), and the modules next to a
    scenario file that it imports (its own helpers). Code it imports from elsewhere (other installed packages) is not
    covered: after changing such code, delete the program store's folder."""
    files = set()
    try:
        own = (scenario.init, scenario.step, scenario.summary or scenario.reduce,
               scenario.series or scenario.timeseries)
        for fn in own:
            if fn is None:
                continue
            path = Path(inspect.getsourcefile(fn)).resolve()
            files.add(path)
            module = sys.modules.get(getattr(fn, "__module__", None) or "")
            package = (getattr(module, "__package__", None) or "").partition(".")[0]
            top = sys.modules.get(package) if package else None
            if top is not None and getattr(top, "__file__", None):
                files.update(Path(top.__file__).resolve().parent.rglob("*.py"))
            else:  # a loose file: its helpers beside it
                for value in vars(module).values() if module is not None else ():
                    helper = value if inspect.ismodule(value) else sys.modules.get(getattr(value, "__module__", "") or "")
                    src = getattr(helper, "__file__", None)
                    if src and Path(src).resolve().parent == path.parent:
                        files.add(Path(src).resolve())
        h = hashlib.sha256()
        for path in sorted(files):
            h.update(path.name.encode() + b"\0" + path.read_bytes())
        return "src:" + h.hexdigest()
    except (TypeError, OSError):  # a function without a readable source file
        return None
