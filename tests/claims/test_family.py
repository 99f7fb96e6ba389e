"""The family-wise verdicts of a claims file on hand-made runs (no engine): each claim's decision level
is where its own verdict turns, so the interval shown and the verdict agree at every level; Holm's steps
over a family give the verdicts and levels worked out by hand; a file of one claim keeps its 95 %
verdict; the replication columns and the printed table (family level, per claim, ranges)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from mcjax.claims import evaluate
from mcjax.claims.evaluate import COLUMNS, REPLICATE_COLUMNS, Runs
from mcjax.claims.report import NOT_REPLICATED, display_table, verdict_text
from mcjax.claims.spec import Claim, Side

N = 60
RNG = np.random.default_rng(3)
A = RNG.normal(1.0, 1.0, N)
B = A + RNG.normal(0.3, 0.5, N)
C = RNG.exponential(1.0, N) + 0.8
F = (RNG.random(N) < 0.2).astype(float)
AXIS = [0.1, 0.2, 0.3]


def _rows(values: dict) -> dict:
    frames = [pd.DataFrame({"point_id": pid, "seed_index": np.arange(len(x)), "filter": filt, "y": np.asarray(x, float),
                            "axis": AXIS[pid]}) for (pid, filt), x in values.items()]
    return {"s": pd.concat(frames, ignore_index=True)}


ROWS = _rows({(0, "a"): A, (0, "b"): B, (0, "c"): C, (0, "f"): F, (1, "a"): A + 0.4, (2, "a"): A + 0.9})


def side(pid=0, filt="a", statistic="mean", **kw) -> Side:
    return Side("s", "y", filt, pid, {"axis": AXIS[pid]}, statistic, **kw)


def claim(s: Side, relation: str, cid: str = "c", **kw) -> Claim:
    return Claim(cid, "text", "", kw.pop("paper", None), kw.pop("paper_runs", None), s, relation, **kw)


CASES = {
    "mean below": claim(side(), "below", value=1.3),
    "mean above": claim(side(), "above", value=0.7),
    "paired above": claim(side(filt="b")._replace(minus=side(filt="a")), "above", value=0.1),
    "rate below": claim(side(filt="f", statistic="rate"), "below", value=0.35),
    "rate over, above": claim(side(filt="c", statistic="rate", over=1.0), "above", value=0.5),
    "median below": claim(side(filt="c", statistic="median"), "below", value=2.0),
    "quantile above": claim(side(filt="c", statistic="quantile", q=0.9), "above", value=2.0),
    "within": claim(side(), "within", band=(0.5, 1.5)),
    "equal, fails": claim(side(), "equal", value=2.0, band=(1.9, 2.1)),
    "than": claim(side(0), "below", others=(side(2),)),
    "monotone": claim(side(0), "monotone", others=(side(0), side(1), side(2)), along="axis"),
    "monotone, fails": claim(side(0), "monotone", others=(side(0), side(1), side(2)), along="axis",
                             direction="decreasing"),
    "consistent": claim(side(), "consistent", paper=1.9, paper_runs=20),
    "consistent rate": claim(side(filt="f", statistic="rate"), "consistent", paper=0.5, paper_runs=20),
}


@pytest.mark.parametrize("c", CASES.values(), ids=CASES.keys())
def test_a_claims_decision_level_is_where_its_intervals_verdict_turns(c):
    """Just below its level the claim's intervals (confidence 1 − 2 level) leave it undecided (a paper's
    number: consistent), just above they decide it: the family's level and the interval shown agree."""
    runs = Runs(ROWS)
    d = evaluate.decision(c, runs)
    assert 0 < d.level < 0.45
    before = evaluate.judge(c, runs, 1 - 2 * d.level * (1 - 1e-6))[0].verdict
    after = evaluate.judge(c, runs, 1 - 2 * d.level * (1 + 1e-6))[0].verdict
    undecided = "holds" if c.relation == "consistent" else "undecided"
    assert (before, after != undecided) == (undecided, True)
    single = {"below": (2, 1), "above": (2, 1), "within": (2, 0), "equal": (2, 0), "consistent": (2, 2)}
    sides = max(2, len(c.others))  # than: the claim's side and the other
    assert (d.tests, d.weight) == ((2 * sides, 2) if c.others else single[c.relation])


@pytest.mark.parametrize("name", ["mean below", "paired above", "rate below", "median below", "within", "equal, fails",
                                  "consistent"])
def test_a_file_of_one_claim_keeps_its_95_percent_verdict(name):
    c = CASES[name]
    (row,) = evaluate.family_rows((c,), ROWS)
    own = evaluate.claim_row(c, ROWS)
    assert row["family_confidence"] == pytest.approx(0.95) and row["family_verdict"] == own["verdict"]
    assert row["family_ours"] == own["ours"] and row["family_runs_to_decide"] == own["runs_to_decide"]


def _mean_at(level: float, n: int = 30) -> np.ndarray:
    """Runs whose mean lies below 0 with one-sided p-value `level` (Student-t, n − 1 dof)."""
    z = np.random.default_rng(int(level * 1e6)).normal(size=n)
    z = (z - z.mean()) / z.std(ddof=1)
    return z - stats.t.isf(level, n - 1) / math.sqrt(n)


def test_holms_steps_on_hand_made_families():
    """Three `below 0` claims with one-sided p-values 1e-9, 0.0095 and 0.012, each two one-sided tests (6):
    Holm's step 1 at 0.05/6 decides the first, step 2 at 0.05/5 = 0.01 the second, step 3 at 0.05/4 = 0.0125
    the third — all three hold, where Bonferroni (0.05/6 each) decides only the first; each is shown at its
    step's level, and its adjusted p-value is the least family-wise error that decides it. A fourth claim
    (0.02) makes 8 tests: after the first (0.05/8), 0.0095 > 0.05/7 stops the steps, and the three left
    are undecided at 0.05/7, though each holds alone at 95 %."""
    levels = [1e-9, 0.0095, 0.012]
    rows = _rows({(0, f"f{i}"): _mean_at(lv) for i, lv in enumerate(levels)})
    claims = tuple(claim(side(filt=f"f{i}"), "below", cid=f"c{i}", value=0.0) for i in range(3))
    assert [evaluate.decision(c, Runs(rows)).level for c in claims] == pytest.approx(levels, rel=1e-6)
    holm = evaluate.family_rows(claims, rows, "holm")
    assert [r["family_verdict"] for r in holm] == ["holds"] * 3
    assert [r["family_confidence"] for r in holm] == pytest.approx([1 - 2 * 0.05 / k for k in (6, 5, 4)])
    assert [r["family_p"] for r in holm] == pytest.approx([6e-9, 0.0475, 0.048], rel=1e-5)
    assert {(r["family_claims"], r["family_tests"], r["family"]) for r in holm} == {(3, 6, "holm")}
    bonferroni = evaluate.family_rows(claims, rows, "bonferroni")
    assert [r["family_verdict"] for r in bonferroni] == ["holds", "undecided", "undecided"]
    assert [r["family_confidence"] for r in bonferroni] == pytest.approx([1 - 0.05 / 3] * 3)
    rows = _rows({(0, f"f{i}"): _mean_at(lv) for i, lv in enumerate([*levels, 0.02])})
    claims = (*claims, claim(side(filt="f3"), "below", cid="c3", value=0.0))
    four = evaluate.family_rows(claims, rows, "holm")
    own = [evaluate.claim_row(c, rows) for c in claims]
    assert [r["verdict"] for r in own] == ["holds"] * 4
    assert [r["family_verdict"] for r in four] == ["holds", "undecided", "undecided", "undecided"]
    assert [r["family_confidence"] for r in four] == pytest.approx([1 - 2 * 0.05 / 8] + [1 - 2 * 0.05 / 7] * 3)
    assert all(r["family_runs_to_decide"] > 30 and r["family_high"] > 0 > o["high"] for r, o in zip(four[1:], own[1:]))


def _table(verdicts: list[str], family: list[str]) -> pd.DataFrame:
    rows = {c: [""] * len(verdicts) for c in COLUMNS}
    rows.update(id=[f"c{i}" for i in range(len(verdicts))], verdict=verdicts, family_verdict=family,
                runs_to_decide=[-1] * len(verdicts), family_runs_to_decide=[-1] * len(verdicts),
                runs=[10] * len(verdicts), family=["holm"] * len(verdicts), family_tests=[2 * len(verdicts)] * 2,
                family_confidence=[0.9875, 0.99])
    return pd.DataFrame(rows)


def test_replication_columns_and_the_tables_marks():
    r0 = _table(["holds", "holds"], ["holds", "undecided"])
    r1 = _table(["holds", "fails"], ["holds", "undecided"])
    t = evaluate.replication([r0, r1])
    assert list(t.columns) == [*COLUMNS, *REPLICATE_COLUMNS]
    assert t["range_verdicts"].tolist() == ["holds, holds", "undecided, undecided"]
    assert t["replicates"].tolist() == [True, True] and t["replicates_per_claim"].tolist() == [True, False]
    shown = display_table(t)
    assert list(shown.columns) == ["claim", "where", "paper", "ours [95 %]", "runs", "verdict", "per claim", "ranges"]
    assert shown["verdict"].tolist() == ["holds", "undecided"]
    alone = display_table(t, per_claim=True)
    assert alone["verdict"].tolist() == ["holds", f"holds {NOT_REPLICATED}"]
    assert alone["ranges"].tolist() == ["holds, holds", "holds, fails"]
    meta = {"paper": "P", "ranges": [{"s": 0}, {"s": 1_000_000}]}
    text = verdict_text(t, meta)
    assert "P: 2 claim(s) — 1 holds, 0 fails, 1 undecided at the family-wise level" in text
    assert "their 4 one-sided tests held to a family-wise error of 5 %" in text and "98.75–99.00 %" in text
    assert "range 1: base seed 1000000" in text and "1 − 0.95^2 = 10 %" in text
    assert "(per claim)" in verdict_text(t, meta, per_claim=True)


def test_a_table_from_before_families_is_shown_per_claim():
    old = _table(["holds", "fails"], ["holds", "fails"]).drop(columns=list(evaluate.FAMILY_COLUMNS))
    shown = display_table(old)
    assert list(shown.columns) == ["claim", "where", "paper", "ours [95 %]", "runs", "verdict"]
    assert "verdict: per claim, each from its own 95 % interval alone" in verdict_text(old, {})
