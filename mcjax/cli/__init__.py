"""The command line: ``mcjax sweep / run / tune / report / list`` (:mod:`.commands`), ``mcjax check / league``
(:mod:`.judging`), the ``--executor / --scheduler / --workers`` options and the executor they open
(:mod:`.executor`), one-line refusals (:mod:`.guards`), progress bars, ``mcjax list``'s text and the generated
docs/cli.md (:mod:`.doc`).
Importing it loads no JAX, numpy or pandas."""

from mcjax.cli import judging  # noqa: F401  (registers `check` and `league` on main)
from mcjax.cli.commands import main

__all__ = ["main"]
