"""How good is a filter in the report: the floor multiple's interval (its coverage, by simulation),
the consistency and floor sentences per design point (never pooled across points), and the
per-step figures of a timeseries with their bands."""

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


def _by_point(sentences):
    return {p: [s for s in sentences if f"noise = {p}" in s] for p in ("1 m", "2 m")}


def test_consistency_sentences_name_each_filter_per_point_with_scipy_band():
    runs = _runs()
    sch = tables.schema(META, runs.columns)
    found = [f for f in findings.findings(runs, META) if f.kind == "consistency"]
    assert len(found) == 4  # NEES and NIS at each of the two points: none pooled
    band = chi2_band(4, 400)
    lo, hi = stats.chi2.ppf([0.025, 0.975], 1600) / 400
    assert (band.low, band.high) == pytest.approx((lo, hi))
    nees = [f.text for f in found if "NEES" in f.text]
    for text in nees:
        assert text.split("good ")[1].split(";")[0].endswith("consistent")
        assert text.split("proud ")[1].split(";")[0].endswith("over-confident")
        assert text.split("timid ")[1].split(" (")[0].endswith("under-confident")
        assert tables.format_number(lo, tables.STAT_DIGITS) in text
    assert all(len(v) == 2 for v in _by_point([f.text for f in found]).values())
    # without the NEES column only the NIS sentences remain
    assert all("NIS" in t for t in quality.consistency_sentences(runs.drop(columns="anees"), sch, ["noise"],
                                                                   ["good"], lambda a, v: str(v)))


def test_floor_sentences_give_each_filters_multiple_per_point():
    runs = _runs()
    found = [f.text for f in findings.findings(runs, META) if f.kind == "floor"]
    assert len(found) == 2
    for text in found:
        for f, truth in (("good", 1.5), ("proud", 2.0), ("timid", 1.2)):
            part = text.split(f"{f} ")[1].split(";")[0].rstrip(".")
            m, rest = part.split("×")
            low, high = (float(x) for x in rest.strip(" []").split(","))
            assert low <= truth <= high and abs(float(m) - truth) < 0.1, (f, part)
        assert "bug" not in text
    below = _runs().assign(rmse=lambda d: d["pcrb_rmse"] * 0.5)
    assert any("bug" in f.text for f in findings.findings(below, META) if f.kind == "floor")


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


def test_a_per_agent_axis_gets_one_sentence_per_point():
    """A per-agent parameter swept as lists (tuples once prepared) is compared whole, value by value."""
    runs = _runs(100)
    runs["noise"] = runs["noise"].map(lambda v: [v, 2 * v])
    found = [f.text for f in findings.findings(runs, META) if f.kind == "floor"]
    assert len(found) == 2 and "noise = (1, 2) m" in found[0] and "noise = (2, 4) m" in found[1], found


def test_many_design_points_are_tallied_in_one_sentence():
    runs = _runs(60)
    runs = pd.concat([runs.assign(noise=runs["noise"] + 10 * k, point_id=runs["point_id"] + 10 * k) for k in range(7)])
    found = [f.text for f in findings.findings(runs, META) if f.kind == "consistency"]
    assert len(found) == 2 and found[0].startswith("Consistency over the 14 design points"), found
    assert "good consistent at 14" in found[0] and "proud over-confident at 14" in found[0], found[0]
