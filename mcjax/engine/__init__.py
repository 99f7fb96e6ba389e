"""The batch engine, a package by concern — :mod:`~mcjax.engine.keys` (run keys),
:mod:`~mcjax.engine.loop` (the time loop, ``simulate``), :mod:`~mcjax.engine.compilation` (compiled
programs, the cache, devices, store labels), :mod:`~mcjax.engine.chunks` (runs to chunks and devices).

The batch engine: ``vmap`` over runs of ``lax.scan`` over time, cut into fixed-size chunks.

A *scenario* is a :class:`mcjax.contract.Scenario` (``init``, ``step``, the ``reduce`` its ``summary``
declares, optional ``timeseries``; docs/architecture.md). A sweep is ``points × seeds`` runs, ordered
point-major (run r = point ``r // n_seeds``, seed ``r % n_seeds``). Runs are cut into chunks
of one fixed size, the last one padded and trimmed, so one compiled program serves every
chunk and memory is bounded by the chunk, not the sweep.

Run r's key is ``fold_in(PRNGKey(base_seed), seed_index)``: a seed index draws the same
noise at every sweep point (common random numbers) and results do not depend on the chunk
size. Step t's key is ``fold_in(run_key, t)`` (noise drawn per step, never pre-drawn).

Every CPU core works: the process has one CPU device per core (:mod:`mcjax.runtime`), the
B-run batch program is compiled once, with the scenario's ``compiler_options``, and loaded
on every device (an XLA program is bound to its device; the copies run the same machine
code: :func:`mcjax.runtime.jaxcompat.deserialise`), and the batches of a
chunk go to the devices in turn, each device called from its own thread so they compute side
by side. Every device runs the same program on B-aligned slices, so the numbers do not depend
on the device count either (a ``shard_map`` over the devices gave other bits in the last place).

The entry points (:func:`simulate`, :func:`compiled`, :func:`run_chunks`,
:func:`program_futures`, :func:`devices`) first call :func:`mcjax.configure` (64-bit mode, the
CPU devices; once per process). What the engine keeps in a process — jitted functions and the
futures of compiled programs — is in one bounded dict, :func:`cached`; on disk, compiled
programs go to the program store (:mod:`mcjax.runtime`), for built-in scenarios and a user's
file or plugin scenario alike (:func:`store_label`).
"""

from mcjax.engine.chunks import (BATCH_SIZE, batch_size_for, chunk_inputs, chunk_plan, point_and_seed, points_of,
                                 run_chunks, stack_points)
from mcjax.engine.keys import INIT_KEY, init_key, run_key, run_keys
from mcjax.engine.loop import derivatives, run_records, simulate, time_loop
from mcjax.engine.compilation import (CACHE_MAX, cached, cached_programs, compiled, compiler_options, devices, forget,
                                   program_futures, programs, store_label, user_module)

__all__ = ["BATCH_SIZE", "batch_size_for", "chunk_inputs", "chunk_plan", "point_and_seed", "points_of", "run_chunks",
           "stack_points", "INIT_KEY", "init_key", "run_key", "run_keys", "derivatives", "run_records", "simulate",
           "time_loop", "CACHE_MAX", "cached", "cached_programs", "compiled", "compiler_options", "devices", "forget",
           "program_futures", "programs", "store_label", "user_module"]
