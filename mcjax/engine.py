"""The batch engine: ``vmap`` over runs of ``lax.scan`` over time, cut into fixed-size chunks.

A *scenario* is a :class:`mcjax.contract.Scenario` (``init``, ``step``, ``reduce``, optional
``timeseries``; docs/architecture.md). A sweep is ``points × seeds`` runs, ordered
point-major (run r = point ``r // n_seeds``, seed ``r % n_seeds``). Runs are cut into chunks
of one fixed size, the last one padded and trimmed, so one compiled program serves every
chunk and memory is bounded by the chunk, not the sweep.

Run r's key is ``fold_in(PRNGKey(base_seed), seed_index)``: a seed index draws the same
noise at every sweep point (common random numbers) and results do not depend on the chunk
size. Step t's key is ``fold_in(run_key, t)`` (noise drawn per step, never pre-drawn).

Every CPU core works: the process has one CPU device per core (:mod:`mcjax.runtime`), the
B-run batch program is compiled once, with the scenario's ``compiler_options``, and loaded
on every device (an XLA program is bound to its device; the copies run the same machine
code: :func:`mcjax.jaxcompat.deserialise`), and the batches of a
chunk go to the devices in turn, each device called from its own thread so they compute side
by side. Every device runs the same program on B-aligned slices, so the numbers do not depend
on the device count either (a ``shard_map`` over the devices gave other bits in the last place).

The entry points (:func:`simulate`, :func:`compiled`, :func:`run_chunks`,
:func:`program_futures`, :func:`devices`) first call :func:`mcjax.configure` (64-bit mode, the
CPU devices; once per process). What the engine keeps in a process — jitted functions and the
futures of compiled programs — is in one bounded dict, :func:`cached`; on disk, compiled
programs go to the program store (:mod:`mcjax.runtime`), for built-in scenarios and a user's
file or plugin scenario alike (:func:`_label`).
"""

from __future__ import annotations

import hashlib
import inspect
import sys
import threading
from collections import OrderedDict
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Callable, Hashable, Iterator

import jax
import jax.numpy as jnp
import numpy as np

from mcjax import jaxcompat, runtime
from mcjax.contract import Scenario
from mcjax.smoothing import column


def run_key(base_seed: int, seed_index) -> jax.Array:
    """The key of seed ``seed_index`` (the same at every sweep point)."""
    return jax.random.fold_in(jax.random.PRNGKey(base_seed), seed_index)


def _threefry2x32(k0, k1, x0, x1):
    """Threefry-2x32 with 20 rounds (Salmon, Moraes, Dror, Shaw 2011, "Parallel random numbers:
    as easy as 1, 2, 3", the Threefry-2x32 rotation constants and key schedule), on numpy
    uint32 arrays: the hash behind JAX's default PRNG."""
    rotations = ((13, 15, 26, 6), (17, 29, 16, 24))
    keys = (k0, k1, k0 ^ k1 ^ np.uint32(0x1BD11BDA))
    x0, x1 = x0 + keys[0], x1 + keys[1]
    for i in range(5):
        for r in rotations[i % 2]:
            x0 = x0 + x1
            x1 = ((x1 << np.uint32(r)) | (x1 >> np.uint32(32 - r))) ^ x0
        x0 = x0 + keys[(i + 1) % 3]
        x1 = x1 + keys[(i + 2) % 3] + np.uint32(i + 1)
    return x0, x1


def run_keys(base_seed: int, seed_index) -> np.ndarray:
    """:func:`run_key` of each seed index of the array ``seed_index``, as a numpy (n, 2) uint32
    array, computed in numpy: no JAX program is compiled for it (that took ~0.25 s of a
    sweep's start). JAX's default PRNG: ``PRNGKey(s)`` is the 32-bit words (high, low) of the
    64-bit ``s``, ``fold_in(key, d)`` is Threefry-2x32 keyed by ``key`` on the words (0, d).
    With another PRNG implementation configured in JAX, JAX computes them."""
    idx = np.asarray(seed_index)
    if jax.config.jax_default_prng_impl != "threefry2x32":
        return np.asarray(jax.vmap(lambda s: run_key(base_seed, s))(jnp.asarray(idx, jnp.uint32)))
    seed = int(np.int64(base_seed))  # JAX's range check: a 64-bit signed integer
    k0, k1 = np.uint32((seed >> 32) & 0xFFFFFFFF), np.uint32(seed & 0xFFFFFFFF)
    data = idx.astype(np.uint32).reshape(-1)
    with np.errstate(over="ignore"):
        y0, y1 = _threefry2x32(k0, k1, np.zeros_like(data), data)
    return np.stack([y0, y1], axis=-1).reshape(idx.shape + (2,))


#: Run ``key``'s draw for ``init``: ``fold_in(key, INIT_KEY)`` (step t draws ``fold_in(key, t)``).
INIT_KEY = 0x7FFFFFFF


def init_key(key) -> jax.Array:
    """The key a run's ``init`` draws from (:data:`INIT_KEY`)."""
    return jax.random.fold_in(key, INIT_KEY)


def time_loop(step: Callable, state, key, n_steps: int, *, block: int | None = None, remat: bool = False):
    """The one time-loop driver: ``step(state, key_t, t) -> (state, out)`` for ``t = 0 … n_steps−1``
    with ``key_t = fold_in(key, t)``; returns ``(final state, outs stacked over time)``.

    Serves the exact simulation (:func:`simulate`, ``block=None``: one ``lax.scan`` over the
    steps) and the smooth one of ``mcjax tune`` (``block = K``: a scan over blocks of K steps,
    each block under ``jax.checkpoint`` when ``remat``, so reverse mode keeps one state per
    block; steps past ``n_steps`` in the last block leave the state as it is and output zeros,
    trimmed from the result)."""

    def body(state, t):
        return step(state, jax.random.fold_in(key, t), t)

    if block is None:
        return jax.lax.scan(body, state, jnp.arange(n_steps))
    n_blocks = -(-n_steps // block)
    if n_steps % block:
        shapes = jax.eval_shape(body, state, jnp.asarray(0))[1]

        def idle(state, t):
            return state, jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), shapes)

        def padded(state, t):
            return jax.lax.cond(t < n_steps, body, idle, state, t)
    else:
        padded = body

    def run_block(state, ts):
        return jax.lax.scan(padded, state, ts)

    if remat:
        run_block = jax.checkpoint(run_block)
    state, outs = jax.lax.scan(run_block, state, jnp.arange(n_blocks * block).reshape(n_blocks, block))
    return state, jax.tree.map(lambda a: a.reshape((n_blocks * block,) + a.shape[2:])[:n_steps], outs)


def run_records(scenario, cfg, params, key, smoothing=None):
    """One run's records stacked over time: the exact simulation (``smoothing`` None) or the
    smooth one at those temperatures (:class:`mcjax.smoothing.Smooth`), with the same keys."""
    state = scenario.init(cfg, params, init_key(key))
    smooth = () if smoothing is None else (smoothing,)
    return time_loop(lambda s, k, t: scenario.step(cfg, params, s, k, *smooth), state, key, cfg.n_steps)[1]


def derivatives(scenario, cfg, params, key, sensitivity) -> dict:
    """One run's d output / d Param of the smooth system (a sweep's ``[sensitivity]``), forward
    mode (a per-agent Param moves every agent's value together), by :func:`mcjax.smoothing.column`."""
    names, outputs, smoothing = sensitivity

    def outputs_at(shift):
        q = params._replace(**{n: getattr(params, n) + shift[i] for i, n in enumerate(names)})
        reduced = scenario.reduce(cfg, run_records(scenario, cfg, q, key, smoothing), q)
        return {o: jnp.asarray(reduced[o]).astype(jnp.result_type(float)) for o in outputs}  # a flag's: 0

    jac = jax.jacfwd(outputs_at)(jnp.zeros(len(names), jnp.result_type(float)))
    return {column(o, n): jac[o][..., i] for o in outputs for i, n in enumerate(names)}


def simulate(scenario: Scenario, cfg, params, keys, *, records: bool = False, timeseries: bool = False,
             smoothing=None, sensitivity=None):
    """Run a batch: ``params`` and ``keys`` carry a leading run axis. Returns each run's reduced
    outputs (``scenario.reduce``: a dict of (runs, …) arrays) or, with ``records=True``, the
    records stacked over time (run, time, …): the caller chooses what is kept. ``timeseries``:
    ``(outputs, scenario.timeseries(...))`` from one simulation. ``smoothing``: the smooth
    system (:func:`run_records`); ``sensitivity`` (a sweep's ``[sensitivity]``): each run's
    :func:`derivatives` instead (a program of their own beside the exact one, whose outputs
    so stay bit for bit those of a sweep without them). Not jitted: see :func:`compiled`."""
    runtime.configure()

    def one(p, k):
        if sensitivity is not None:
            return derivatives(scenario, cfg, p, k, sensitivity)
        recs = run_records(scenario, cfg, p, k, smoothing)
        if records:
            return recs
        if timeseries:
            return scenario.reduce(cfg, recs, p), scenario.timeseries(cfg, recs, p)
        return scenario.reduce(cfg, recs, p)

    return jax.vmap(one)(params, keys)


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

    options = compiler_options(scenario)
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


def compiler_options(scenario: Scenario) -> dict | None:
    """The scenario's XLA options (:attr:`mcjax.contract.Scenario.compiler_options`) that this
    JAX knows; an unknown one is dropped (with a RuntimeWarning) rather than failing every
    compilation."""
    return runtime.known_compiler_options(scenario.compiler_options)


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
    :func:`mcjax.jaxcompat.deserialise`; should that fail, the device compiles its own). With a
    ``label`` (what names the program: :func:`_label`), the program is also stored on
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


def _label(scenario: Scenario, cfg, records: bool, timeseries: bool, sensitivity=None) -> str | None:
    """What names a batch program in the program store (:func:`mcjax.runtime.load_executable`,
    whose key adds mcjax's own source, JAX's version, the CPU and ``XLA_FLAGS``): the scenario,
    its Config, the flags, the sensitivities, the compiler options, and — for a scenario defined outside mcjax (a
    file or a plugin) — the content of its source files (:func:`_source_digest`). None (not
    stored) when those files cannot be read."""
    module = getattr(scenario.init, "__module__", "") or ""
    where = module if module.startswith("mcjax.") else _source_digest(scenario)
    if where is None:
        return None
    label = f"{scenario.name}|{where}|{cfg!r}|{bool(records)}|{bool(timeseries)}|{compiler_options(scenario)}"
    return label if sensitivity is None else f"{label}|{sensitivity!r}"


def _user_module(scenario: Scenario):
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


def stack_points(points: list) -> object:
    """Stack a list of Params (one per sweep point) into one Params with a point axis."""
    return jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *points)


#: Runs per compiled call. XLA's CPU code for a batch of B runs can differ in the last bit
#: between batch sizes and between lanes of one batch (vectorised vs remainder loops,
#: reduction tiling), so every sweep runs the same B-run program on B-aligned slices of the
#: run index: results are then bit-identical whatever the chunk size. Per-run cost on the
#: CPU is flat from about 100 runs per call up (measured; docs/benchmarks.md).
BATCH_SIZE = 100


def batch_size_for(n_runs: int) -> int:
    """The compiled batch of a sweep of ``n_runs`` runs (fixed by the sweep, not the chunk)."""
    return max(1, min(BATCH_SIZE, n_runs))


def chunk_plan(n_runs: int, chunk_size: int) -> list[tuple[int, int]]:
    """``[(start, stop), …]`` of the chunks covering ``n_runs`` runs. The chunk size is rounded
    up to a multiple of the compiled batch, so chunk boundaries stay batch-aligned."""
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be >= 1; got {chunk_size}")
    b = batch_size_for(n_runs)
    size = -(-chunk_size // b) * b
    return [(s, min(s + size, n_runs)) for s in range(0, n_runs, size)]


def chunk_inputs(point_params, n_seeds: int, base_seed: int, start: int, stop: int, size: int):
    """Params and keys of runs ``start … stop−1``, padded to ``size`` by repeating the last run."""
    runs = np.arange(start, stop)
    runs = np.concatenate([runs, np.full(size - len(runs), stop - 1)])
    point_idx, seed_idx = runs // n_seeds, runs % n_seeds
    params = jax.tree.map(lambda a: np.asarray(a)[point_idx], point_params)
    keys = run_keys(base_seed, seed_idx)
    return params, keys


def run_chunks(scenario: Scenario, cfg, point_params, n_seeds: int, *, base_seed: int = 0,
               chunk_size: int = 1000, chunks: list[int] | None = None,
               records: bool = False, timeseries: bool = False,
               sensitivity=None) -> Iterator[tuple[int, int, int, dict]]:
    """Run a sweep chunk by chunk; yields ``(chunk_index, start, stop, outputs)`` with the
    outputs trimmed to the chunk's real runs and converted to numpy.

    ``point_params``: Params with a leading point axis; ``chunks``: only those (resuming);
    ``timeseries`` as in :func:`simulate`; ``sensitivity`` adds the :func:`derivatives`.
    Each chunk is consecutive calls of one compiled :data:`BATCH_SIZE`-run program (the last
    padded by repeating the chunk's last run), sent to the devices in turn (one calling thread
    per device): memory is bounded by the chunk, the numbers depend on neither it nor the devices.
    """
    runtime.configure()
    n_points = int(jax.tree.leaves(point_params)[0].shape[0])
    n_runs = n_points * n_seeds
    b = batch_size_for(n_runs)
    plan = chunk_plan(n_runs, chunk_size)
    # as many devices as the largest chunk has batches (a one-batch sweep compiles once)
    devs = devices(scenario)[:max(1, max(-(-(e - s) // b) for s, e in plan))]
    fns = [compiled(scenario, cfg, records, timeseries)] + (
        [] if sensitivity is None else [compiled(scenario, cfg, sensitivity=sensitivity)])
    programs = None
    # one dispatching thread per device (from one thread: CPU/wall 1.05 with two devices, measured)
    lanes = [ThreadPoolExecutor(1, thread_name_prefix=f"mcjax-device-{i}") for i in range(len(devs))]

    def call(futures, dev, params, keys):  # this device's programs: they may still be loading
        params, keys = jax.device_put(params, dev), jax.device_put(keys, dev)
        out, *extra = [jax.tree.map(np.asarray, f.result()(params, keys)) for f in futures]
        for d in extra:  # the derivatives join the outputs
            out = (out[0] | d, out[1]) if timeseries else out | d
        return out

    try:
        for idx, (start, stop) in enumerate(plan):
            if chunks is not None and idx not in chunks:
                continue
            parts = []
            for k, s in enumerate(range(start, stop, b)):
                e = min(s + b, stop)
                params, keys = chunk_inputs(point_params, n_seeds, base_seed, s, e, b)
                if programs is None:
                    programs = [program_futures(fn, (params, keys), devs, _label(scenario, cfg, *flags),
                                                _user_module(scenario))
                                for fn, flags in zip(fns, [(records, timeseries), (False, False, sensitivity)])]
                d = k % len(devs)
                parts.append((e - s, lanes[d].submit(call, [p[d] for p in programs], devs[d], params, keys)))
            parts = [(m, f.result()) for m, f in parts]
            out = jax.tree.map(lambda *xs: np.concatenate([x[:m] for (m, _), x in zip(parts, xs)]),
                               *[o for _, o in parts])
            yield idx, start, stop, out
    finally:
        for lane in lanes:
            lane.shutdown(wait=True, cancel_futures=True)
