"""Ranking filters by their paired intervals, one scenario × point at a time.

Every filter of a league cell runs on the same seeds, so two filters compare run by run: the
difference of their errors seed by seed, with its 95 % Student-t interval
(:func:`mcjax.analysis.statistics.mean_ci`, over the seeds where both are finite).

The rule (:func:`paired_ranks`):

1. sort the filters by their mean error (the finite runs'), lowest first;
2. the first filter left is the *leader* of the next rank; every filter left whose paired
   interval of (its error − the leader's) contains 0 shares that rank (it is not shown to be worse);
3. remove them and repeat with the next rank (1, 2, 3, …: one number per group).

So rank 1 is the best filter and every filter not shown to be worse than it; a filter with a
rank of its own is clearly worse than every leader before it. A pair with fewer than two paired
runs has no interval: it cannot be told apart and shares the rank. A filter with no finite run
has no rank (None).

Pure functions of numbers; no JAX.
"""

from __future__ import annotations

import math
from typing import Mapping

import numpy as np
import pandas as pd

from mcjax.analysis.statistics import MeanCI, mean_ci


def paired_difference(a: pd.Series, b: pd.Series) -> MeanCI:
    """Mean of ``a − b`` over the seeds (the index) where both are finite, with its 95 % interval."""
    a, b = a.astype(float), b.astype(float)
    common = a.index.intersection(b.index)
    d = a.loc[common].to_numpy() - b.loc[common].to_numpy()
    return mean_ci(d[np.isfinite(d)])


def _mean(x: pd.Series) -> float:
    v = x.astype(float).to_numpy()
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else math.nan


def overlaps(a: pd.Series, b: pd.Series) -> bool:
    """True when the paired interval of ``a − b`` contains 0 (or there is none: fewer than two pairs)."""
    d = paired_difference(a, b)
    return not (math.isfinite(d.low) and math.isfinite(d.high)) or d.low <= 0.0 <= d.high


def paired_ranks(values: Mapping[str, pd.Series]) -> dict[str, int | None]:
    """The rank of each filter (module docstring): ``values`` maps a filter to its per-run errors
    indexed by seed; lower is better. Filters of equal mean keep the mapping's order."""
    means = {f: _mean(v) for f, v in values.items()}
    left = sorted((f for f in values if math.isfinite(means[f])), key=lambda f: means[f])
    ranks: dict[str, int | None] = {f: None for f in values}
    rank = 0
    while left:
        rank += 1
        leader = left[0]
        group = [leader] + [f for f in left[1:] if overlaps(values[f], values[leader])]
        for f in group:
            ranks[f] = rank
        left = [f for f in left if f not in group]
    return ranks
