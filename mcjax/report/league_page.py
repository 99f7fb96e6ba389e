"""``mcjax report`` of a league folder (``mcjax league``): the league table first, as text (the command's own
table) and as one HTML page, ``OUT/report/index.html``, that leads with it — per scenario x fault point the
filters by rank, the best of each column marked — with its legend (every word and mark of the table, the
cost's method and machine; wrapped, not in a box), a link to each cell's sweep (its own report where
``mcjax report OUT/<scenario>/<point>`` wrote one, else its folder) and the league's provenance (the league
file, runs, git revision, package versions, dates). Self-contained, as every report page. No JAX."""

from __future__ import annotations

import html
import os
from datetime import datetime
from pathlib import Path
from typing import Any, Mapping

import pandas as pd

from mcjax.analysis.tables import terminal_width
from mcjax.base.files import atomic_write
from mcjax.league.folder import read_league
from mcjax.league.table import display_table, legend, league_text
from mcjax.report import html_page

#: Provenance keys of ``league.parquet``'s metadata, in the order shown, with their labels.
PROVENANCE = (("created_utc", "league table written (UTC)"), ("git_revision", "git revision of mcjax"),
              ("git_dirty", "uncommitted changes in the mcjax checkout"), ("mcjax", "mcjax"), ("python", "Python"),
              ("jax", "jax"), ("jaxlib", "jaxlib"), ("numpy", "numpy"), ("pandas", "pandas"), ("pyarrow", "pyarrow"))


def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


def _sweeps(out: Path, table: pd.DataFrame) -> str:
    """A list of each cell's sweep: its report when there is one, else its folder, with its filters."""
    items = []
    for (scenario, point), cell in table.groupby(["scenario", "point"], sort=False):
        folder = out / str(scenario) / str(point)
        ran = ", ".join(cell.loc[cell["status"] == "run", "filter"])
        page = folder / "report" / html_page.PAGE_NAME
        target = page if page.is_file() else folder
        href = os.path.relpath(target, out / "report").replace(os.sep, "/") + ("" if page.is_file() else "/")
        what = "its report" if page.is_file() else (f"its folder (<code>mcjax report {_e(folder)}</code> writes its "
                                                    "report)")
        items.append(f'<li><a href="{_e(href)}">{_e(scenario)} / {_e(point)}</a> — {what}; filters run: '
                     f"{_e(ran or 'none')}</li>")
    return "<ul>" + "".join(items) + "</ul>"


def page(out: Path, table: pd.DataFrame, meta: Mapping[str, Any], now: datetime | None = None) -> str:
    """The HTML text of the league folder ``out``'s page (module docstring)."""
    shown = display_table(table)
    rows = [[str(v) for v in row] for row in shown.itertuples(index=False)]
    title = meta.get("title", "league")
    lines = legend(table, meta)
    parts = [html_page.head(f"mcjax report — league: {title}"), f"<h1>mcjax report — league: {_e(title)}</h1>",
             f'<p class="subtitle">{_e(lines[0])}</p>',
             '<section id="league" class="findings"><h2>The league table</h2>',
             "<p>Per scenario and fault point, the filters by rank: rank 1 is the lowest mean error, and a filter "
             "whose 95 % interval of its difference to the rank's leader, paired by seed, contains zero shares its "
             "rank. What each column, word and mark means:</p>",
             '<ul class="legend">' + "".join(f"<li>{_e(line)}</li>" for line in lines[1:]) + "</ul>",
             html_page.html_table(list(shown.columns), rows, numbers=True),
             '<p class="note">Read from <code>league.parquet</code> in the league folder; <code>mcjax report OUT '
             "--format csv</code> gives every column (the intervals' ends, the paired difference to the leader, "
             "the costs in seconds).</p></section>",
             '<section id="sweeps"><h2>Each cell\'s sweep</h2>' + _sweeps(out, table) + "</section>"]
    info = [["league file", str(meta.get("league_file", "?"))], ["runs per cell", str(meta.get("seeds", "?"))],
            ["fault points", ", ".join(f"{k} ({v})" if v != k else k for k, v in (meta.get("points") or {}).items())
             or "?"],
            ["cost measured on", str(meta.get("machine") or "not timed (timing_runs = 0)")]]
    parts.append(html_page.provenance_section(info, meta, PROVENANCE, now))
    parts.append(html_page.FOOT)
    return "\n".join(parts)


def report_league(out: Path, fmt: str = "text", *, plots: bool = True) -> tuple[str, list[Path]]:
    """``(the league table as text, [the page])`` of the league folder ``out``; ValueError naming the file when
    the league has not finished."""
    try:
        table, meta = read_league(out)
    except FileNotFoundError as exc:
        raise ValueError(str(exc)) from None
    text = league_text(table, meta, fmt, width=terminal_width())
    if not plots:
        return text, []
    written = out / "report" / html_page.PAGE_NAME
    written.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(written, page(Path(out), table, meta))
    return text, [written]
