"""The command line: ``mcjax sweep / run / check / tune / report / list`` (:mod:`.commands`), the
``--executor / --scheduler / --workers`` options and the executor they open (:mod:`.executor`), progress bars, ``mcjax list``'s text and the
generated docs/cli.md (:mod:`.doc`). Importing it loads no JAX, numpy or pandas."""

from mcjax.cli.commands import main

__all__ = ["main"]
