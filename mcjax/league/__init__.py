"""A league of filters: every filter of a league file run on the same seeds in every scenario and
fault point it names, and ranked (``mcjax league``). The league file (:mod:`mcjax.league.spec`),
the ranking by paired intervals (:mod:`mcjax.league.rank`), the league table
(:mod:`mcjax.league.table`), the timing pass (:mod:`mcjax.league.timing`), ``mcjax league``
without the CLI (:mod:`mcjax.league.runner`) and the league folder's files
(:mod:`mcjax.league.folder`). docs/claims.md ("The league") says how to write a league file.

Importing the package imports no JAX; the modules that run sweeps (spec, timing, runner) do.
"""
