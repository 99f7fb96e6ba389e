"""A paper's claims as data: a claims file (:mod:`mcjax.claims.spec`), its verdicts from the runs
(:mod:`mcjax.claims.evaluate`), ``mcjax check`` without the CLI (:mod:`mcjax.claims.runner`), the
check folder's files (:mod:`mcjax.claims.folder`) and the verdict table's report
(:mod:`mcjax.claims.report`). docs/claims.md says how to write a claims file.

Importing the package imports no JAX; the modules that run sweeps (spec, runner) do.
"""
