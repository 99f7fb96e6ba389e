"""How a command refuses and fails: one line on stderr per mistake and exit 2 (bad input, found before anything
runs) or exit 1 (a chunk that failed), and the checks made before a command starts — the environment variables,
and the installed filter plugins' names for the commands that run filters. No JAX until a filter is looked up."""

from __future__ import annotations

import sys

import click

from mcjax.base import envvars
from mcjax.base.interrupt import exit_now, own_process


def fail(message: str) -> None:
    """``error: …`` on stderr, one line per line of ``message`` (a spec with several mistakes: one each, as
    :class:`mcjax.base.validation.SpecError` holds them), white space folded within each; exit 2."""
    lines = [" ".join(line.split()) for line in str(message).splitlines()]
    click.echo("\n".join(f"error: {line}" for line in lines if line) or "error:", err=True)
    sys.exit(2)


def chunk_failed(message: str) -> None:
    """A chunk failed (computing or writing): one line, exit 1 (at once in the command's own process)."""
    click.echo(f"error: {message}", err=True)
    if own_process():
        exit_now(1)
    sys.exit(1)


def check_environment() -> None:
    """The environment variables mcjax reads, checked before JAX starts (one line, exit 2)."""
    try:
        envvars.check()
    except ValueError as exc:
        fail(str(exc))


def refuse_clashing_filters() -> None:
    """An installed filter plugin that takes a built-in filter's name (:func:`mcjax.tracking.filters.registry.clashes`)
    stops a command that runs filters before anything runs: one line, exit 2."""
    from mcjax.tracking.filters import registry

    found = registry.clashes()
    if found:
        fail(found[0])
