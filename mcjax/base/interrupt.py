"""Ctrl-C during a long command, and leaving the process safely.

The first Ctrl-C of a sweep, run or tune is acknowledged at once and asks the work to stop
after the chunk (or step) in flight; the second exits with 130 at once. Python's wakeup fd
wakes a watcher thread even while XLA holds the main thread. The command's own process ends
with ``os._exit`` after flushing its output, so no signal lands in the interpreter's teardown
(JAX's compute and compile threads may still run). No JAX.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from pathlib import Path

#: What the first Ctrl-C of a sweep or run prints, at once.
ACK = "stopping after the chunk in flight; press Ctrl-C again to stop now"
#: The same for a sweep on a Dask cluster, which cancels its chunks in flight.
ACK_DASK = "stopping: cancelling the chunks in flight (the chunks written stay); press Ctrl-C again to stop now"


#: What must happen before the process leaves at once (:func:`exit_now`, a second Ctrl-C), last
#: added first: e.g. removing an output folder's lock (:mod:`mcjax.study.lock`).
AT_EXIT: list = []


def last_calls() -> None:
    """Run (and forget) the callables of :data:`AT_EXIT`, last added first, ignoring their errors."""
    while AT_EXIT:
        with contextlib.suppress(Exception):
            AT_EXIT.pop()()


def exit_now(code: int) -> None:
    """Leave at once, without the interpreter's teardown: JAX's compute and compile threads may
    still run, and tearing the runtime down under them can crash the process. :data:`AT_EXIT`
    runs first."""
    last_calls()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


#: How ``sys.argv[0]`` ends in the mcjax command's own process: the ``mcjax`` script, ``python -m mcjax.cli``,
#: ``python -m mcjax``.
COMMAND_PATHS = (("mcjax",), ("mcjax", "cli", "__main__.py"), ("mcjax", "__main__.py"))


def own_process() -> bool:
    """Whether this process is the mcjax command itself (:data:`COMMAND_PATHS`), not a program that calls
    it (click's test runner): only then does a command keep its Ctrl-C handling to the end and leave
    without the interpreter's teardown."""
    parts = Path(sys.argv[0]).parts
    return any(parts[-len(end):] == end for end in COMMAND_PATHS)


def finish(stop: threading.Event) -> None:
    """The end of a sweep or run that completed: in the command's own process, leave now (130
    if a Ctrl-C came meanwhile), so no Ctrl-C can land in the teardown."""
    if own_process():
        exit_now(130 if stop.is_set() else 0)


@contextlib.contextmanager
def ctrl_c(last_words, ack: str = ACK):
    """Ctrl-C during a sweep or run. The first one is acknowledged at once (``ack``) and sets
    the yielded Event: the sweep stops after the chunk in flight. The second stops now:
    ``last_words()`` is printed and the process exits with 130. A watcher thread hears the
    signal through Python's wakeup fd, so the acknowledgement comes even while XLA holds the
    main thread. Outside the main thread (no signals there) the Event is never set."""
    stop = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)

    def say(text: str) -> None:
        with contextlib.suppress(OSError):
            os.write(2, (text + "\n").encode())

    def watch() -> None:
        count = 0
        while True:
            try:
                data = os.read(read_fd, 64)
            except OSError:
                return
            if not data:
                return
            count += data.count(bytes([signal.SIGINT]))
            if count >= 2:
                say(f"\nstopped now; {last_words()}")
                last_calls()
                os._exit(130)
            if count == 1 and not stop.is_set():
                stop.set()
                say(f"\n{ack}")

    old_handler = signal.signal(signal.SIGINT, lambda signum, frame: None)
    old_fd = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
    watcher = threading.Thread(target=watch, name="mcjax-ctrl-c", daemon=True)
    watcher.start()
    try:
        yield stop
    finally:
        if not own_process():  # in its own process the handler stays to the end (see finish)
            signal.set_wakeup_fd(old_fd)
            signal.signal(signal.SIGINT, old_handler)
            os.close(write_fd)
            watcher.join(timeout=1.0)
            os.close(read_fd)
