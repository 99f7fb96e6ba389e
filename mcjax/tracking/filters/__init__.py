"""Filters: Gaussian steps (:mod:`.gaussian`), the distributed consensus filters
(:mod:`.consensus`), IMM (:mod:`.imm`, :mod:`.consensus_imm`), and :func:`run_filter` for
recorded data (:mod:`.recorded`)."""

from mcjax.tracking.filters.consensus import FILTER_KINDS, FilterOptions
from mcjax.tracking.filters.recorded import run_filter

__all__ = ["run_filter", "FILTER_KINDS", "FilterOptions"]
