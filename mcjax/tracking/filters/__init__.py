"""Filters: Gaussian steps (:mod:`.gaussian`), the distributed consensus filters (:mod:`.consensus`,
:mod:`.robust_consensus`), each declared as a record of the filter contract (:mod:`mcjax.contract.filter`)
and found by name (:mod:`.registry`), any filter's step by its record (:mod:`.steps`), IMM (:mod:`.imm`,
:mod:`.consensus_imm`), and :func:`run_filter` for recorded data (:mod:`.recorded`)."""

from mcjax.tracking.filters.consensus import FilterOptions
from mcjax.tracking.filters.recorded import run_filter
from mcjax.tracking.filters.registry import FILTER_KINDS

__all__ = ["run_filter", "FILTER_KINDS", "FilterOptions"]
