"""``python -m mcjax``: the ``mcjax`` command line (:func:`mcjax.cli.main`), for a Python whose
scripts folder is not on PATH."""

from mcjax.cli import main

if __name__ == "__main__":
    main(prog_name="mcjax")
