"""Where a command's chunks are computed, as the CLI takes it: this process, or a Dask cluster
(``--executor``, ``--scheduler``, ``--workers`` of ``mcjax sweep`` and ``mcjax check``), checked
together before anything runs, and the executor opened and closed around the work."""

from __future__ import annotations

import contextlib
import shlex
import sys
from typing import NamedTuple

import click


def _fail(message: str) -> None:
    click.echo("error: " + " ".join(str(message).split()), err=True)  # always one line
    sys.exit(2)


class Remote(NamedTuple):
    """Where a sweep's chunks are computed: ``dask`` False (this process), or a Dask cluster at
    ``scheduler`` or of ``workers`` local processes; ``words``: the options, for the resume hint."""

    dask: bool = False
    scheduler: str | None = None
    workers: int | None = None
    words: str = ""


def executor_options(executor: str, scheduler: str | None, workers: int | None) -> Remote:
    """Check --executor, --scheduler and --workers together (a one-line error and exit 2 for
    a combination that makes no sense, or for --executor dask without Dask installed)."""
    if executor != "dask":
        if scheduler is not None or workers is not None:
            _fail(f"{'--scheduler' if scheduler is not None else '--workers'} needs --executor dask")
        return Remote()
    if scheduler is not None and workers is not None:
        _fail("--scheduler and --workers exclude each other: --scheduler uses a running cluster, --workers starts "
              "one on this machine")
    if scheduler is None and workers is None:
        _fail("--executor dask needs --scheduler ADDRESS (a running cluster, e.g. tcp://10.0.0.5:8786) or --workers N "
              "(a cluster of N processes on this machine)")
    if workers is not None and workers < 1:
        _fail(f"--workers must be at least 1; got {workers}")
    if scheduler is not None and not scheduler.strip():
        _fail("--scheduler must be an address such as tcp://10.0.0.5:8786")
    from mcjax.study.dask import DaskMissing, load_distributed

    try:
        load_distributed()
    except DaskMissing as exc:
        _fail(str(exc))
    words = f" --executor dask --scheduler {shlex.quote(scheduler)}" if scheduler else f" --executor dask --workers {workers}"
    return Remote(True, scheduler, workers, words)


@contextlib.contextmanager
def open_executor(remote: Remote):
    """The executor of a sweep: None (this process), or one on a Dask cluster, connected here
    (a one-line error and exit 2 when the scheduler cannot be reached) and closed after."""
    if not remote.dask:
        yield None
        return
    from mcjax.study.dask import connect

    with contextlib.ExitStack() as stack:
        try:
            executor = stack.enter_context(connect(remote.scheduler, remote.workers))
        except OSError as exc:
            _fail(str(exc))
        yield executor
