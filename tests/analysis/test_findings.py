"""The report's "What this shows" (mcjax.analysis.findings): every order a sentence claims is backed by
intervals recomputed here with scipy (independent of mcjax.analysis.statistics), at the design point it
names; where two filters' intervals overlap no sentence orders them; the scenario's headline comparison
leads, with both intervals; an order that holds over a range of an axis is said once for the range;
divergence in percent with its Wilson interval; the glossary and the base Params from the declarations."""

from __future__ import annotations

import math
import re

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from mcjax.analysis import findings, wording
from mcjax.report import glossary
from tests.analysis.test_tables import make_metadata

KM = {"display_unit": "km", "display_factor": 1e-3}


def _runs(spec: dict, seeds: int, *, divergent: dict | None = None, disconnected: dict | None = None,
          rng_seed: int = 0) -> pd.DataFrame:
    """Rows per (comm_radius value, seed, filter): the error of filter f at value v drawn
    normal(mean, sd) from ``spec[v][f] = (mean, sd)``; ``divergent[(v, f)]`` runs flagged
    diverged; ``disconnected[v]`` runs with disconnected steps."""
    rng = np.random.default_rng(rng_seed)
    rows = []
    for pid, (v, per_filter) in enumerate(spec.items()):
        for s in range(seeds):
            ds = 3 if s < (disconnected or {}).get(v, 0) else 0
            for f, (mean, sd) in per_filter.items():
                rows.append(dict(scenario="toy", point_id=pid, seed_index=s, comm_radius=v, filter=f,
                                 rmse=float(rng.normal(mean, sd)), mean_error=0.0,
                                 diverged=s < (divergent or {}).get((v, f), 0), nonfinite=False,
                                 lambda2_mean=1.0 - 0.1 * ds, lambda2_min=0.0 if ds else 0.5,
                                 disconnected_steps=ds))
    return pd.DataFrame(rows)


def _meta(values, filters=("icf", "cif")) -> dict:
    meta = make_metadata({"comm_radius": list(values)}, filters=filters)
    meta["params"] = {**meta["params"], "comm_radius": {**meta["params"]["comm_radius"], **KM}}
    return meta


def _t_interval(x: np.ndarray) -> tuple[float, float]:
    """95 % Student-t interval of the mean by scipy (independent of mcjax.analysis.statistics)."""
    lo, hi = stats.t.interval(0.95, len(x) - 1, loc=np.mean(x), scale=stats.sem(x))
    return float(lo), float(hi)


def _at(df, point):
    for axis, value in point:
        df = df[df[axis] == value]
    return df


def _check_orders(found, df):
    """Every claimed order of mean errors: the lower filter's interval lies wholly below, at its point."""
    n = 0
    for f in found:
        if f.kind not in ("headline", "order"):
            continue
        for lower, higher, point in f.orders:
            at = _at(df, point)
            a = at[at["filter"] == lower]["rmse"].to_numpy()
            b = at[at["filter"] == higher]["rmse"].to_numpy()
            assert _t_interval(a)[1] < _t_interval(b)[0], (lower, higher, point)
            n += 1
    return n


def _check_moves(found, df):
    """Every change a trend claims: the two ends' intervals apart, in the direction said."""
    n = 0
    for f in found:
        for flt, start, end, way in f.moves:
            a = _t_interval(_at(df, start).query("filter == @flt")["rmse"].to_numpy())
            b = _t_interval(_at(df, end).query("filter == @flt")["rmse"].to_numpy())
            assert (b[1] < a[0]) if way == "falls" else (a[1] < b[0]), (flt, start, end, way)
            n += 1
    return n


def test_overlapping_intervals_are_never_ordered():
    # at 50 km icf and cif have the same error distribution (intervals overlap); at 100 km cif is far lower
    spec = {50e3: {"icf": (100.0, 20.0), "cif": (101.0, 20.0)}, 100e3: {"icf": (30.0, 2.0), "cif": (10.0, 2.0)}}
    df = _runs(spec, seeds=30)
    a, b = (_t_interval(df[(df["comm_radius"] == 50e3) & (df["filter"] == f)]["rmse"].to_numpy())
            for f in ("icf", "cif"))
    assert a[0] < b[1] and b[0] < a[1]  # the set-up: the two intervals overlap at 50 km
    box = findings.box(df, _meta(spec))
    order = next(f for f in box.sentences if f.kind == "order")
    assert order.orders == (("cif", "icf", (("comm_radius", 100e3),)),)  # none at 50 km, one at 100 km
    assert _check_orders(box.sentences, df) == 1
    assert "icf ≈ cif at comm_radius = 50 km; cif < icf at comm_radius = 100 km." in order.text, order.text
    # the order table quotes the means and intervals of the data, lowest first
    cell = box.orders.set_index("comm_radius").iloc[:, 0]
    m = df[(df["comm_radius"] == 100e3) & (df["filter"] == "cif")]["rmse"]
    assert cell[100e3].startswith(f"cif {findings.quote(m.mean(), *_t_interval(m.to_numpy()), 'm')} < icf ")
    assert " ≈ " in cell[50e3] and "<" not in cell[50e3]


def test_the_headline_leads_and_an_order_over_a_range_is_said_once():
    """The scenario's headline (modified_icf against icf) is the first sentence, with both intervals where the
    lead is largest; the order that holds from 60 to 100 km is one clause, 50 km (every interval overlapping)
    the exception; every order and every change said is re-checked with scipy at its point."""
    f3 = ("icf", "modified_icf", "cif")
    spec = {50e3: dict.fromkeys(f3, (700.0, 300.0)),
            **{v: {"icf": (k * lv, 1.0), "modified_icf": (1.6 * lv, 1.0), "cif": (lv, 1.0)}
               for v, lv, k in ((60e3, 40.0, 3.0), (80e3, 21.0, 2.5), (100e3, 11.0, 2.5))}}
    df = _runs(spec, seeds=40)
    meta = {**_meta(spec, f3), "headlines": [["modified_icf", "icf"]],
            "filter_names": {"icf": "ICF", "modified_icf": "modified ICF", "cif": "CIF"}}
    found = findings.findings(df, meta)
    head, order = found[0], found[1]
    assert head.kind == "headline" and order.kind == "order"
    assert head.text.startswith("Modified ICF against ICF: lower mean rmse at every comm_radius from 60 to 100 km, "
                                "the 95 % intervals apart (at 60 km: "), head.text  # 120 against 64 m: the largest lead
    for f in ("modified_icf", "icf"):
        x = df[(df["comm_radius"] == 60e3) & (df["filter"] == f)]["rmse"]
        assert findings.quote(x.mean(), *_t_interval(x.to_numpy()), "m") in head.text, (f, head.text)
    assert head.text.endswith("the intervals overlap at comm_radius = 50 km."), head.text
    assert {p for _, _, p in head.orders} == {(("comm_radius", v),) for v in (60e3, 80e3, 100e3)}
    assert ("CIF < modified ICF < ICF at every comm_radius from 60 to 100 km; ICF ≈ modified ICF ≈ CIF at "
            "comm_radius = 50 km.") in order.text, order.text
    assert len(order.orders) == 3 * 3 and _check_orders(found, df) == 3 + 9
    assert _check_moves(found, df) > 0 and len(found) <= 8


def test_every_claim_is_backed_on_a_noisy_three_filter_sweep():
    rng = np.random.default_rng(5)
    spec = {v: {f: (float(rng.uniform(10, 40)), float(rng.uniform(1, 15))) for f in ("icf", "modified_icf", "cif")}
            for v in (40e3, 60e3, 80e3, 100e3, 120e3)}
    df = _runs(spec, seeds=12, rng_seed=7)
    found = findings.findings(df, {**_meta(spec, ("icf", "modified_icf", "cif")), "headlines": [["cif", "icf"]]})
    assert _check_orders(found, df) > 0
    # the trend sentence: a filter "falls"/"rises" only with its end intervals apart
    trend = next(f for f in found if f.kind == "trend")
    for f in ("icf", "modified_icf", "cif"):
        a = _t_interval(df[(df["comm_radius"] == 40e3) & (df["filter"] == f)]["rmse"].to_numpy())
        b = _t_interval(df[(df["comm_radius"] == 120e3) & (df["filter"] == f)]["rmse"].to_numpy())
        moved = re.search(rf"(?<!\w){f}'s from", trend.text) is not None
        assert moved == (a[1] < b[0] or b[1] < a[0]), (f, a, b, trend.text)
    assert _check_moves(found, df) == sum("'s from" in p for p in trend.text.split(";"))


def test_divergence_in_percent_with_its_wilson_interval_and_where_it_starts():
    spec = {50e3: {"icf": (50.0, 5.0), "cif": (40.0, 5.0)}, 80e3: {"icf": (20.0, 2.0), "cif": (10.0, 2.0)},
            100e3: {"icf": (20.0, 2.0), "cif": (10.0, 2.0)}}
    df = _runs(spec, seeds=100, divergent={(50e3, "icf"): 99, (50e3, "cif"): 60, (80e3, "icf"): 2,
                                            (80e3, "cif"): 2}, disconnected={50e3: 100})
    found = findings.findings(df, _meta(spec))
    div = next(f for f in found if f.kind == "divergence").text
    # 2 of 100: the issue's example, Wilson interval [0.55 %, 7.0 %]
    lo, hi = stats.binomtest(2, 100).proportion_ci(method="wilson")
    assert f"icf 2.0 % [{100 * lo:.1f}, {100 * hi:.1f}]" in div, div
    assert "icf 2.0 % [0.6, 7.0]" in div
    assert "none of the runs at comm_radius = 100 km" in div and "divergence starts below 100 km: at 80 km:" in div, div
    assert f"the interval up to {100 * stats.binomtest(0, 100).proportion_ci(method='wilson').high:.1f} %" in div
    # at 50 km cif's 60 % [50.2, 69.1] is below icf's 99 % [94.6, 99.8]: said, and kept as a claim
    assert "there cif diverges least" in div and ("cif", "icf", (("comm_radius", 50e3),)) in next(
        f for f in found if f.kind == "divergence").orders
    graph = next(f for f in found if f.kind == "graph").text
    assert "at 50 km in 100.0 % [96.3, 100.0] of runs" in graph and "no run at comm_radius = 80 km and 100 km" in graph, graph


def test_no_divergence_sentence_claims_an_order_of_overlapping_rates():
    spec = {50e3: {"icf": (50.0, 5.0), "cif": (40.0, 5.0)}, 100e3: {"icf": (20.0, 2.0), "cif": (10.0, 2.0)}}
    df = _runs(spec, seeds=40, divergent={(50e3, "icf"): 10, (50e3, "cif"): 8})
    div = next(f for f in findings.findings(df, _meta(spec)) if f.kind == "divergence")
    assert div.orders == () and "diverges least" not in div.text, div.text


def test_an_interval_of_zero_width_says_every_run_gave_it():
    """Every run at 50 km disconnected for 3 steps: "every run: 3", not "mean 3 [3, 3] per run"; a spread keeps
    its mean and interval."""
    spec = {50e3: {"icf": (50.0, 5.0), "cif": (40.0, 5.0)}, 100e3: {"icf": (20.0, 2.0), "cif": (10.0, 2.0)}}
    graph = next(f for f in findings.findings(_runs(spec, seeds=20, disconnected={50e3: 20, 100e3: 5}), _meta(spec))
                 if f.kind == "graph").text
    assert "at 50 km in 100.0 % [83.9, 100.0] of runs (disconnected_steps, every run: 3)" in graph, graph
    assert re.search(r"at 100 km in 25\.0 % \[.*\] of runs \(disconnected_steps: mean 0\.75 \[.*\] per run\)",
                     graph), graph
    assert findings.quote(17.0, 17.0, 17.0, "steps") == "every run: 17 steps"
    assert findings.quote(0.0, 0.0, 0.0, "m", every="every seed") == "every seed: 0 m"
    assert findings.quote(17.0, math.nan, math.nan, "steps") == "17 steps (no interval)"


@pytest.mark.parametrize("rate, low, high, text", [(0.02, 0.005502, 0.07001, "2.0 % [0.6, 7.0]"),
                                                   (0.0, 0.0, 0.03699, "0.0 % [0.0, 3.7]"),
                                                   (0.5, math.nan, math.nan, "50.0 %")])
def test_percent(rate, low, high, text):
    assert findings.percent(rate, low, high) == text


def test_glossary_from_the_declarations():
    meta = _meta([50e3, 100e3])
    meta["config"] = {"divergence_threshold": 1000.0}
    terms = dict(glossary.glossary(meta, ["comm_radius"]))
    assert any(t.startswith("icf, cif") for t in terms)  # no words declared per filter: one entry, the title's words
    assert "toy: a synthetic scenario" in terms[next(t for t in terms if t.startswith("icf, cif"))]
    for name in ("rmse [m]", "diverged", "lambda2_mean", "lambda2_min", "disconnected_steps", "comm_radius [km]",
                 "Params"):
        assert name in terms, (name, list(terms))
    assert terms["rmse [m]"].startswith("rmse over the run")  # the declaration's own words first
    assert "divergence_threshold = 1000" in terms["diverged"]
    meta["filter_descriptions"] = {"icf": "the information consensus filter", "cif": "the centralised filter"}
    terms = dict(glossary.glossary(meta, ["comm_radius"]))
    assert terms["icf"] == "the information consensus filter" and terms["cif"] == "the centralised filter"


def test_base_params_table():
    meta = _meta([50e3, 100e3])
    rows, note = glossary.params_table(meta, ["comm_radius"])
    assert "does not record its base Params" in note and "configs/x.toml" in note
    meta["base_params"] = {"comm_radius": 1e5, "eps": 0.5}
    rows, note = glossary.params_table(meta, ["comm_radius"])
    table = {r[0]: r for r in rows}
    assert table["comm_radius"][1].startswith("swept") and table["eps"][1] == "0.5"
    assert table["comm_radius"][2] == "m"


def test_the_page_shows_the_base_configs_params(tmp_path):
    """A dataset without recorded base Params: the page reads its base config file's [params]
    (found from sweep.json's spec file) with the spec's [params] over them, and says so."""
    import json

    from click.testing import CliRunner

    from mcjax.cli import main
    from tests.analysis.test_tables import write_dataset
    from tests.report.test_html_page import parse

    (tmp_path / "configs").mkdir()
    (tmp_path / "configs" / "base.toml").write_text('scenario = "toy"\n[params]\neps = 0.25\nsigma_wind = 5.0\n')
    (tmp_path / "sweeps").mkdir()
    (tmp_path / "sweeps" / "s.toml").write_text("")
    meta = _meta([50e3, 100e3])
    meta["spec"].update(base="../configs/base.toml", params={"sigma_wind": 7.0})
    out = tmp_path / "out"
    write_dataset(out, _runs({50e3: {"icf": (5.0, 1.0), "cif": (4.0, 1.0)},
                              100e3: {"icf": (5.0, 1.0), "cif": (4.0, 1.0)}}, seeds=6), meta)
    (out / "sweep.json").write_text(json.dumps({"spec": meta["spec"], "spec_file": str(tmp_path / "sweeps" / "s.toml")}))
    assert CliRunner().invoke(main, ["report", str(out)]).exit_code == 0
    page = parse(out / "report" / "index.html")
    table = next(t for t in page.tables if t and t[0][:2] == ["Param", "value"])
    assert {r[0]: r[1] for r in table[1:]} == {"comm_radius": "swept (comm_radius is an axis)", "eps": "0.25",
                                               "sigma_wind": "7"}
    assert any(f"base config file {tmp_path / 'configs' / 'base.toml'} as that file is now" in t
               for t in page.text.get("p", []))


def test_a_single_point_orders_its_filters_and_gives_their_divergence_rates():
    df = _runs({100e3: {"icf": (30.0, 1.0), "cif": (10.0, 1.0)}}, seeds=50, divergent={(100e3, "icf"): 1})
    meta = make_metadata({}, filters=("icf", "cif"))
    meta["spec"].pop("grid")
    box = findings.box(df.drop(columns="comm_radius"), {**meta, "headlines": [["cif", "icf"]]})
    head, order, div = box.sentences
    assert head.orders == order.orders == (("cif", "icf", ()),) and box.orders is None
    assert head.text.startswith("Cif against icf: lower mean rmse, the 95 % intervals apart (10"), head.text
    assert order.text.endswith(": cif < icf."), order.text
    lo, hi = stats.binomtest(1, 50).proportion_ci(method="wilson")
    assert div.text == f"Divergence rate: icf 2.0 % [{100 * lo:.1f}, {100 * hi:.1f}], cif 0.0 % [0.0, 7.1]."


def test_per_agent_axis_values_are_said_in_the_display_unit():
    spec = {(50e3, 60e3): {"icf": (30.0, 1.0), "cif": (10.0, 1.0)}, (90e3, 100e3): {"icf": (20.0, 9.0), "cif": (19.0, 9.0)}}
    df = _runs(spec, seeds=10)
    df["comm_radius"] = df["comm_radius"].map(list)  # as Parquet gives a per-agent column back
    text = findings.findings(df, _meta([0, 1]))[0].text
    assert "cif < icf at comm_radius = (50, 60) km; icf ≈ cif at comm_radius = (90, 100) km" in text, text


def test_design_points_are_named_compactly():
    """A range of one axis, a product of ranges, every point but a few, or how many (past three products)."""
    r, t = wording.Axis("radius", "km", 1e-3), wording.Axis("turn", "deg/s", 1.0)
    one = [(v,) for v in (50e3, 60e3, 80e3, 100e3)]
    assert wording.where(one[1:], one, [r]) == "at every radius from 60 to 100 km"
    assert wording.where(one, one, [r]) == "at every radius"
    assert wording.where([one[0], one[2]], one, [r]) == "at radius = 50 km and 80 km"
    grid = [(a, b) for a in (0.0, 450.0, 700.0, 800.0) for b in (1.0, 3.0, 6.0, 9.0)]
    radii = wording.Axis("radius", "m", 1.0)
    assert wording.where([p for p in grid if p[0] > 0], grid, [radii, t]) == \
        "at every radius from 450 to 800 m"  # every turn: unsaid
    assert wording.where([p for p in grid if p != (0.0, 1.0)], grid, [radii, t]) == \
        "at every point but radius = 0 m with turn = 1 deg/s"
    assert wording.where([(0.0, 1.0), (450.0, 3.0), (450.0, 6.0)], grid, [radii, t]) == \
        "at (radius = 0 m, turn = 1 deg/s) and (radius = 450 m, turn = 3 deg/s and 6 deg/s)"
    assert wording.where(grid[::5], grid, [radii, t]) == "at 4 of the 16 points"  # the diagonal
