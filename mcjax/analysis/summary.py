"""One summary per report page: :class:`Summary`, built once from a runs table and its metadata by
:func:`summarize_dataset`, is what the page's table, its findings, its quality sentences and its
figures read (as the study pipeline builds one Study), instead of each rebuilding the schema, the
swept axes and the :func:`mcjax.analysis.tables.summarize` table.

The summaries the findings and figures group by other keys (one axis per panel, two axes of a
heatmap, a single point) come from :meth:`Summary.by` and :meth:`Summary.at`: cut from the one
table when they group the same runs (the table's rows, reordered), computed once and kept when they
pool over an axis. No JAX, no matplotlib.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import pandas as pd

from mcjax.analysis import tables
from mcjax.analysis.quality import same_value

__all__ = ["Summary", "summarize_dataset", "summary_for"]


@dataclass(frozen=True, eq=False)  # frames inside: compared by identity
class Summary:
    """What a report page reads of a runs table (see :func:`summarize_dataset`)."""

    schema: tables.Schema           # the metadata's Schema, checked against the table's columns
    axes: tuple[str, ...]           # the swept axes (or those asked for)
    plot_axes: tuple[str, ...]      # those of them with more than one value in the runs
    data: pd.DataFrame              # the runs, per-agent (list) axis cells as tuples (tables.prepare)
    table: pd.DataFrame             # tables.summarize(runs, metadata, axes): per point and filter
    _kept: dict = field(default_factory=dict, repr=False)  # the other groupings asked for, by keys

    def by(self, keys: Sequence[str]) -> pd.DataFrame:
        """``tables.summarize(data, schema, keys)`` over every run: cut from :attr:`table` when the
        groups are the same (every axis left out has one value), else computed once and kept."""
        keys = tuple(keys)
        if keys not in self._kept:
            left_out = [a for a in self.axes if a not in keys]
            if set(keys) <= set(self.axes) and all(a not in self.plot_axes for a in left_out):
                rank = self.table["filter"].map(tables.filter_rank(list(self.schema.filters)))
                cut = self.table.drop(columns=left_out).assign(_rank=rank)
                cut = cut.sort_values([*keys, "_rank"], kind="stable").drop(columns="_rank")
                self._kept[keys] = cut[[*keys, *cut.columns.drop(list(keys))]].reset_index(drop=True)
            else:
                self._kept[keys] = tables.summarize(self.data, self.schema, list(keys))
        return self._kept[keys]

    def at(self, keys: Sequence[str], panel: Sequence[tuple[str, Any]]) -> pd.DataFrame:
        """The summary by ``keys`` of the runs at one panel (``((axis, value), ...)`` of other
        axes): the rows of ``by([*keys, *panel axes])`` there, without the panel's columns."""
        others = [a for a, _ in panel]
        s = self.by([*keys, *others])
        mask = pd.Series(True, index=s.index)
        for a, v in panel:
            mask &= same_value(s[a], v)
        return s[mask.to_numpy()].drop(columns=others).reset_index(drop=True)


def summarize_dataset(df: pd.DataFrame, metadata: Mapping[str, Any] | tables.Schema,
                      axes: str | Sequence[str] | None = None) -> Summary:
    """The one :class:`Summary` of a runs table: its schema (:func:`mcjax.analysis.tables.schema`,
    checked against the columns), its swept axes (``axes``, default the metadata's), those with more
    than one value, the runs with list cells as tuples and :func:`mcjax.analysis.tables.summarize`'s
    table. Raises what those raise (a metadata that does not fit the table, no ``filter`` column)."""
    sch = tables.schema(metadata, df.columns)
    names = tuple(tables.resolve_axes(sch, df.columns, axes))
    data = tables.prepare(df, names)
    plot_axes = tuple(a for a in names if data[a].nunique(dropna=False) > 1)
    return Summary(sch, names, plot_axes, data, tables.summarize(df, metadata, list(names)))


def summary_for(df: pd.DataFrame, metadata: Mapping[str, Any] | tables.Schema,
                axes: str | Sequence[str] | None = None, summary: Summary | None = None) -> Summary:
    """``summary`` when given (and built for ``axes``, when those are given), else
    :func:`summarize_dataset` of ``df``: how a function that may be handed the page's summary gets one."""
    wanted = None if axes is None else ([axes] if isinstance(axes, str) else list(axes))
    if summary is not None and (wanted is None or wanted == list(summary.axes)):
        return summary
    return summarize_dataset(df, metadata, axes)
