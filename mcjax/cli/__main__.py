"""``python -m mcjax.cli``: the ``mcjax`` command line, as ``python -m mcjax``."""

from mcjax.cli import main

if __name__ == "__main__":
    main(prog_name="mcjax")
