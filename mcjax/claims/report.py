"""The report of a check folder: the verdict table first (claim, where, the paper's figure, ours
with its 95 % interval in its output's unit, the verdict at the file's family-wise level and each
claim's alone; with a replication, each seed range's verdict and a mark where they differ), then each
sweep's own report and figures (the page that leads with the verdicts and draws them is
:mod:`mcjax.report.claims_page`'s).

The text table fits a terminal's width (:func:`terminal_width`; ``COLUMNS`` honoured): a claim's
text is shortened with an ellipsis, its id kept, and every other column stays whole; where even
that leaves too little of the text (:data:`MIN_TEXT`), each claim gets a line of its own above its
numbers. Markdown and CSV keep every text whole.

No JAX.
"""

from __future__ import annotations

import math
import os
import textwrap
from pathlib import Path
from typing import Callable

import pandas as pd

from mcjax.analysis import tables
from mcjax.analysis.schema import unit
from mcjax.analysis.tables import terminal_width
from mcjax.base import parquet
from mcjax.claims.folder import claim_tables, read_verdicts, sweep_folder

VERDICT_ORDER = ("holds", "fails", "undecided")
#: The mark of a claim whose seed ranges do not give the same verdict.
NOT_REPLICATED = "†"
#: The verdict words and what each means: the legend of the printed table and of the page.
VERDICT_WORDS = (
    ("holds", "the interval lies entirely on the claimed side (below or above the value, inside the band, "
              "the statistics' intervals apart in the claimed order)"),
    ("fails", "it lies entirely on the other side"),
    ("undecided", "it straddles the boundary (or the statistic has no interval)"),
    ("undecided (~N runs)", "about N runs per point would decide it at its column's level (an interval's "
                            "half-width shrinks as 1/√n)"),
)
#: The fewest characters of a claim's text the one-line table keeps (after its id); with less room
#: each claim gets a line of its own above its numbers.
MIN_TEXT = 40
#: What ends a shortened text.
ELLIPSIS = "…"


def _own_keys(raw: dict) -> dict:
    """The keys of a claim's own statistic: an order's first side over the claim's keys."""
    order = raw.get("order")
    if raw.get("relation") == "ordered" and isinstance(order, list) and order and isinstance(order[0], dict):
        return {**raw, **order[0]}
    return raw


def claim_units(table: pd.DataFrame, folder: str | os.PathLike) -> dict[str, str]:
    """Each claim's unit, by id: its output's declared unit in its sweep's metadata (``""`` for a
    rate, a fraction of runs, and where the folder does not say)."""
    raws, metas, out = claim_tables(folder), {}, {}
    for cid in table["id"]:
        raw = _own_keys(raws.get(cid, {}))
        sweep, output = raw.get("sweep"), raw.get("output")
        if raw.get("statistic") == "rate" or not isinstance(sweep, str) or not isinstance(output, str):
            out[cid] = ""
            continue
        if sweep not in metas:
            try:
                metas[sweep] = parquet.read_metadata(sweep_folder(folder, sweep))
            except (OSError, ValueError, TypeError):
                metas[sweep] = {}
        out[cid] = unit(output, metas[sweep])
    return out


def with_unit(text: str, u: str) -> str:
    """``text`` (a printed statistic) followed by its unit ``u``, when both are there."""
    return f"{text} {u}" if u and text else text


def paper_with_unit(paper, u: str) -> str:
    """A claim's ``paper`` text with the unit ``u`` when it is one finite number ("6.5" → "6.5 m"); a text
    such as "0.95 vs 1.2" or "KCF below KF" as written."""
    try:
        number = math.isfinite(float(paper))
    except (TypeError, ValueError):
        number = False
    return with_unit(paper, u) if number else paper


def _verdicts(table: pd.DataFrame, column: str, runs: str) -> list[str]:
    return [v if v != "undecided" or n < 0 else f"undecided (~{n:,} runs)" for v, n in zip(table[column], table[runs])]


def _family(table: pd.DataFrame, per_claim: bool) -> bool:
    """Whether the table is shown at its family's level (a table from before it had one: never)."""
    return not per_claim and "family_verdict" in table


def display_table(table: pd.DataFrame, per_claim: bool = False, units: dict[str, str] | None = None) -> pd.DataFrame:
    """The verdict table as a reader sees it: claim, where, paper, ours [95 %], runs, verdict (at
    the family's level; an undecided one with roughly the runs per point that would decide it at
    that level) and the claim's verdict alone (``per claim``); with a replication, each range's
    verdict (``ranges``) and :data:`NOT_REPLICATED` beside a verdict they do not all give.
    ``per_claim``: the verdict column is the claim's alone (the table before families). ``units``
    (by id, :func:`claim_units`): written after ours and after a paper's figure that is a number."""
    units = units or {}
    family = _family(table, per_claim)
    verdict = _verdicts(table, "family_verdict", "family_runs_to_decide") if family else \
        _verdicts(table, "verdict", "runs_to_decide")
    suffix = "" if family else "_per_claim"
    replicated = f"replicates{suffix}" in table
    if replicated:
        verdict = [v if same else f"{v} {NOT_REPLICATED}" for v, same in zip(verdict, table[f"replicates{suffix}"])]
    u = [units.get(i, "") for i in table["id"]]
    shown = {"claim": [f"{i}: {c}" for i, c in zip(table["id"], table["claim"])],
             "where": table["where"],
             "paper": [paper_with_unit(p, x) for p, x in zip(table["paper"], u)],
             "ours [95 %]": [with_unit(o, x) for o, x in zip(table["ours"], u)], "runs": table["runs"],
             "verdict": verdict}
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


def verdict_legend() -> str:
    """The line that defines every verdict word (:data:`VERDICT_WORDS`)."""
    return "verdicts: " + "; ".join(f"{w}: {m}" for w, m in VERDICT_WORDS)


def shorten(text: str, room: int, keep: int = 0) -> str:
    """``text`` in ``room`` characters: whole when it fits, else cut (at a space when one is near)
    and ended with :data:`ELLIPSIS`; its first ``keep`` characters (a claim's id) are always kept."""
    if len(text) <= room:
        return text
    cut = max(room - len(ELLIPSIS), keep)
    head = text[:cut]
    space = head.rfind(" ", keep)
    if space > keep and cut - space <= 12:
        head = head[:space]
    return head.rstrip(" ,;:") + ELLIPSIS


def _aligned(headers: list[str], rows: list[list[str]], numeric: list[bool], indent: str = "") -> list[str]:
    widths = [max([len(h), *(len(r[i]) for r in rows)]) for i, h in enumerate(headers)]

    def line(cells: list[str]) -> str:
        return (indent + "  ".join(c.rjust(w) if num else c.ljust(w)
                                   for c, w, num in zip(cells, widths, numeric))).rstrip()

    return [line(headers), *(line(r) for r in rows)]


def fit_table(shown: pd.DataFrame, table: pd.DataFrame, width: int) -> tuple[list[str], bool]:
    """The lines of :func:`display_table`'s ``shown`` (of the verdict ``table``) in ``width``
    columns, and whether a text was shortened. One line per claim, its text shortened (:func:`shorten`,
    its id kept) and every other column whole, when that leaves :data:`MIN_TEXT` characters of
    every text; else two lines per claim: ``id (where): text`` shortened to the width, then the other
    columns indented (the paper's figure, a text of the file, shortened only if they still do not fit)."""
    headers, rows, numeric = tables.format_cells(shown)
    ids = [str(i) for i in table["id"]]
    widths = [max([len(h), *(len(r[i]) for r in rows)]) for i, h in enumerate(headers)]
    room = width - sum(widths[1:]) - 2 * (len(widths) - 1)
    if room >= min(widths[0], max(len(i) for i in ids) + 2 + MIN_TEXT):
        cut = [[shorten(r[0], room, len(i)), *r[1:]] for r, i in zip(rows, ids)]
        return _aligned(headers, cut, numeric), any(a[0] != b[0] for a, b in zip(cut, rows))
    keep = [k for k, h in enumerate(headers) if h not in ("claim", "where")]
    heads, cells, nums = [headers[k] for k in keep], [[r[k] for k in keep] for r in rows], [numeric[k] for k in keep]
    short = False
    if "paper" in heads:
        p = heads.index("paper")
        others = sum(max([len(h), *(len(c[k]) for c in cells)]) for k, h in enumerate(heads) if k != p)
        room = max(len("paper"), width - 2 - others - 2 * (len(heads) - 1))
        for c in cells:
            short |= len(c[p]) > room
            c[p] = shorten(c[p], room)
    numbers = _aligned(heads, cells, nums, indent="  ")
    lines = ["claim (where): text", numbers[0]]
    for cid, where, text, row in zip(ids, table["where"], table["claim"], numbers[1:]):
        whole = f"{cid} ({where}): {text}" if where else f"{cid}: {text}"
        lines += [shorten(whole, width, len(cid)).rstrip(), row]
        short |= len(whole) > width
    return lines, short


def _wrapped(lines: list[str], width: int | None, first: str = "", then: str = "  ") -> list[str]:
    if width is None:
        return [first + line for line in lines]
    return [w for line in lines for w in textwrap.wrap(line, width, initial_indent=first, subsequent_indent=then,
                                                       break_long_words=False, break_on_hyphens=False) or [""]]


def verdict_text(table: pd.DataFrame, meta: dict, fmt: str = "text", per_claim: bool = False, *,
                 units: dict[str, str] | None = None, width: int | None = None) -> str:
    """The verdict table with its header lines (paper, counts, what each statistic is, what each
    verdict word means, the level the verdicts are stated at); ``per_claim``: the verdict column is
    each claim's alone; ``units``: each claim's unit, by id (:func:`claim_units`). ``width`` (text
    only): the table and its lines fit that many columns (:func:`fit_table`; None: whole)."""
    tables.check_format(fmt)
    if fmt == "csv":
        return table.to_csv(index=False)
    family = _family(table, per_claim)
    counts = table["family_verdict" if family else "verdict"].value_counts()
    bases = meta.get("base_seeds") or {}
    seeds_from = "" if not any(bases.values()) else "; base seed: " + ", ".join(f"{k} {v}" for k, v in bases.items())
    shown = display_table(table, per_claim, units)
    body, short = (fit_table(shown, table, width) if fmt == "text" and width else (None, False))
    header = [f"{meta.get('paper', 'claims')}: {len(table)} claim(s) — "
              + ", ".join(f"{int(counts.get(v, 0))} {v}" for v in VERDICT_ORDER)
              + (" at the family-wise level" if family else " (per claim)" if "family_verdict" in table else ""),
              f"claims file: {_shown(meta.get('claims_file', '?'))}; runs per point: "
              + ", ".join(f"{k} {v}" for k, v in (meta.get("seeds") or {}).items()) + seeds_from,
              "ours: the statistic with its 95 % interval (mean and paired difference: Student-t; rate: Wilson; "
              "median and quantile: order statistics), in its output's unit (a rate: a fraction of runs); runs: "
              "the runs it rests on",
              verdict_legend(),
              *family_legend(table, meta, per_claim)]
    if short:
        header.append(f"claim: shortened ({ELLIPSIS}) to the terminal's {width} columns, its id kept; the whole text: "
                      f"--format markdown or csv, or the page `mcjax report` writes of the check folder")
    if fmt == "markdown":
        return tables.format_table(shown, fmt, header)
    text = "\n".join([*_wrapped(header, width), ""]) + "\n"
    text += "\n".join(body if body is not None else tables.format_table(shown, "text").splitlines()) + "\n"
    # what each claim's statistic is, below the table
    notes = [f"{i}: {s}; {r}" for i, s, r in zip(table["id"], table["statistic"], table["relation"])]
    return text + "\n" + "\n".join(_wrapped(notes, width, "  ", "      ")) + "\n"


def report_check(folder: str | os.PathLike, fmt: str = "text", *, plots: bool = True,
                 warn: Callable[[str], None] | None = None,
                 sweep_report: Callable | None = None, width: int | None = None) -> tuple[str, list[Path]]:
    """``(verdict text, files)``: the verdict table of the check in ``folder`` (text: in ``width``
    columns, else the terminal's, :func:`terminal_width`), then (``plots``) each sweep folder's
    report files, drawn by ``sweep_report(folder, fmt, plots=..., warn=...)``
    (:func:`mcjax.report.report`)."""
    table, meta = read_verdicts(folder)
    text = verdict_text(table, meta, fmt, units=claim_units(table, folder),
                        width=(width or terminal_width()) if fmt == "text" else None)
    files: list[Path] = []
    if plots and sweep_report is not None:  # a replication's: each range's sweeps
        for sub in sweep_folders(folder):
            files += sweep_report(sub, fmt, plots=True, warn=warn)[1]
    return text, files


def sweep_folders(folder: str | os.PathLike) -> list[Path]:
    """The sweep folders of a check (a replication's: each range's), sorted."""
    return sorted(p for p in [*Path(folder).iterdir(), *Path(folder).glob("range_*/*")]
                  if p.is_dir() and (p / "runs").is_dir())
