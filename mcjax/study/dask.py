"""Sweeps on a Dask cluster: the chunks of a sweep computed by the workers of ``dask.distributed``.

``mcjax sweep SPEC --executor dask --scheduler tcp://HOST:PORT`` uses a running cluster;
``--executor dask --workers N`` starts one on this machine (a ``LocalCluster`` of N worker
processes) for the length of the sweep. docs/cluster.md says how to start a cluster.

How the work is shared:

* The unit of work is a chunk of the sweep's chunk plan (its batch-aligned runs). One Dask
  task computes one chunk and returns its rows (pandas DataFrames); Dask carries them back to
  this process, which writes them as part files exactly as a local sweep does (temporary
  file, then rename: :func:`mcjax.study.execute.publish_chunk`). Workers therefore never need to see
  the output folder: a cloud pool or another site's nodes work as well as a lab's machines
  with a shared disk, only this process touches ``--out``, and ``--resume`` works across
  executors (start on Dask, finish locally, or the reverse).
* The spec goes to the cluster once, pickled (a scenario from a ``file.py:SCENARIO``
  reference travels by value, so workers need not see that file; built-in and installed
  scenarios travel by name, so workers need mcjax installed). A worker unpickles it once and
  keeps it (:data:`_WORKER_SPECS`), so its compiled batch program — held by the engine per
  scenario and Config — serves every chunk that worker runs; for the built-in scenarios the
  engine's program store on the worker's disk (``MCJAX_CACHE_DIR``) also serves later sweeps.
* Results are the same bytes as a local sweep's: each run's random key depends only on its
  seed index, and every chunk runs the same batch program on batch-aligned slices. A worker
  runs a chunk only if its mcjax source, JAX and NumPy match this process's
  (:func:`software_fingerprint`); machines of a different CPU kind may still differ in the
  last bit (XLA compiles for the CPU it runs on).
* A worker that dies (killed, out of memory) has its chunk re-run by Dask on another worker
  (up to Dask's ``distributed.scheduler.allowed-failures`` times, 3 by default); nothing is
  written twice since only whole chunks are published. A chunk that raises stops the sweep
  with :class:`mcjax.study.execute.ChunkError` (one line: the chunk, its points, the error); the
  chunks already written stay.
* A scheduler that goes away (killed, its node lost) ends the sweep with
  :class:`SchedulerLost` (one line; the command exits 1) within :data:`LOST_AFTER` seconds:
  Dask cancels every chunk in flight when the client loses its scheduler, and the client is
  closed without waiting for the scheduler. The chunks written stay; ``--resume`` finishes
  them, locally or on a new cluster, with the same bytes. Dask's own log lines about the lost
  connection are silenced (the client reports it once).

Dask is an optional dependency: ``pip install -e ".[dask]"``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import logging
import os
import sys
import time
import uuid
import warnings
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable, Iterator, NamedTuple

from mcjax.base.validation import one_line
from mcjax.study.execute import ChunkError, ChunkRows, chunk_rows
from mcjax.study.plan import Study, describe_chunk

#: What to run when Dask is missing.
INSTALL_HINT = 'pip install -e ".[dask]"  (or: pip install "dask[distributed]")'
#: Seconds to wait for a scheduler given by --scheduler before giving up.
CONNECT_TIMEOUT = 20
#: How often (seconds) the client looks for completed chunks (and Ctrl-C) while it waits.
POLL = 0.05
#: Seconds within which a sweep whose scheduler went away ends (SchedulerLost, exit code 1).
LOST_AFTER = 10
#: Seconds given to closing a client whose scheduler is gone.
CLOSE_TIMEOUT = 2
#: Specs a worker keeps unpickled (each with its compiled program in the engine's caches).
_WORKER_SPECS_MAX = 4
#: The specs a worker process has unpickled, by their spec token (:class:`Shipment`).
_WORKER_SPECS: dict[str, Study] = {}
#: The first copy of each scenario a worker process has unpickled, by scenario token.
_WORKER_SCENARIOS: dict[str, Any] = {}


class SchedulerLost(ChunkError):
    """The Dask scheduler went away in the middle of a sweep; the message, one line, says so and
    how to finish (``--resume``)."""


class DaskMissing(ImportError):
    """``dask.distributed`` is not installed; the message says how to install it."""


def load_distributed():
    """The ``distributed`` module, or :class:`DaskMissing`."""
    try:
        import distributed
    except ImportError:
        raise DaskMissing(f"the dask executor needs Dask, which is not installed: {INSTALL_HINT}") from None
    return distributed


@lru_cache(maxsize=1)
def software_fingerprint() -> str:
    """A hash of what a chunk's numbers depend on besides the spec: mcjax's source files and
    the versions of JAX, jaxlib and NumPy. Client and workers must agree on it."""
    import jax
    import jaxlib
    import numpy

    h = hashlib.sha256()
    root = Path(__file__).resolve().parent
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    h.update(f"{jax.__version__}|{jaxlib.__version__}|{numpy.__version__}".encode())
    return h.hexdigest()


#: This process among the clients of a cluster (names what it sends).
_CLIENT = uuid.uuid4().hex[:12]
#: The specs sent from here, by id (each kept alive with its tokens and pickled bytes).
_SENT: dict[int, tuple[Study, str, str, bytes]] = {}
#: The scenarios named from here, by id (kept alive, so an id is never reused).
_NAMED: dict[int, Any] = {}


class Shipment(NamedTuple):
    """A spec as sent to the workers: its pickled bytes and two names a worker recognises it
    by. ``spec_token`` names the spec object, ``scenario_token`` its scenario object (the
    same for every spec of one scenario from one client process)."""

    spec_token: str
    scenario_token: str
    blob: bytes


def ship(spec: Study) -> Shipment:
    """The spec pickled for the workers (:func:`spec_bytes`), pickled once per spec object."""
    sent = _SENT.get(id(spec))
    if sent is None or sent[0] is not spec:
        _NAMED.setdefault(id(spec.scenario), spec.scenario)
        if len(_SENT) >= _WORKER_SPECS_MAX:
            _SENT.pop(next(iter(_SENT)))
        sent = _SENT[id(spec)] = (spec, f"{_CLIENT}-{uuid.uuid4().hex[:12]}", f"{_CLIENT}-{id(spec.scenario)}",
                                  spec_bytes(spec))
    return Shipment(*sent[1:])


def spec_bytes(spec: Study) -> bytes:
    """The spec pickled for the workers. The module of a scenario loaded from a file
    (``file.py:SCENARIO``, which workers may not see) is pickled by value; everything else
    by reference (mcjax and installed plugins must be importable on the workers)."""
    import cloudpickle

    user = {getattr(f, "__module__", None) for f in (spec.scenario.init, spec.scenario.step, spec.scenario.reduce)}
    modules = [sys.modules[m] for m in sorted(m for m in user if m and m.startswith("mcjax_user_scenario_"))
               if m in sys.modules]
    for m in modules:
        cloudpickle.register_pickle_by_value(m)
    try:
        return cloudpickle.dumps(spec)
    finally:
        for m in modules:
            cloudpickle.unregister_pickle_by_value(m)


def worker_specs() -> dict[str, Study]:
    """The specs this (worker) process keeps unpickled, by spec token (a copy of the dict)."""
    return dict(_WORKER_SPECS)


def _worker_spec(shipment: Shipment) -> Study:
    """The shipped spec in this worker process: unpickled the first time, then kept, with the
    first copy of its scenario that came from the same client. The engine caches compiled
    programs per scenario and Config, so a worker compiles once for every chunk of a sweep,
    and once for all the sweeps of one scenario and Config a client sends (a scenario from a
    file arrives as new functions with each unpickling; keeping the first copy avoids
    compiling again)."""
    spec = _WORKER_SPECS.get(shipment.spec_token)
    if spec is None:
        import pickle

        spec = pickle.loads(shipment.blob)
        scenario = _WORKER_SCENARIOS.setdefault(shipment.scenario_token, spec.scenario)
        spec = dataclasses.replace(spec, scenario=scenario)
        if len(_WORKER_SPECS) >= _WORKER_SPECS_MAX:
            _WORKER_SPECS.pop(next(iter(_WORKER_SPECS)))
        _WORKER_SPECS[shipment.spec_token] = spec
    return spec


def compute_chunk(shipment: Shipment, index: int, fingerprint: str) -> ChunkRows:
    """The Dask task: the rows of chunk ``index`` of the shipped spec (runs on a worker)."""
    if software_fingerprint() != fingerprint:
        import jax
        import numpy

        raise RuntimeError(f"this worker runs other software than the client (mcjax source, jax {jax.__version__}, "
                           f"numpy {numpy.__version__}); install the same versions everywhere, so results are the "
                           f"same bytes")
    return next(chunk_rows(_worker_spec(shipment), [index]))


def _pass(shipment: Shipment) -> Shipment:
    """A task that returns its input: the shipped spec enters the graph once, and is sent to
    each worker once (Dask copies a task's result to the workers whose tasks need it)."""
    return shipment


def _error_text(exc: BaseException) -> str:
    """An error in one line, ``Type: message``. An error that carries a traceback in its
    message (a scenario's host callback failing inside XLA) is shown by its last line, the
    Python error that started it."""
    text = str(exc)
    if "Traceback (most recent call last)" in text:
        lines = [line.strip() for line in text.splitlines() if line.strip()]
        if lines:
            text = one_line(lines[-1])
            return text if len(text) <= 300 else text[:280] + " …"
    text = one_line(text)
    text = text if len(text) <= 300 else text[:280] + " …"
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


@dataclass(frozen=True)
class DaskExecutor:
    """Computes a sweep's chunks as Dask tasks on the workers of ``client``'s cluster
    (:class:`mcjax.study.execute.Executor`); rows come back to this process as chunks complete."""

    client: Any  # distributed.Client

    def map_chunks(self, spec: Study, chunks: list[int],
                   should_stop: Callable[[], bool]) -> Iterator[ChunkRows]:
        distributed = load_distributed()
        if not chunks or should_stop():
            return
        shipment = ship(spec)
        fingerprint = software_fingerprint()
        run = uuid.uuid4().hex[:8]  # task names of this call (a cancelled chunk's name is not reused at once)
        spec_future = self.client.submit(_pass, shipment, key=f"mcjax-spec-{shipment.spec_token}-{run}")
        futures = {self.client.submit(compute_chunk, spec_future, i, fingerprint,
                                      key=f"mcjax-chunk-{shipment.spec_token}-{run}-{i}"): i for i in chunks}
        completed = distributed.as_completed(list(futures), loop=self.client.loop)
        lost = None  # when the client was first seen without its scheduler
        try:
            while not completed.is_empty():
                if should_stop():
                    return
                if self.client.status != "running":
                    lost = lost or time.monotonic()
                    if time.monotonic() - lost > LOST_AFTER / 2:
                        raise self._lost()
                done = completed.next_batch(block=False)
                if not done:
                    time.sleep(POLL)
                    continue
                if self.client.status != "running" and any(f.status == "cancelled" for f in done):
                    raise self._lost()  # Dask cancels everything in flight when the scheduler goes
                failed = []
                for future in sorted(done, key=futures.get):  # complete chunks first, in plan order
                    if future.status == "finished":
                        rows = future.result()
                        future.release()
                        yield rows
                    else:
                        failed.append(future)
                if failed:
                    future = failed[0]
                    exc = future.exception() if future.status == "error" else RuntimeError(future.status)
                    raise ChunkError(f"{describe_chunk(spec, futures[future])} failed on a Dask worker: "
                                     f"{_error_text(exc)}")
        finally:
            if self.client.status == "running":
                left = [f for f in futures if f.status not in ("finished", "error")]
                if left:
                    self.client.cancel(left)
                spec_future.release()

    def _lost(self) -> SchedulerLost:
        address = getattr(self.client.scheduler, "address", None) or "its address"
        return SchedulerLost(f"lost the Dask scheduler at {address} (its chunks in flight are cancelled); finish "
                             f"with --resume (locally, or on a new cluster)")


@contextlib.contextmanager
def connect(scheduler: str | None = None, workers: int | None = None) -> Iterator[DaskExecutor]:
    """A :class:`DaskExecutor` on the cluster at ``scheduler`` (an address such as
    ``tcp://10.0.0.5:8786``), or on a ``LocalCluster`` of ``workers`` processes started here
    (one thread each; the machine's cores are shared among them as JAX CPU devices) and shut
    down on leaving. Raises :class:`DaskMissing` without Dask, OSError when the scheduler
    cannot be reached."""
    distributed = load_distributed()
    if (scheduler is None) == (workers is None):
        raise ValueError("give a scheduler address or a number of workers")
    with contextlib.ExitStack() as stack:
        if scheduler is not None:
            stack.enter_context(_quiet_dask_logs())  # a lost scheduler is reported once, by SchedulerLost
            try:
                client = distributed.Client(scheduler, timeout=CONNECT_TIMEOUT, set_as_default=False)
            except (OSError, TimeoutError) as exc:
                raise OSError(f"cannot reach the Dask scheduler at {scheduler}: {one_line(exc)}") from None
        else:
            cluster = stack.enter_context(local_cluster(workers))
            client = distributed.Client(cluster, set_as_default=False)
        stack.callback(_close, client)
        yield DaskExecutor(client)


def _close(client) -> None:
    """Close ``client``; one whose scheduler is gone is closed without waiting for it."""
    if client.status == "running":
        client.close()
        return
    with contextlib.suppress(Exception):
        client.close(timeout=CLOSE_TIMEOUT)


@contextlib.contextmanager
def _quiet_dask_logs() -> Iterator[None]:
    """Dask's loggers at CRITICAL for the ``with`` block (then as they were)."""
    loggers = [logging.getLogger(name) for name in ["distributed", *logging.root.manager.loggerDict]
               if name == "distributed" or name.startswith("distributed.")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def local_cluster(workers: int, **kwargs):
    """A ``LocalCluster`` of ``workers`` worker processes with one thread each, each worker
    given ``max(1, cores // workers)`` JAX CPU devices (``MCJAX_CPU_DEVICES``, unless this
    process sets it), no dashboard and no log lines below CRITICAL (a failed chunk is reported
    once, by the client). ``kwargs`` go to ``LocalCluster``."""
    import logging

    distributed = load_distributed()
    devices = os.environ.get("MCJAX_CPU_DEVICES") or str(max(1, (os.cpu_count() or 1) // workers))
    env = {**kwargs.pop("env", {}), "MCJAX_CPU_DEVICES": devices}
    options = dict(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                   silence_logs=logging.CRITICAL, env=env)
    with warnings.catch_warnings():  # the scheduler's small web server takes another port if 8787 is busy: fine
        warnings.filterwarnings("ignore", message=r"Port \d+ is already in use")
        return distributed.LocalCluster(**{**options, **kwargs})
