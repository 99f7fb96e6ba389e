"""``mcjax report`` of a check folder (``mcjax check``): the verdict table as text (the command's own,
:func:`mcjax.claims.report.verdict_text`), each sweep's own report, and one page,
``OUT/report/index.html``, that leads with the verdicts: what each verdict word means, the verdict
table (each claim's whole text, where, the paper's figure, its statistic and relation, ours with its
95 % interval and at the family's level, in its output's unit, the runs, the verdict, the runs to
decide it and the verdict alone), then the forest plot (:mod:`mcjax.report.plots.forest`), links to
each sweep's report and the check's provenance. Self-contained, as every report page
(:mod:`mcjax.report.html_page`'s head, style and embedded images). No JAX.
"""

from __future__ import annotations

import html
import os
from datetime import datetime
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import pandas as pd

from mcjax.base.files import atomic_write
from mcjax.claims.folder import claim_tables, read_verdicts
from mcjax.claims.report import (NOT_REPLICATED, VERDICT_ORDER, VERDICT_WORDS, claim_units, family_legend,
                                 paper_with_unit, report_check, sweep_folders, with_unit)
from mcjax.report import html_page

__all__ = ["PAGE_NAME", "verdict_rows", "page", "report_check_folder"]

#: The page's file name inside ``OUT/report/``.
PAGE_NAME = html_page.PAGE_NAME
#: Provenance keys of ``claims.parquet``'s metadata, in the order shown, with their labels.
PROVENANCE = (("created_utc", "verdicts written (UTC)"), ("git_revision", "git revision of mcjax"),
              ("git_dirty", "uncommitted changes in the mcjax checkout"), ("mcjax", "mcjax"), ("python", "Python"),
              ("jax", "jax"), ("numpy", "numpy"), ("pandas", "pandas"))


def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


def verdict_rows(table: pd.DataFrame, units: Mapping[str, str] | None = None) -> pd.DataFrame:
    """The page's verdict table, every text whole: claim (``id: text``), where, paper, statistic
    (and the relation it is judged by), ours [95 %] and (with a family) ours at the family's level
    with its confidence, runs, verdict (:data:`~mcjax.claims.report.NOT_REPLICATED` where the seed
    ranges differ), runs to decide (``~N``, or ``—`` once decided), per claim (the verdict alone)
    and, with a replication, each range's verdicts."""
    units = units or {}
    family = "family_verdict" in table
    u = [units.get(i, "") for i in table["id"]]
    paper = [paper_with_unit(p, x) for p, x in zip(table["paper"], u)]
    out = {"claim": [f"{i}: {c}" for i, c in zip(table["id"], table["claim"])], "where": table["where"],
           "paper": paper, "statistic": [f"{s}; {r}" for s, r in zip(table["statistic"], table["relation"])],
           "ours [95 %]": [with_unit(o, x) for o, x in zip(table["ours"], u)]}
    if family:
        out["ours at the family's level"] = [f"{with_unit(o, x)} ({100 * c:.2f} %)" for o, x, c in
                                             zip(table["family_ours"], u, table["family_confidence"])]
    out["runs"] = [f"{int(n):,}" for n in table["runs"]]
    verdict, runs = ("family_verdict", "family_runs_to_decide") if family else ("verdict", "runs_to_decide")
    marks = table["replicates"] if "replicates" in table else [True] * len(table)
    out["verdict"] = [v if same else f"{v} {NOT_REPLICATED}" for v, same in zip(table[verdict], marks)]
    out["runs to decide"] = [f"~{int(n):,}" if v == "undecided" and n >= 0 else "—"
                             for v, n in zip(table[verdict], table[runs])]
    if family:
        out["per claim"] = [f"{v} (~{int(n):,} runs)" if v == "undecided" and n >= 0 else v
                            for v, n in zip(table["verdict"], table["runs_to_decide"])]
    if "range_verdicts" in table:
        out["ranges"] = table["range_verdicts"]
    return pd.DataFrame(out)


def _png_width(path: Path) -> int | None:
    head = Path(path).read_bytes()[:24]
    return int.from_bytes(head[16:20], "big") if head[:8] == b"\x89PNG\r\n\x1a\n" else None


def _links(out: Path, pages: Sequence[Path]) -> str:
    if not pages:
        return "<p>(No sweep report: run <code>mcjax report</code> without <code>--no-plots</code>.)</p>"
    items = []
    for p in pages:
        sweep = p.parent.parent.relative_to(out).as_posix()
        href = os.path.relpath(p, out / "report").replace(os.sep, "/")
        items.append(f'<li><a href="{_e(href)}">{_e(sweep)}</a> — its findings, figures and tables</li>')
    return "<ul>" + "".join(items) + "</ul>"


def page(out_dir: str | os.PathLike, table: pd.DataFrame, meta: Mapping[str, Any], units: Mapping[str, str],
         forest: Any | None, sweep_pages: Sequence[Path] = (), now: datetime | None = None) -> str:
    """The HTML text of the check folder's page (module docstring): the verdict table is its first
    table. ``forest``: the written forest plot (``.path``, ``.caption``) or None; ``sweep_pages``:
    each sweep's ``report/index.html``, linked."""
    out = Path(out_dir)
    family = "family_verdict" in table
    counts = table["family_verdict" if family else "verdict"].value_counts()
    paper = str(meta.get("paper", "claims"))
    parts = [html_page.head(f"mcjax report — check: {paper}"), f"<h1>mcjax report — check: {_e(paper)}</h1>"]
    if meta.get("title"):
        parts.append(f'<p class="subtitle">{_e(meta["title"])}</p>')
    seeds = ", ".join(f"{k} {v}" for k, v in (meta.get("seeds") or {}).items())
    parts.append('<section id="verdicts" class="findings"><h2>Verdicts</h2>')
    parts.append(f"<p>{len(table)} claim(s): " + ", ".join(f"<strong>{int(counts.get(v, 0))} {v}</strong>"
                                                           for v in VERDICT_ORDER)
                 + (" at the family-wise level" if family else "") + f"; runs per point: {_e(seeds or '?')}; "
                 f"claims file: <code>{_e(meta.get('claims_file', '?'))}</code>.</p>")
    legend = [f"<strong>{_e(w)}</strong>: {_e(m)}" for w, m in VERDICT_WORDS]
    legend += [_e(line) for line in family_legend(table, dict(meta))]
    legend += [_e("ours [95 %]: the statistic with its 95 % interval (mean and paired difference: Student-t; rate: "
                  "Wilson; median and quantile: order statistics) in its output's unit (a rate: a fraction of runs)"
                  + ("; ours at the family's level: the same at the confidence its verdict was reached at" if family
                     else "") + "; runs: the runs it rests on; runs to decide: about how many runs per point would "
                  "decide an undecided claim at the verdict's level")]
    parts.append('<ul class="legend">' + "".join(f"<li>{x}</li>" for x in legend) + "</ul>")
    shown = verdict_rows(table, units)
    parts.append(html_page.html_table(list(shown.columns), [[str(v) for v in r] for r in
                                                             shown.itertuples(index=False)]))
    parts.append('<p class="note">Read from <code>claims.parquet</code> in the check folder; '
                 "<code>mcjax report OUT --format csv</code> gives every column.</p></section>")
    parts.append('<section id="forest"><h2>Each claim against what it is compared with</h2>')
    if forest is not None:
        width = _png_width(forest.path)
        size = f' width="{(width + 1) // 2}"' if width else ""
        parts.append(f'<figure id="forest-plot"><img src="{html_page.image(forest.path)}" alt="Each claim\'s '
                     f'estimate and intervals against its claimed value, band or the paper\'s number."{size} '
                     f'style="max-width:100%;height:auto"><figcaption><strong>{_e(forest.path.name)}</strong> — '
                     f"{_e(forest.caption)}</figcaption></figure>")
    parts.append("</section>")
    parts.append('<section id="sweeps"><h2>Each sweep\'s report</h2>' + _links(out, sweep_pages) + "</section>")
    rows = [["claims file", str(meta.get("claims_file", "?"))], ["runs per point", seeds or "?"]]
    if meta.get("base_seed") is not None:
        rows.append(["base seed (--base-seed)", str(meta["base_seed"])])
    if meta.get("replicate"):
        rows.append(["seed ranges (--replicate)", str(meta["replicate"])])
    parts.append(html_page.provenance_section(rows, meta, PROVENANCE, now))
    parts.append(html_page.FOOT)
    return "\n".join(parts)


def report_check_folder(out_dir: str | os.PathLike, fmt: str = "text", *, plots: bool = True,
                        warn: Callable[[str], None] | None = None,
                        sweep_report: Callable | None = None) -> tuple[str, list[Path]]:
    """``(verdict text, files)`` of the check folder ``out_dir``: the text and each sweep's report
    files (:func:`mcjax.claims.report.report_check`), then (``plots``) the forest plot and the page,
    ``OUT/report/index.html``, last."""
    from mcjax.report.plots.forest import claim_marks, write_forest  # matplotlib only when plotting

    out = Path(out_dir)
    text, files = report_check(out, fmt, plots=plots, warn=warn, sweep_report=sweep_report)
    if not plots:
        return text, files
    table, meta = read_verdicts(out)
    units = claim_units(table, out)
    forest = write_forest(claim_marks(table, claim_tables(out), units), out)
    pages = [p / "report" / PAGE_NAME for p in sweep_folders(out) if (p / "report" / PAGE_NAME).is_file()]
    path = atomic_write(out / "report" / PAGE_NAME, page(out, table, meta, units, forest, pages))
    return text, [*files, forest.path, path]
