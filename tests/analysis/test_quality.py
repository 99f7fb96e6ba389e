"""How good is a filter in the report: the floor multiple's interval (its coverage, by simulation),
the consistency and floor table per design point and filter (never pooled across points) with its
one legend and one sentence each in the box, the verdict only over the runs that did not diverge
(or "not judged" past half of them), and the per-step figures of a timeseries with their bands."""

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from mcjax.analysis import findings, quality, tables
from mcjax.analysis.statistics import chi2_band, floor_multiple
from mcjax.report.plots.steps import step_plots

OUTPUTS = {
    "rmse": {"unit": "m", "description": "RMS error", "per_filter": True, "role": "error"},
    "anees": {"unit": "", "description": "NEES", "per_filter": True, "role": "nees", "dof": 4},
    "anis": {"unit": "", "description": "NIS", "per_filter": True, "role": "nis", "dof": 2},
    "pcrb_rmse": {"unit": "m", "description": "floor", "per_filter": False, "role": "floor"},
}
META = {"scenario": "test", "filters": ["good", "proud", "timid"], "outputs": OUTPUTS,
        "params": {"noise": {"unit": "m", "description": "noise"}}, "spec": {"grid": {"noise": [1.0, 2.0]}}}


def _runs(n=400, seed=0):
    """Runs at two design points: 'good' a consistent filter 1.5x the floor, 'proud' over-confident
    (NEES x3) 2x the floor, 'timid' under-confident (NEES / 3) at the floor x 1.2."""
    rng = np.random.default_rng(seed)
    rows = []
    for noise in (1.0, 2.0):
        floor = noise * (1 + 0.1 * rng.random(n))
        for f, scale, nees in (("good", 1.5, 1.0), ("proud", 2.0, 3.0), ("timid", 1.2, 1 / 3)):
            e = floor * scale * np.sqrt(rng.chisquare(8, n) / 8)
            rows.append(pd.DataFrame({"noise": noise, "filter": f, "seed_index": np.arange(n), "rmse": e,
                                      "pcrb_rmse": floor, "anees": nees * rng.chisquare(4, n) / 1.0,
                                      "anis": nees * rng.chisquare(2, n), "point_id": int(noise)}))
    return pd.concat(rows, ignore_index=True)


def test_floor_multiple_interval_covers_the_true_multiple():
    """Over 400 simulated studies of 200 paired runs (errors sqrt(3) times a random floor, with noise),
    the interval holds sqrt(3) in 90 to 99 % of them (95 % nominal)."""
    rng = np.random.default_rng(1)
    hits = 0
    for _ in range(400):
        b = 1 + rng.random(200)
        e = np.sqrt(3) * b * np.sqrt(rng.chisquare(5, 200) / 5)
        m = floor_multiple(e, b)
        hits += m.low <= np.sqrt(3) <= m.high
    assert 0.90 <= hits / 400 <= 0.99


def test_floor_multiple_edge_cases():
    assert floor_multiple([2.0, 2.0], [1.0, 1.0]).mean == pytest.approx(2.0)
    assert np.isnan(floor_multiple([1.0], [1.0]).low)
    assert np.isnan(floor_multiple([np.nan], [1.0]).mean)
    with pytest.raises(ValueError, match="paired"):
        floor_multiple([1.0, 2.0], [1.0])


def _table(runs, meta=META):
    box = findings.box(runs, meta)
    return box, box.quality.set_index(["noise", "filter"])


def test_one_table_per_point_and_filter_with_scipys_band_and_one_sentence():
    runs = _runs()
    box, table = _table(runs)
    assert len(table) == 2 * 3  # each filter at each of the two points: none pooled
    lo, hi = stats.chi2.ppf([0.025, 0.975], 1600) / 400
    assert (chi2_band(4, 400).low, chi2_band(4, 400).high) == pytest.approx((lo, hi))
    for noise in (1.0, 2.0):
        for f, verdict in (("good", "consistent"), ("proud", "over-confident"), ("timid", "under-confident")):
            row = table.loc[(noise, f)]
            assert row["NEES verdict"] == verdict and row["NIS verdict"] == verdict, (noise, f, row)
            v = runs[(runs["noise"] == noise) & (runs["filter"] == f)]["anees"]
            assert row["average NEES"] == tables.format_number(v.mean(), tables.STAT_DIGITS)
            assert row["NEES band (4 dof)"] == f"[{tables.format_number(lo, 4)}, {tables.format_number(hi, 4)}]"
            assert row["runs judged"] == "400 of 400"
    (sentence,) = [f.text for f in box.sentences if f.kind == "consistency"]
    assert "NEES (4 dof): good consistent at every point; proud over-confident at every point; timid under-confident" \
        in sentence, sentence
    # one legend: what each column is; without the NIS column the legend says it was not computed
    assert sum("χ² band" in line for line in box.legend) == 2 and not any("not computed" in x for x in box.legend)
    box, table = _table(runs.drop(columns="anis"), {**META, "outputs": {k: v for k, v in OUTPUTS.items() if k != "anis"}})
    assert "NIS verdict" not in table.columns and "average NIS: not computed in this dataset" in " ".join(box.legend)


def test_the_verdict_is_over_the_runs_that_did_not_diverge_and_not_given_past_half():
    """'good' diverges in 10 % of its runs (their NEES huge): judged consistent over the other 90 %, the
    share left out named; 'proud' in 80 % at noise 2: not judged."""
    runs = _runs(200)
    n = runs.groupby(["noise", "filter"]).cumcount()
    runs["diverged"] = ((runs["filter"] == "good") & (n < 20)) | ((runs["filter"] == "proud") & (runs["noise"] == 2.0)
                                                                   & (n < 160))
    runs.loc[runs["diverged"], "anees"] = 1e6
    meta = {**META, "outputs": {**OUTPUTS, "diverged": {"unit": "", "description": "d", "per_filter": True,
                                                        "role": "divergence"}}}
    box, table = _table(runs, meta)
    good = table.loc[(1.0, "good")]
    kept = runs[(runs["noise"] == 1.0) & (runs["filter"] == "good") & ~runs["diverged"]]["anees"]
    assert good["NEES verdict"] == "consistent" and good["runs judged"] == "180 of 200 (10 % diverged, left out)"
    assert good["average NEES"] == tables.format_number(kept.mean(), tables.STAT_DIGITS)
    lo, hi = stats.chi2.ppf([0.025, 0.975], 4 * 180) / 180
    assert good["NEES band (4 dof)"] == f"[{tables.format_number(lo, 4)}, {tables.format_number(hi, 4)}]"
    assert table.loc[(2.0, "proud"), "NEES verdict"] == "not judged: 80 % of runs diverged"
    assert table.loc[(1.0, "proud"), "NEES verdict"] == "over-confident"
    (sentence,) = [f.text for f in box.sentences if f.kind == "consistency"]
    assert "over the runs that did not diverge, not judged where more than 50 %" in sentence
    assert "proud over-confident at 1 point, not judged at 1 point" in sentence, sentence
    assert quality.NOT_JUDGED_ABOVE == 0.5


def test_the_floor_column_and_sentence_give_each_filters_multiple_per_point():
    runs = _runs()
    box, table = _table(runs)
    for (noise, f), row in table.iterrows():
        truth = {"good": 1.5, "proud": 2.0, "timid": 1.2}[f]
        m, rest = row["RMSE / floor"].split("× ")
        low, high = (float(x) for x in rest.strip("[]").split(","))
        assert low <= truth <= high and abs(float(m) - truth) < 0.1, (noise, f, row["RMSE / floor"])
    (sentence,) = [f.text for f in box.sentences if f.kind == "floor"]
    assert "good from 1." in sentence and "bug" not in sentence, sentence
    below = runs.assign(rmse=lambda d: d["pcrb_rmse"] * 0.5)
    (sentence,) = [f.text for f in findings.findings(below, META) if f.kind == "floor"]
    assert "a bug to report" in sentence and "good at noise = 1 m" in sentence, sentence


def test_a_per_agent_axis_gets_one_row_per_point():
    """A per-agent parameter swept as lists (tuples once prepared) is compared whole, value by value."""
    runs = _runs(100)
    runs["noise"] = runs["noise"].map(lambda v: [v, 2 * v])
    _, table = _table(runs)
    assert sorted(set(table.index.get_level_values(0))) == [(1.0, 2.0), (2.0, 4.0)] and len(table) == 6


def test_many_design_points_are_tallied_in_one_sentence():
    runs = _runs(60)
    runs = pd.concat([runs.assign(noise=runs["noise"] + 10 * k, point_id=runs["point_id"] + 10 * k) for k in range(7)])
    found = [f.text for f in findings.findings(runs, META) if f.kind == "consistency"]
    assert len(found) == 1 and "good consistent at every point" in found[0], found
    assert "proud over-confident at every point" in found[0], found[0]


def _series(n_runs=50, T=20):
    rng = np.random.default_rng(2)
    rows = []
    for point in (1, 2):
        for s in range(n_runs):
            for f, scale in (("good", 1.0), ("proud", 3.0)):
                rows.append(pd.DataFrame({"point_id": point, "seed_index": s, "t": np.arange(T), "filter": f,
                                          "error_mean": scale * rng.random(T), "pcrb_error": np.ones(T),
                                          "nees": scale * rng.chisquare(4, T), "nis": rng.chisquare(2, T)}))
    ts = pd.concat(rows, ignore_index=True)
    meta = {"timeseries_outputs": {
        "error_mean": {"unit": "m", "description": "e", "per_filter": True, "role": "error"},
        "pcrb_error": {"unit": "m", "description": "b", "per_filter": False, "role": "floor"},
        "nees": {"unit": "", "description": "n", "per_filter": True, "role": "nees", "dof": 4},
        "nis": {"unit": "", "description": "n", "per_filter": True, "role": "nis", "dof": 2}}}
    return ts, meta


def test_step_plots_draw_the_floor_and_the_bands_one_panel_per_point():
    ts, ts_meta = _series()
    runs = _runs(50).query("filter != 'timid'")
    made = list(step_plots(ts, ts_meta, runs, META))
    assert [p.name for p in made] == ["error_and_floor.png", "nees_per_step.png", "nis_per_step.png"]
    nees = made[1].figure.axes
    assert len(nees) == 2 and {a.get_title() for a in nees} == {"noise = 1 m", "noise = 2 m"}
    band = chi2_band(4, 50)
    (span,) = nees[0].patches
    assert (span.get_y(), span.get_y() + span.get_height()) == pytest.approx((band.low, band.high))
    assert "floor" in made[0].caption and "50 runs" in made[0].caption
    lines = {ln.get_label(): ln for ln in made[0].figure.axes[0].lines}
    assert np.allclose(lines["floor (PCRB)"].get_ydata(), 1.0)
    many = pd.concat([runs.assign(noise=runs["noise"] + k, point_id=runs["point_id"] + 10 * k) for k in range(12)])
    assert all(type(p).__name__ == "Skipped" for p in step_plots(ts, ts_meta, many, META))
