"""The printed verdict table fits the terminal (issue 61, item 4): `mcjax check` and `mcjax report` of a
check folder print it in the terminal's width (COLUMNS honoured), each claim's text shortened with an
ellipsis and its id kept, every number and verdict whole, with units on the numbers and a legend of every
verdict word; markdown and CSV keep the whole text; a pipe without COLUMNS gets the whole table."""

from __future__ import annotations

import io
import os
import shutil
from pathlib import Path

import pandas as pd
import pytest
from click.testing import CliRunner

from mcjax.claims.folder import read_verdicts
from mcjax.claims.report import (ELLIPSIS, MIN_TEXT, display_table, fit_table, shorten, terminal_width,
                                 verdict_text)
from mcjax.cli import main

ROOT = Path(__file__).resolve().parents[2]
CHEN = ROOT / "benchmarks" / "claims" / "chen2013.toml"


def _table_lines(text: str) -> list[str]:
    """The table (and its notes) of a printed verdict text: what follows the header's blank line."""
    lines = text.splitlines()
    return lines[lines.index("") + 1:]


def _shown(text: str, cid: str, claim: str) -> int:
    """How many characters of the claim's text the line that starts with its id shows."""
    (line,) = [ln for ln in text.splitlines() if ln.startswith(f"{cid} ") or ln.startswith(f"{cid}:")]
    at = line.find(claim[:8], len(cid))
    n = 0
    while at >= 0 and at + n < len(line) and n < len(claim) and line[at + n] == claim[n]:
        n += 1
    return n


@pytest.fixture(scope="module")
def chen(tmp_path_factory):
    """Chen & Lu 2013's claims file at 2 runs per point: its verdicts mostly undecided, so its
    verdict columns at their widest ("undecided (~1,234 runs)")."""
    out = tmp_path_factory.mktemp("chen") / "check"
    r = CliRunner().invoke(main, ["check", str(CHEN), "--seeds", "2", "--out", str(out)], env={"COLUMNS": "100"})
    assert r.exit_code == 0, r.output
    return out, r.output


@pytest.mark.xdist_group("test_verdict_table")  # one worker runs the module's check once
def test_the_check_of_chen2013_fits_100_columns_and_200_show_more_of_each_claim(chen):
    out, printed = chen
    table, _ = read_verdicts(out)
    text = printed.split(f"verdicts: {out}")[0]
    assert max(len(line) for line in text.splitlines()) <= 100, text
    for cid in table["id"]:  # every claim by its whole id, at the start of a line
        assert any(line.startswith(f"{cid} ") or line.startswith(f"{cid}:") for line in text.splitlines()), cid
    assert "m/s" in text and ELLIPSIS in text and "shortened (…) to the terminal's 100 columns" in text
    legend = " ".join(text.split())  # its lines wrapped to the width
    for word in ("holds:", "fails:", "undecided:", "undecided (~N runs):", "family-wise level", "per claim:"):
        assert word in legend, word
    for value in table["ours"]:  # every number whole, with its unit where it has one
        assert value in text
    wide = CliRunner().invoke(main, ["report", str(out), "--no-plots"], env={"COLUMNS": "200"}).output
    assert max(len(line) for line in wide.splitlines()) <= 200
    narrow = [_shown(text, i, c) for i, c in zip(table["id"], table["claim"])]
    more = [_shown(wide, i, c) for i, c in zip(table["id"], table["claim"])]
    assert all(m >= n for m, n in zip(more, narrow)) and sum(more) > sum(narrow) + 20 * len(table), (narrow, more)
    again = CliRunner().invoke(main, ["check", str(CHEN), "--seeds", "2", "--out", str(out), "--resume"],
                               env={"COLUMNS": "200"})
    assert again.exit_code == 0 and max(len(line) for line in again.output.split("verdicts: ")[0].splitlines()) <= 200


@pytest.mark.xdist_group("test_verdict_table")
def test_markdown_csv_and_a_pipe_keep_every_claims_whole_text(chen, monkeypatch):
    out, _ = chen
    # no terminal behind stdout (as under pytest -s in one, it could be): the size is the fallback
    monkeypatch.setattr(shutil, "get_terminal_size", lambda fallback=(80, 24): os.terminal_size(
        (int(os.environ["COLUMNS"]), 24) if os.environ.get("COLUMNS") else fallback))
    table, _ = read_verdicts(out)
    runner = CliRunner()
    md = runner.invoke(main, ["report", str(out), "--format", "markdown", "--no-plots"], env={"COLUMNS": "60"})
    csv = runner.invoke(main, ["report", str(out), "--format", "csv", "--no-plots"], env={"COLUMNS": "60"})
    piped = runner.invoke(main, ["report", str(out), "--no-plots"], env={"COLUMNS": None})
    for text in table["claim"]:
        assert text.replace("|", "\\|") in md.output and text in piped.output
        assert text in csv.output
    assert ELLIPSIS not in md.output and ELLIPSIS not in piped.output
    assert pd.read_csv(io.StringIO(csv.output))["family_low"].tolist() == pytest.approx(
        table["family_low"].tolist(), nan_ok=True)


def test_shorten_keeps_the_id_and_every_other_column_whole():
    assert shorten("abc: a short text", 40, 3) == "abc: a short text"
    cut = shorten("kcf-below-local: consensus beats each UAV's own filter at every radius", 40, 15)
    assert cut.startswith("kcf-below-local: ") and cut.endswith(ELLIPSIS) and len(cut) <= 40
    assert shorten("a-very-long-claim-id: text", 5, 20) == "a-very-long-claim-id" + ELLIPSIS  # the id whole
    table = pd.DataFrame({"id": ["a", "bb"], "claim": ["x " * 60, "y " * 10], "where": ["Fig. 1", "Table 2"],
                          "paper": ["0.5", "text"], "ours": ["1.23 [1.1, 1.4]", "0.2 [0.1, 0.3]"], "runs": [10, 10],
                          "verdict": ["holds", "undecided"], "runs_to_decide": [-1, 1234]})
    shown = display_table(table, units={"a": "m", "bb": "m/s"})
    assert shown["ours [95 %]"].tolist() == ["1.23 [1.1, 1.4] m", "0.2 [0.1, 0.3] m/s"]
    assert shown["paper"].tolist() == ["0.5 m", "text"]  # a paper's number gets the unit, its text does not
    one, short = fit_table(shown, table, 120)  # one line per claim: MIN_TEXT characters of each text fit
    assert short and len(one) == 3 and all(len(line) <= 120 for line in one) and MIN_TEXT == 40
    assert "undecided (~1,234 runs)" in one[2] and "1.23 [1.1, 1.4] m" in one[1]
    narrow = 90  # too narrow for MIN_TEXT characters of a text beside the other columns: two lines per claim
    two, _ = fit_table(shown, table, narrow)
    assert len(two) == 2 + 2 * len(table) and two[2].startswith("a (Fig. 1): x x") and "Fig. 1" not in two[3]
    assert all(len(line) <= narrow for line in two)
    assert "bb (Table 2): y y y" in two[4] and "undecided (~1,234 runs)" in two[5]


def test_the_width_is_the_terminals_columns_honoured_and_none_for_a_pipe(monkeypatch):
    monkeypatch.setenv("COLUMNS", "123")
    assert terminal_width() == 123
    monkeypatch.delenv("COLUMNS")
    monkeypatch.setattr(shutil, "get_terminal_size", lambda fallback=(80, 24): os.terminal_size(fallback))
    assert terminal_width() is None  # not a terminal: the whole table
    table = pd.DataFrame({"id": ["a"], "claim": ["x " * 80], "where": [""], "paper": [""], "ours": ["1 [0, 2]"],
                          "runs": [3], "verdict": ["holds"], "runs_to_decide": [-1], "statistic": ["mean of e"],
                          "relation": ["below 5"]})
    assert ("x " * 80).strip() in verdict_text(table, {})  # no width: nothing shortened
