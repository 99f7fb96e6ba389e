"""``mcjax report`` of a league folder (``mcjax league``): the league table first, as text (the command's own
table) and as one HTML page, ``OUT/report/index.html``, that leads with it — per scenario x fault point the
filters by rank, the best of each column marked. No JAX."""

from __future__ import annotations

import html
from pathlib import Path

from mcjax.base.files import atomic_write
from mcjax.league.folder import read_league
from mcjax.league.table import display_table, league_text
from mcjax.report import html_page


def report_league(out: Path, fmt: str = "text", *, plots: bool = True) -> tuple[str, list[Path]]:
    """``(the league table as text, [the page])`` of the league folder ``out``; ValueError naming the file when
    the league has not finished."""
    try:
        table, meta = read_league(out)
    except FileNotFoundError as exc:
        raise ValueError(str(exc)) from None
    text = league_text(table, meta, fmt)
    if not plots:
        return text, []
    shown = display_table(table)
    rows = [[str(v) for v in row] for row in shown.itertuples(index=False)]
    title = meta.get("title", "league")
    body = [html_page.head(f"mcjax report — league: {title}"),
            f"<h1>{html.escape(str(title))}</h1>",
            "<p>Per scenario and fault point, the filters by rank: rank 1 is the lowest mean error, and a filter "
            "whose 95 % interval of its difference to the best, paired by seed, contains zero shares its rank. "
            "<code>*</code> marks the best of each column in a cell.</p>",
            f"<pre>{html.escape(league_text(table, meta, 'text').split(chr(10) + chr(10))[0])}</pre>",
            html_page.html_table(list(shown.columns), rows, numbers=True), html_page.FOOT]
    page = out / "report" / "index.html"
    page.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(page, "\n".join(body))
    return text, [page]
