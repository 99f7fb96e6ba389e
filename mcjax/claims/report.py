"""The report of a check folder: the verdict table first (claim, where, the paper's figure, ours
with its 95 % interval, verdict), then each sweep's own report and figures.

No JAX.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable

import pandas as pd

from mcjax.analysis import tables
from mcjax.claims.folder import read_verdicts

VERDICT_ORDER = ("holds", "fails", "undecided")


def display_table(table: pd.DataFrame) -> pd.DataFrame:
    """The verdict table as a reader sees it: claim, where, paper, ours [95 %], verdict (an
    undecided one with roughly the runs per point that would decide it)."""
    verdict = [v if v != "undecided" or n < 0 else f"undecided (~{n:,} runs)"
               for v, n in zip(table["verdict"], table["runs_to_decide"])]
    return pd.DataFrame({"claim": [f"{i}: {c}" for i, c in zip(table["id"], table["claim"])],
                         "where": table["where"], "paper": table["paper"],
                         "ours [95 %]": table["ours"], "runs": table["runs"], "verdict": verdict})


def _shown(path: str) -> str:
    """A path as the reader typed it, near enough: relative to the current folder when inside it."""
    try:
        return os.path.relpath(path) if not os.path.relpath(path).startswith("..") else path
    except ValueError:  # another drive (Windows)
        return path


def verdict_text(table: pd.DataFrame, meta: dict, fmt: str = "text") -> str:
    """The verdict table with its header lines (paper, counts, what each statistic is)."""
    tables.check_format(fmt)
    if fmt == "csv":
        return table.to_csv(index=False)
    counts = table["verdict"].value_counts()
    header = [f"{meta.get('paper', 'claims')}: {len(table)} claim(s) — "
              + ", ".join(f"{int(counts.get(v, 0))} {v}" for v in VERDICT_ORDER),
              f"claims file: {_shown(meta.get('claims_file', '?'))}; runs per point: "
              + ", ".join(f"{k} {v}" for k, v in (meta.get("seeds") or {}).items()),
              "ours: the statistic with its 95 % interval (mean and paired difference: Student-t; rate: Wilson; "
              "median and quantile: order statistics); holds / fails: the interval lies on the claimed / the "
              "other side; an order holds when neighbouring intervals are apart"]
    lines = tables.format_table(display_table(table), fmt, header)
    if fmt == "text":  # what each claim's statistic is, below the table
        lines += "\n" + "\n".join(f"  {i}: {s}; {r}" for i, s, r in
                                  zip(table["id"], table["statistic"], table["relation"])) + "\n"
    return lines


def report_check(folder: str | os.PathLike, fmt: str = "text", *, plots: bool = True,
                 warn: Callable[[str], None] | None = None,
                 sweep_report: Callable | None = None) -> tuple[str, list[Path]]:
    """``(verdict text, files)``: the verdict table of the check in ``folder``, then (``plots``)
    each sweep folder's report files, drawn by ``sweep_report(folder, fmt, plots=..., warn=...)``
    (:func:`mcjax.report.report`)."""
    table, meta = read_verdicts(folder)
    text = verdict_text(table, meta, fmt)
    files: list[Path] = []
    if plots and sweep_report is not None:
        for sub in sorted(p for p in Path(folder).iterdir() if p.is_dir() and (p / "runs").is_dir()):
            files += sweep_report(sub, fmt, plots=True, warn=warn)[1]
    return text, files
