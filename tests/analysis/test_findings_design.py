""""What this shows" respects the design: on two swept axes where pooling misleads (one comm radius
with every run of one filter diverging and disconnected, the others with none), no sentence pools
design points, and every order a sentence states is re-checked with scipy on the panel it names."""

import re

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


def test_no_sentence_pools_design_points_and_every_order_holds_on_its_panel():
    df = _runs()
    found = findings.findings(df, META)
    assert found
    texts = [f.text for f in found]
    assert not any("pooled" in t for t in texts)
    # a pooled rate would be 1 in 4 radii (25 %) or 1 in 3 turns: only 0 % and 100 % exist at any point
    rates = [float(x) for t in texts for x in re.findall(r"(\d+\.\d) % \[", t)]
    assert rates and set(rates) <= {0.0, 100.0}
    checked = 0
    for f in found:
        if f.kind in ("consistency", "floor"):
            continue
        assert f.panel, f.text  # two axes: every sentence names its panel
        assert f.text.startswith("With "), f.text
        panel = df
        for axis, value in f.panel:
            panel = panel[panel[axis] == value]
        for lower, higher, where in f.orders:
            at = panel[panel[f.axis] == where]
            a, b = at[at["filter"] == lower], at[at["filter"] == higher]
            if f.kind == "divergence":
                lo_a, hi_a = _wilson(a["diverged"].sum(), len(a))
                lo_b, hi_b = _wilson(b["diverged"].sum(), len(b))
            else:
                lo_a, hi_a = _t(a["rmse"].to_numpy())
                lo_b, hi_b = _t(b["rmse"].to_numpy())
            assert hi_a < lo_b, (f.text, lower, higher, where)
            checked += 1
    assert checked >= 10


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


def test_sentences_name_filters_and_axes_by_their_declared_words():
    meta = {**META, "filter_names": {"imm": "IMM-UKF", "ct": "CT-only UKF"},
            "params": {**META["params"], "comm_radius": {**META["params"]["comm_radius"], "label": "comm radius"}}}
    found = [f for f in findings.findings(_runs(), meta) if f.kind not in ("consistency", "floor")]
    texts = " ".join(f.text for f in found)
    assert "IMM-UKF" in texts and "CT-only UKF" in texts and "comm radius = " in texts
    assert not re.search(r"(?<![\w-])(imm|ct|comm_radius)(?![\w-])", texts), texts
    assert all(order[0] in ("imm", "ct") for f in found for order in f.orders)  # the data keep the code names
