"""The study pipeline: spec → plan → engine → store → report, one owner module per stage.

* :mod:`~mcjax.study.spec` reads and validates a sweep spec or a config file into a
  :class:`Study` (one validated, immutable object, built once);
* :mod:`~mcjax.study.plan` holds the :class:`Study`: its points table and each point's Params
  (built once), its chunk plan, and the memory check of that plan;
* :mod:`~mcjax.study.rows` turns a chunk's outputs into tidy rows;
* :mod:`~mcjax.study.execute` computes the chunks (:class:`LocalExecutor`; the Dask executor is
  :mod:`mcjax.study.dask`) and publishes them as part files (:func:`run_sweep`);
* :mod:`~mcjax.study.store` owns the output folder: identity file, parts, ``--resume``,
  ``--force``;
* :mod:`~mcjax.study.runner` runs a spec into its folder as ``mcjax sweep`` does
  (:func:`load_sweep`, :func:`run_sweep_folder`), reporting through callbacks.

``mcjax run``, ``mcjax sweep``, ``mcjax tune`` and the Dask executor all take a Study. The
names below are the pipeline's public face::

    from mcjax.study import load_spec, prepare_output, run_sweep
    study = load_spec("sweeps/default.toml", seeds=10, out_dir="results/default")
    prepare_output(study, study.out_dir)   # the identity file, as mcjax sweep writes it
    rows = run_sweep(study)                # the parts, into study.out_dir; and the rows
"""

from mcjax.base.validation import SpecError
from mcjax.study.execute import ChunkError, ChunkRows, Executor, LocalExecutor, chunk_rows, publish_chunk, run_sweep
from mcjax.study.plan import DEFAULT_SEEDS, Study, describe_chunk, memory_budget, step_sizes
from mcjax.study.rows import chunk_keys, chunk_parts, part_metadata, run_rows, timeseries_rows
from mcjax.study.spec import (MAX_BASE_SEED, MAX_CHUNK_SIZE, MAX_POINTS, MAX_RUNS, MAX_SEEDS, SPEC_KEYS, ConfigFile,
                              build_spec, is_config_file, is_sweep_spec, load_config_file, load_spec,
                              read_config_file)
from mcjax.study.runner import SweepProgress, SweepResult, load_sweep, run_sweep_folder, summary_columns, sweep_headline
from mcjax.study.store import (IDENTITY_FILE, RESULTS_DIR, OutputError, check_parts, default_out_dir, identity,
                               missing_chunks, prepare_output, read_identity)

__all__ = [
    "SpecError", "ChunkError", "ChunkRows", "Executor", "LocalExecutor", "chunk_rows", "publish_chunk", "run_sweep",
    "DEFAULT_SEEDS", "Study", "describe_chunk", "memory_budget", "step_sizes", "chunk_keys", "chunk_parts",
    "part_metadata", "run_rows", "timeseries_rows", "MAX_BASE_SEED", "MAX_CHUNK_SIZE", "MAX_POINTS", "MAX_RUNS",
    "MAX_SEEDS", "SPEC_KEYS", "ConfigFile", "build_spec", "is_config_file", "is_sweep_spec", "load_config_file",
    "load_spec", "read_config_file", "IDENTITY_FILE", "RESULTS_DIR", "OutputError", "check_parts",
    "default_out_dir", "identity", "missing_chunks", "prepare_output", "read_identity", "SweepProgress",
    "SweepResult", "load_sweep", "run_sweep_folder", "summary_columns", "sweep_headline",
]
