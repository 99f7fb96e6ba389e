""""What this shows" respects the design: on two swept axes where pooling misleads (one comm radius
with every run of one filter diverging and disconnected, the others with none), no sentence pools
design points, and every order a sentence states is re-checked with scipy at the design point it
names. On the two-axis sweep of Ren & Lv 2017 (sweeps/ren2017_comm_turn.toml, its real metadata,
made-up runs) the box leads with the scenario's headline and holds at most 8 sentences, none repeated."""

import re
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

from mcjax.analysis import findings

META = {
    "scenario": "test", "filters": ["imm", "ct"],
    "outputs": {"rmse": {"unit": "m", "description": "RMS error", "per_filter": True, "role": "error"},
                "diverged": {"unit": "", "description": "diverged", "per_filter": True, "role": "divergence"},
                "disconnected_steps": {"unit": "steps", "description": "d", "per_filter": False,
                                       "role": "disconnected_steps"}},
    "params": {"comm_radius": {"unit": "m", "description": "comm radius", "display_unit": "km",
                               "display_factor": 0.001},
               "turn_rate": {"unit": "deg/s", "description": "turn rate"}},
    "spec": {"grid": {"comm_radius": [0.0, 50e3, 100e3, 150e3], "turn_rate": [1.0, 5.0, 9.0]}},
}


def _runs(n=60):
    rng = np.random.default_rng(4)
    rows = []
    for point, (radius, turn) in enumerate((r, t) for r in (0.0, 50e3, 100e3, 150e3) for t in (1.0, 5.0, 9.0)):
        cut = radius == 0.0
        for f in ("imm", "ct"):
            err = rng.normal(1.0 + 0.3 * turn * (f == "ct") + 5 * cut, 0.2, n)
            rows.append(pd.DataFrame({"comm_radius": radius, "turn_rate": turn, "filter": f, "point_id": point,
                                      "seed_index": np.arange(n), "rmse": err,
                                      "diverged": np.full(n, cut and f == "ct"),
                                      "disconnected_steps": np.full(n, 60 if cut else 0)}))
    return pd.concat(rows, ignore_index=True)


def _t(values):
    return stats.t.interval(0.95, len(values) - 1, loc=np.mean(values), scale=stats.sem(values))


def _wilson(k, n):
    ci = stats.binomtest(int(k), int(n)).proportion_ci(0.95, method="wilson")
    return ci.low, ci.high


def check_claims(found, df, error="rmse"):
    """Re-check with scipy every order and every change the sentences claim, at its design point; the count."""
    groups = {}

    def runs(point, flt):  # the runs of one filter at one design point
        axes = tuple(a for a, _ in point)
        if axes not in groups:
            groups[axes] = {k if isinstance(k, tuple) else (k,): g for k, g in df.groupby([*axes, "filter"])}
        return groups[axes][(*(v for _, v in point), flt)]

    checked = 0
    for f in found:
        for lower, higher, point in f.orders:
            a, b = runs(point, lower), runs(point, higher)
            if f.kind == "divergence":
                (lo_a, hi_a), (lo_b, hi_b) = _wilson(a["diverged"].sum(), len(a)), _wilson(b["diverged"].sum(), len(b))
            else:
                (lo_a, hi_a), (lo_b, hi_b) = _t(a[error].to_numpy()), _t(b[error].to_numpy())
            assert hi_a < lo_b, (f.text, lower, higher, point)
            checked += 1
        for flt, start, end, way in f.moves:
            (lo_a, hi_a), (lo_b, hi_b) = _t(runs(start, flt)[error].to_numpy()), _t(runs(end, flt)[error].to_numpy())
            assert (hi_b < lo_a) if way == "falls" else (hi_a < lo_b), (f.text, flt, start, end)
            checked += 1
    return checked


def test_no_sentence_pools_design_points_and_every_order_holds_on_its_panel():
    df = _runs()
    found = findings.findings(df, META)
    assert found
    texts = [f.text for f in found]
    assert not any("pooled" in t for t in texts)
    # a pooled rate would be 1 in 4 radii (25 %) or 1 in 3 turns: only 0 % and 100 % exist at any point
    rates = [float(x) for t in texts for x in re.findall(r"(\d+\.\d) % \[", t)]
    assert rates and set(rates) <= {0.0, 100.0}
    assert all(len(point) == 2 for f in found for *_, point in f.orders)  # two axes: every claim names its point
    assert check_claims(found, df) >= 10
    assert len(found) <= 8 and len(set(texts)) == len(texts)


def test_one_axis_sentences_name_no_panel():
    df = _runs().query("turn_rate == 5.0")
    meta = {**META, "spec": {"grid": {"comm_radius": [0.0, 50e3, 100e3, 150e3]}}}
    found = [f for f in findings.findings(df, meta) if f.kind not in ("consistency", "floor")]
    assert found and all(f.panel == () and not f.text.startswith("With ") for f in found)


def test_the_divergence_sentence_names_where_the_filters_differ_most():
    """Rates cif 0 / 7 / 100 % and icf 10 / 70 / 100 % at three radii: the worst radius has equal rates; the
    sentence also names the middle one, where the filters differ most (with its rates)."""
    n, rows = 100, []
    for point, (radius, rates) in enumerate(((20e3, (0, 10)), (60e3, (7, 70)), (100e3, (100, 100)))):
        for f, k in zip(("imm", "ct"), rates):
            rows.append(pd.DataFrame({"comm_radius": radius, "turn_rate": 1.0, "filter": f, "point_id": point,
                                      "seed_index": np.arange(n), "rmse": np.linspace(1, 2, n),
                                      "diverged": np.arange(n) < k, "disconnected_steps": 0}))
    meta = {**META, "spec": {"grid": {"comm_radius": [20e3, 60e3, 100e3]}}}
    (text,) = [f.text for f in findings.findings(pd.concat(rows), meta) if f.kind == "divergence"]
    assert "differ most at 60 km: imm 7.0 %" in text and "ct 70.0 %" in text, text
    assert "at 100 km: imm 100.0 % [96.3, 100.0], ct 100.0 %" in text, text


def test_sentences_name_filters_and_axes_by_their_declared_words():
    meta = {**META, "filter_names": {"imm": "IMM-UKF", "ct": "CT-only UKF"},
            "params": {**META["params"], "comm_radius": {**META["params"]["comm_radius"], "label": "comm radius"}}}
    found = [f for f in findings.findings(_runs(), meta) if f.kind not in ("consistency", "floor")]
    texts = " ".join(f.text for f in found)
    assert "IMM-UKF" in texts and "CT-only UKF" in texts and "comm radius = " in texts
    assert not re.search(r"(?<![\w-])(imm|ct|comm_radius)(?![\w-])", texts), texts
    assert all(order[0] in ("imm", "ct") for f in found for order in f.orders)  # the data keep the code names


def test_the_ren2017_sweep_box_leads_with_its_headline_in_at_most_eight_sentences():
    """sweeps/ren2017_comm_turn.toml's real metadata (4 comm radii x 4 turn rates, IMM-UKF against CV and CT),
    made-up runs (20 seeds) where the order changes with the turn rate and radius 0 disconnects and diverges:
    the box's first sentence is the headline, at most 8 sentences, none repeated, every claim re-checked."""
    from mcjax.study import load_spec

    study = load_spec(Path(__file__).resolve().parents[2] / "sweeps" / "ren2017_comm_turn.toml")
    meta = {**study.scenario.metadata(study.config), "spec": study.source}  # as the sweep writes it, less provenance
    assert meta["headlines"] == [["imm", "cv"], ["imm", "ct"]]
    rng = np.random.default_rng(11)
    rows, seeds = [], 20
    radii, turns = study.source["grid"]["comm_radius"], study.source["grid"]["turn_rate"]
    for point, (radius, turn) in enumerate((r, t) for r in radii for t in turns):
        level = 40.0 if radius == 0 else 10.0 - radius / 200
        mean = {"imm": level, "cv": level * (1 + 6 * turn), "ct": level * (1.3 - 2 * turn)}
        for f in ("imm", "cv", "ct"):
            rows.append(pd.DataFrame({
                "comm_radius": radius, "turn_rate": turn, "filter": f, "point_id": point, "seed_index": np.arange(seeds),
                "rmse": rng.normal(mean[f], 0.1 * mean[f], seeds), "anees": rng.chisquare(4, seeds),
                "diverged": np.arange(seeds) < (15 if radius == 0 and f == "cv" else 0), "nonfinite": False,
                "disconnected_steps": 60 if radius == 0 else 0, "lambda2_min": 0.0, "lambda2_mean": 0.0}))
    df = pd.concat(rows, ignore_index=True)
    box = findings.box(df, meta)
    texts = [f.text for f in box.sentences]
    assert box.sentences[0].kind == "headline" and texts[0].startswith("IMM-UKF against CV-only UKF: lower mean rmse")
    assert "against CT-only UKF:" in texts[0], texts[0]
    assert len(texts) <= 8 and len(set(texts)) == len(texts), texts
    assert all(not re.search(r"\.\s+[A-Z]", t) for t in texts), texts  # one sentence each
    assert sum(f.kind == "consistency" for f in box.sentences) == 1 and check_claims(box.sentences, df) >= 16
    assert len(box.orders) == 16 and len(box.quality) == 16 * 3
    judged = box.quality.set_index(["comm_radius", "turn_rate", "filter"])["NEES verdict"]
    assert judged[(0.0, turns[0], "cv")] == "not judged: 75 % of runs diverged"


def test_a_scenario_declares_its_headlines_in_one_checked_field():
    """Scenario(headlines=...): pairs of its filter kinds; the metadata keeps those the sweep runs; else one line."""
    import dataclasses

    import pytest

    from mcjax import scenarios

    sc = scenarios.get("leader_follower")
    assert sc.metadata(sc.Config())["headlines"] == [["modified_icf", "icf"]]
    assert "headlines" not in sc.metadata(sc.Config(filters=("cif", "icf")))
    for bad in ((("icf", "icf"),), (("icf", "nope"),), ("icf",)):
        with pytest.raises(ValueError, match=r"^scenario 'leader_follower': headlines must be pairs \(expected lower, "
                                             r"higher\) of two different filter kinds of its Config \(cif, icf, .*\); got "):
            dataclasses.replace(sc, headlines=bad)
