"""The report of a check folder: the verdict table first (claim, where, the paper's figure, ours
with its 95 % interval, the verdict at the file's family-wise level and each claim's alone; with a
replication, each seed range's verdict and a mark where they differ), then each sweep's own report
and figures.

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
#: The mark of a claim whose seed ranges do not give the same verdict.
NOT_REPLICATED = "†"


def _verdicts(table: pd.DataFrame, column: str, runs: str) -> list[str]:
    return [v if v != "undecided" or n < 0 else f"undecided (~{n:,} runs)" for v, n in zip(table[column], table[runs])]


def _family(table: pd.DataFrame, per_claim: bool) -> bool:
    """Whether the table is shown at its family's level (a table from before it had one: never)."""
    return not per_claim and "family_verdict" in table


def display_table(table: pd.DataFrame, per_claim: bool = False) -> pd.DataFrame:
    """The verdict table as a reader sees it: claim, where, paper, ours [95 %], runs, verdict (at
    the family's level; an undecided one with roughly the runs per point that would decide it at
    that level) and the claim's verdict alone (``per claim``); with a replication, each range's
    verdict (``ranges``) and :data:`NOT_REPLICATED` beside a verdict they do not all give.
    ``per_claim``: the verdict column is the claim's alone (the table before families)."""
    family = _family(table, per_claim)
    verdict = _verdicts(table, "family_verdict", "family_runs_to_decide") if family else \
        _verdicts(table, "verdict", "runs_to_decide")
    suffix = "" if family else "_per_claim"
    replicated = f"replicates{suffix}" in table
    if replicated:
        verdict = [v if same else f"{v} {NOT_REPLICATED}" for v, same in zip(verdict, table[f"replicates{suffix}"])]
    shown = {"claim": [f"{i}: {c}" for i, c in zip(table["id"], table["claim"])],
             "where": table["where"], "paper": table["paper"],
             "ours [95 %]": table["ours"], "runs": table["runs"], "verdict": verdict}
    if family:
        shown["per claim"] = _verdicts(table, "verdict", "runs_to_decide")
    if replicated:
        shown["ranges"] = table[f"range_verdicts{suffix}"]
    return pd.DataFrame(shown)


def _percent(x: float) -> str:
    return f"{100 * x:.2f}"


def family_legend(table: pd.DataFrame, meta: dict, per_claim: bool = False) -> list[str]:
    """The header lines that say at which level the verdicts are stated (and, with a replication,
    what the ranges are)."""
    m = len(table)
    chance = f"{100 * (1 - 0.95 ** m):.0f} %"
    alone = (f"if every claim sat on its boundary, per-claim verdicts would be wrong somewhere with chance "
             f"about 1 − 0.95^{m} = {chance}")
    lines = []
    if _family(table, per_claim):
        method, tests = str(table["family"].iloc[0]), int(table["family_tests"].iloc[0])
        low, high = float(table["family_confidence"].min()), float(table["family_confidence"].max())
        levels = f"{_percent(low)} %" if round(low, 6) == round(high, 6) else f"{_percent(low)}–{_percent(high)} %"
        how = "by Holm's 1979 step-down" if method == "holm" else "by Bonferroni: simultaneous intervals"
        lines.append(f"verdict: at the family-wise level — the file's {m} claim(s) are one family, their {tests} "
                     f"one-sided tests held to a family-wise error of 5 % ({how}): each claim judged on its "
                     f"intervals at {levels} confidence, its runs to decide at that level (docs/claims.md); "
                     f"per claim: its own 95 % interval alone ({alone})")
    else:
        lines.append(f"verdict: per claim, each from its own 95 % interval alone, with no family-wise level ({alone})"
                     + ("; without --per-claim the file's verdicts are held to a family-wise error of 5 %"
                        if "family_verdict" in table else ""))
    if "replicates" in table:
        ranges = meta.get("ranges") or []
        starts = "; ".join(f"range {r}: base seed {', '.join(sorted(set(map(str, b.values()))))}"
                           for r, b in enumerate(ranges))
        lines.append(f"ranges: the verdict on each of {len(ranges) or 'the'} disjoint seed ranges ({starts}), the "
                     f"table's from range 0; {NOT_REPLICATED}: the ranges do not all give it (the claim does not "
                     f"replicate)")
    return lines


def _shown(path: str) -> str:
    """A path as the reader typed it, near enough: relative to the current folder when inside it."""
    try:
        return os.path.relpath(path) if not os.path.relpath(path).startswith("..") else path
    except ValueError:  # another drive (Windows)
        return path


def verdict_text(table: pd.DataFrame, meta: dict, fmt: str = "text", per_claim: bool = False) -> str:
    """The verdict table with its header lines (paper, counts, what each statistic is, the level
    the verdicts are stated at); ``per_claim``: the verdict column is each claim's alone."""
    tables.check_format(fmt)
    if fmt == "csv":
        return table.to_csv(index=False)
    family = _family(table, per_claim)
    counts = table["family_verdict" if family else "verdict"].value_counts()
    bases = meta.get("base_seeds") or {}
    seeds_from = "" if not any(bases.values()) else "; base seed: " + ", ".join(f"{k} {v}" for k, v in bases.items())
    header = [f"{meta.get('paper', 'claims')}: {len(table)} claim(s) — "
              + ", ".join(f"{int(counts.get(v, 0))} {v}" for v in VERDICT_ORDER)
              + (" at the family-wise level" if family else " (per claim)" if "family_verdict" in table else ""),
              f"claims file: {_shown(meta.get('claims_file', '?'))}; runs per point: "
              + ", ".join(f"{k} {v}" for k, v in (meta.get("seeds") or {}).items()) + seeds_from,
              "ours: the statistic with its 95 % interval (mean and paired difference: Student-t; rate: Wilson; "
              "median and quantile: order statistics); holds / fails: the interval lies on the claimed / the "
              "other side; an order holds when neighbouring intervals are apart",
              *family_legend(table, meta, per_claim)]
    lines = tables.format_table(display_table(table, per_claim), fmt, header)
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
    if plots and sweep_report is not None:  # a replication's: each range's sweeps
        for sub in sorted(p for p in [*Path(folder).iterdir(), *Path(folder).glob("range_*/*")]
                          if p.is_dir() and (p / "runs").is_dir()):
            files += sweep_report(sub, fmt, plots=True, warn=warn)[1]
    return text, files
