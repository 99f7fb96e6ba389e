"""The league table as a reader sees it, on hand-made runs: the ANEES placed against its band in
words (the band from scipy here), every blank cell saying why, the unit beside the error, and the
cost star only where the fastest filter's range over the timed repeats lies below every other's."""

import numpy as np
import pandas as pd
from scipy import stats

from mcjax.league.table import (NO_FLOOR, NO_NEES, NOT_TIMED, WITHIN_SPREAD, cell_rows, display_table, frame,
                                legend, league_text)

SEEDS = np.arange(10)
ROLE = {"error": "rmse", "nees": "nees", "dof": 2, "unit": "m", "divergence": "diverged"}


def runs(errors: dict, nees: dict) -> pd.DataFrame:
    """Ten runs per filter: its errors (a constant plus the seed's share) and NEES values."""
    out = []
    for f, e in errors.items():
        out.append(pd.DataFrame({"filter": f, "seed_index": SEEDS, "rmse": e + 0.1 * SEEDS,
                                 "nees": nees[f], "diverged": False}))
    return pd.concat(out, ignore_index=True)


def table(costs=None, role=ROLE):
    rows = runs({"a": 1.0, "b": 5.0}, {"a": np.full(10, 0.5), "b": np.full(10, 2.0)})
    return frame(cell_rows("s", "scen", "p", rows, role, ["a", "b"], ["a", "b", "c"], {"c": "cannot run here: why"},
                           costs, "machine"))


def test_the_anees_is_placed_against_its_band_in_words():
    shown = display_table(table()).set_index("filter")
    low, high = stats.chi2.ppf([0.025, 0.975], 2 * 10) / 10   # the band of 10 runs' average NEES, 2 dof
    assert low > 0.5 and low < 2.0 < high
    band = f"[{low:.3g}, {high:.3g}]"
    assert shown.loc["a", "ANEES"] == f"0.5, below its band {band}: under-confident"
    assert shown.loc["b", "ANEES"] == f"2, inside its band {band}: consistent *"


def test_every_blank_says_why_and_the_error_has_its_unit():
    t = table()
    shown = display_table(t).set_index("filter")
    assert shown.loc["a", "error [95 %]"].startswith("1.45 m [") and shown.loc["a", "error [95 %]"].endswith("*")
    assert (shown.loc[["a", "b"], "x floor [95 %]"] == NO_FLOOR).all()          # no floor role
    assert (shown.loc[["a", "b"], "ms/run [range]"] == NOT_TIMED).all()         # no timing pass
    assert (shown.loc["c"].drop(["scenario", "point", "note"]) == "–").all() and shown.loc["c", "note"] == \
        "cannot run here: why"
    no_nees = display_table(table(role={k: v for k, v in ROLE.items() if k != "nees"})).set_index("filter")
    assert (no_nees.loc[["a", "b"], "ANEES"] == NO_NEES).all()
    text = "\n".join(legend(t, {"title": "t", "seeds": 10, "timing_runs": 0}))
    for word in (NO_FLOOR, NO_NEES, NOT_TIMED, "in m", "below it under-confident", "–: the filter did not run"):
        assert word in text, word


def test_the_cost_star_goes_only_beyond_the_spread_of_the_repeats():
    clear = display_table(table({"a": (1e-3, 0.9e-3, 1.1e-3, "alone"), "b": (2e-3, 1.2e-3, 2.2e-3, "alone")}))
    clear = clear.set_index("filter")
    assert clear.loc["a", "ms/run [range]"] == "1 [0.9, 1.1] *" and clear.loc["b", "ms/run [range]"] == "2 [1.2, 2.2]"
    assert clear.loc["a", "note"] == "" and clear.loc["b", "note"] == ""
    within = display_table(table({"a": (1e-3, 0.9e-3, 1.3e-3, "alone"),
                                  "b": (2e-3, 1.2e-3, 2.2e-3, "with a (the scenario needs it)")})).set_index("filter")
    assert not within["ms/run [range]"].str.endswith("*").any()
    assert within.loc["a", "note"] == WITHIN_SPREAD
    assert within.loc["b", "note"] == "timed with a (the scenario needs it)"


def test_the_text_and_markdown_lead_with_the_legend_and_the_method():
    t = table({"a": (1e-3, 0.9e-3, 1.1e-3, "alone"), "b": (2e-3, 1.2e-3, 2.2e-3, "alone")})
    meta = {"title": "t", "seeds": 10, "timing_runs": 6, "machine": "a test machine",
            "timing": {"repeats": 3, "repeat_runs": 2, "load": 1.5}}
    text = league_text(t, meta, "text", width=80)
    words = " ".join(text.split())  # the header lines wrapped at 80 columns
    assert "the median of 3 timed repeats of 2 run(s) each" in words and "a test machine" in words
    assert "filter alone" in words and "load average 1.5" in words
    assert max(len(line) for line in text.splitlines()) <= 80
    assert league_text(t, meta, "markdown").startswith("- t: 1 scenario(s) x 1 point(s) x 3 filter(s), 10 runs")


def test_a_league_table_written_before_the_cost_ranges_still_reads():
    """league.parquet of 2026-12-06 had one cost per filter and no range: shown, never starred."""
    old = table({"a": (1e-3, 0.9e-3, 1.1e-3, "alone"), "b": (2e-3, 1.2e-3, 2.2e-3, "alone")})
    shown = display_table(old.drop(columns=["cost_low", "cost_high"])).set_index("filter")
    assert list(shown.loc[["a", "b"], "ms/run [range]"]) == ["1", "2"] and (shown.loc[["a", "b"], "note"] == "").all()
