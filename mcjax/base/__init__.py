"""The foundations, with no JAX: one validation layer (kinds, ranges, choices, one-line messages), display
units, the environment variables, atomic file writes, Ctrl-C handling, the Parquet layer (part files,
schema metadata) and a dataset's provenance (package versions, git revision). Every other layer may
import these; they import nothing else of mcjax."""
