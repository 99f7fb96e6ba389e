"""`mcjax report` of a check folder (issue 61, item 3): a page, OUT/report/index.html, whose first table is
the verdicts (each claim's whole text, its statistic, runs and runs to decide), with the forest plot whose
intervals are claims.parquet's own numbers, and links to each sweep's report; reporting changes no file
of the check. The check is the tiny one of tests/claims/test_claims.py (4 runs per point, 12 steps)."""

from __future__ import annotations

import base64
import hashlib
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from tests.claims.test_claims import CLAIMS, write
from tests.report.test_html_page import parse
from tests.report.test_plots import check_png

from mcjax.claims.folder import claim_tables, read_verdicts
from mcjax.claims.report import claim_units
from mcjax.claims.runner import run_check
from mcjax.cli import main
from mcjax.report.plots.forest import VERDICT_COLORS, claim_marks, forest_figure

MORE = """
[[claim]]
id = "kcf-near-the-paper"
claim = "the consensus filter's mean wind error is about the paper's"
where = "Table 1"
paper = 0.951
output = "wind_mean_x"
filter = "kcf"
at = { comm_radius = 100000.0 }
relation = "within"
band = [0.5, 1.5]

[[claim]]
id = "kcf-than-local"
claim = "the consensus filter's intervals lie below the local filter's"
output = "wind_mean_x"
filter = "kcf"
at = { comm_radius = 100000.0 }
relation = "below"
than = { filter = "local" }
"""


def _digest(out: Path) -> dict[str, str]:
    return {str(p.relative_to(out)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(out.rglob("*")) if p.is_file() and "report" not in p.relative_to(out).parts}


def _span(fig, gid: str) -> tuple[float, float]:
    """The x extent of the shaded span ``gid`` (a Rectangle in data x since matplotlib 3.9, else a Polygon)."""
    (patch,) = [p for ax in fig.axes for p in ax.patches if p.get_gid() == gid]
    if hasattr(patch, "get_width"):
        return patch.get_x(), patch.get_x() + patch.get_width()
    xs = np.asarray(patch.get_xy())[:, 0]
    return float(xs.min()), float(xs.max())


@pytest.fixture(scope="module")
def reported(tmp_path_factory):
    """A check of five claims (below a value, equal, ordered, within a band with the paper's number,
    below another side), then `mcjax report` of its folder."""
    root = tmp_path_factory.mktemp("claims_page")
    out = root / "check"
    run_check(write(root, CLAIMS + MORE), out_dir=out)
    before = _digest(out)
    r = CliRunner().invoke(main, ["report", str(out)])
    assert r.exit_code == 0, r.output
    return out, r.output, before


@pytest.mark.xdist_group("test_claims_page")  # one worker runs the module's check once
def test_the_check_folders_page_leads_with_the_verdicts(reported):
    out, printed, before = reported
    table, _ = read_verdicts(out)
    page_path = out / "report" / "index.html"
    assert printed.splitlines()[-1] == f"page: {page_path}"  # the verdicts' page last, after each sweep's
    assert f"page: {out / 's' / 'report' / 'index.html'}" in printed
    assert f"plot: {out / 'report' / 'forest.png'}" in printed
    page = parse(page_path)
    first = page.tables[0]
    assert first[0] == ["claim", "where", "paper", "statistic", "ours [95 %]", "ours at the family's level", "runs",
                        "verdict", "runs to decide", "per claim"]
    rows = first[1:]
    assert [r[0] for r in rows] == [f"{i}: {c}" for i, c in zip(table["id"], table["claim"])]  # whole text
    assert [r[3] for r in rows] == [f"{s}; {x}" for s, x in zip(table["statistic"], table["relation"])]
    assert [r[6] for r in rows] == [str(n) for n in table["runs"]]
    assert [r[7] for r in rows] == list(table["family_verdict"]) and [r[9].split(" (")[0] for r in rows] == list(
        table["verdict"])
    assert [r[8] for r in rows] == [f"~{n:,}" if v == "undecided" and n >= 0 else "—"
                                    for v, n in zip(table["family_verdict"], table["family_runs_to_decide"])]
    assert rows[0][4] == f"{table['ours'][0]} m/s" and rows[3][2] == "0.951 m/s"  # units on the numbers
    html = page_path.read_text(encoding="utf-8")
    legend = re.sub(r"<[^>]+>", "", html.split('<ul class="legend">', 1)[1].split("</ul>", 1)[0])
    assert html.index('<ul class="legend">') < html.index("<table")  # the legend, then the verdicts
    for word in ("holds:", "fails:", "undecided:", "undecided (~N runs):", "family-wise level", "per claim:"):
        assert word in legend, word
    (figure,) = page.figures
    forest = out / "report" / "forest.png"
    check_png(forest)
    assert base64.b64decode(figure["img"]["src"].split(",", 1)[1]) == forest.read_bytes()
    links = [a["href"] for t, a in page.tags if t == "a" and "href" in a]
    assert "../s/report/index.html" in links and (page_path.parent / "../s/report/index.html").resolve().is_file()
    assert not {t for t, _ in page.tags} & {"script", "link", "iframe"}
    assert _digest(out) == before  # no run, no claims.parquet, no check.json touched


@pytest.mark.xdist_group("test_claims_page")
def test_the_forest_plots_intervals_are_claims_parquets(reported):
    out, _, _ = reported
    table, _ = read_verdicts(out)
    fig, caption = forest_figure(claim_marks(table, claim_tables(out), claim_units(table, out)))
    drawn = {ln.get_gid(): ln for ax in fig.axes for ln in ax.get_lines() if ln.get_gid()}
    assert len(fig.axes) == len(table)
    for row in table.to_dict("records"):
        cid, ests = row["id"], json.loads(row["estimates"])
        if len(ests) == 1:  # the family's interval the verdict is read from, and the claim's own 95 %
            assert list(drawn[f"family:{cid}:0"].get_xdata()) == [row["family_low"], row["family_high"]]
            assert list(drawn[f"claim:{cid}:0"].get_xdata()) == [row["low"], row["high"]]
            assert list(drawn[f"estimate:{cid}:0"].get_xdata()) == [row["value"]] * 2
        else:  # one row per statistic: its estimate's interval, and the family's as family_ours writes it
            found = re.findall(r"\[(\S+), (\S+)\]", row["family_ours"])
            for i, e in enumerate(ests):
                assert list(drawn[f"claim:{cid}:{i}"].get_xdata()) == [e["low"], e["high"]]
                assert list(drawn[f"family:{cid}:{i}"].get_xdata()) == pytest.approx(
                    [float(x) for x in found[i]], rel=5e-3)
        assert drawn[f"family:{cid}:0"].get_color() == VERDICT_COLORS[row["family_verdict"]]
        assert drawn[f"claim:{cid}:0"].get_color() == VERDICT_COLORS[row["verdict"]]
    assert list(drawn["value:kcf-below-local"].get_xdata()) == [0.0, 0.0]  # the claimed value
    assert list(drawn["paper:kcf-near-the-paper"].get_xdata()) == [0.951]  # the paper's number
    assert _span(fig, "band:kcf-near-the-paper") == pytest.approx((0.5, 1.5), abs=1e-15)  # the claimed band
    low, high = _span(fig, "band:radius-does-not-help-local")  # equal: value ± tolerance
    assert math.isclose(high - low, 2e-9, rel_tol=1e-6) and abs(low + high) < 1e-15
    assert "family-wise level" in caption and "95 %" in caption
