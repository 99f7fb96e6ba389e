"""Tests of mcjax.report: statistics, summary table, formats, plots (synthetic datasets)."""

from __future__ import annotations

import io
import itertools
import math
import subprocess
import sys

import matplotlib
import matplotlib.image as mpimg
import numpy as np
import pandas as pd
import pytest
from scipy import stats

from mcjax import report as rp
from mcjax import results

FILTERS = ("cif", "icf", "kcf")
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


# --------------------------------------------------------------------------------------
# synthetic data
# --------------------------------------------------------------------------------------


def synthetic_runs(grid: dict, seeds: int = 12, filters=FILTERS, seed: int = 0) -> pd.DataFrame:
    """A runs table shaped like a sweep's: one row per (point, seed, filter)."""
    rng = np.random.default_rng(seed)
    names = list(grid)
    points = list(itertools.product(*(grid[n] for n in names))) if names else [()]
    rows = []
    for pid, values in enumerate(points):
        p = dict(zip(names, values))
        radius = p.get("comm_radius", 80e3)
        for s in range(seeds):
            l2 = max(0.0, (radius - 40e3) / 20e3 + rng.normal(0, 0.3))
            for fi, f in enumerate(filters):
                div = bool(rng.random() < min(1.0, max(0.0, (100e3 - radius) / 60e3 * (0.3 + 0.2 * fi))))
                r = (30 + 5 * fi) * (1 + rng.normal(0, 0.1)) * (40 if div else 1)
                rows.append(dict(scenario="leader_follower", point_id=pid, seed_index=s, filter=f, **p,
                                 rmse=r, mean_error=0.8 * r, final_error=r, max_error=2 * r,
                                 leader_rmse=r, anees=4.0, diverged=div, nonfinite=False,
                                 lambda2_min=0.5 * l2, lambda2_mean=l2,
                                 disconnected_steps=int(rng.poisson(2)), robustness_min=0.1,
                                 seeing_mean=2.0, seeing_min=1))
    return pd.DataFrame(rows)


def write_dataset(out_dir, df, grid, zipped=None):
    spec = {"base": "configs/x.toml", "grid": grid}
    if zipped:
        spec["zip"] = zipped
    results.write_part(out_dir, "runs", df, "part-000000", {"spec": spec})
    return out_dir


def known_table() -> pd.DataFrame:
    """Two points x two filters x 4 seeds with hand-chosen values."""
    rows = []
    data = {  # (comm_radius, filter) -> rmse per seed, diverged per seed
        (50e3, "cif"): ([10.0, 12.0, 14.0, 1000.0], [False, False, False, True]),
        (50e3, "kcf"): ([20.0, 22.0, 2000.0, np.nan], [False, False, True, True]),
        (100e3, "cif"): ([5.0, 5.0, 5.0, 5.0], [False] * 4),
        (100e3, "kcf"): ([8.0, 9.0, 10.0, 11.0], [False] * 4),
    }
    l2 = {50e3: ([0.1, 0.2, 0.3, 0.4], [0.0, 0.05, 0.1, 0.2], [3, 1, 0, 0]),
          100e3: ([1.0, 1.0, 2.0, 2.0], [0.5, 0.6, 0.7, 0.8], [0, 0, 0, 0])}
    for (radius, f), (rmse, div) in data.items():
        lm, lmin, disc = l2[radius]
        for s in range(4):
            rows.append(dict(point_id=0 if radius == 50e3 else 1, seed_index=s, filter=f,
                             comm_radius=radius, rmse=rmse[s], diverged=div[s],
                             nonfinite=not np.isfinite(rmse[s]), lambda2_mean=lm[s],
                             lambda2_min=lmin[s], disconnected_steps=disc[s]))
    return pd.DataFrame(rows)


# --------------------------------------------------------------------------------------
# statistics
# --------------------------------------------------------------------------------------


def test_wilson_hand_computed():
    # k=5, n=10, z=1.959964: z^2/n = 0.3841459, centre (0.5 + 0.19207)/1.3841459 = 0.5,
    # half = z/1.3841459 * sqrt(0.5*0.5/10 + z^2/(4*10^2)) = 1.416013 * 0.186021 = 0.263407
    lo, hi = rp.wilson_interval(5, 10)
    assert lo == pytest.approx(0.236593, abs=2e-6)
    assert hi == pytest.approx(0.763407, abs=2e-6)
    # k=0: lower bound 0, upper z^2/(n + z^2) = 3.841459/13.841459
    lo, hi = rp.wilson_interval(0, 10)
    assert lo == 0.0
    assert hi == pytest.approx(3.841459 / 13.841459, rel=1e-6)


@pytest.mark.parametrize("k,n", [(0, 1), (1, 1), (0, 7), (3, 10), (10, 10), (1, 200), (57, 200), (999, 1000)])
def test_wilson_matches_scipy(k, n):
    ci = stats.binomtest(k, n).proportion_ci(method="wilson")
    lo, hi = rp.wilson_interval(k, n)
    assert lo == pytest.approx(ci.low, abs=1e-12)
    assert hi == pytest.approx(ci.high, abs=1e-12)
    ci90 = stats.binomtest(k, n).proportion_ci(confidence_level=0.9, method="wilson")
    assert rp.wilson_interval(k, n, confidence=0.9) == pytest.approx((ci90.low, ci90.high), abs=1e-12)


def test_wilson_edge_cases():
    assert all(math.isnan(v) for v in rp.wilson_interval(0, 0))
    with pytest.raises(ValueError, match="k <= n"):
        rp.wilson_interval(3, 2)
    with pytest.raises(ValueError, match="confidence"):
        rp.wilson_interval(1, 2, confidence=1.5)


def test_t_critical_matches_scipy():
    for dof in [*range(1, 121), 150, 500, 1e4]:
        assert rp.t_critical_95(dof) == pytest.approx(stats.t.ppf(0.975, dof), rel=1e-6), dof
    assert rp.t_critical_95(math.inf) == pytest.approx(stats.norm.ppf(0.975), rel=1e-12)
    assert math.isnan(rp.t_critical_95(0))


@pytest.mark.parametrize("n", [2, 3, 10, 30, 31, 57, 400])
def test_mean_ci_matches_scipy_t_interval(n):
    x = np.random.default_rng(n).gamma(2.0, 10.0, size=n)
    mean, lo, hi = rp.mean_ci(x)
    ref = stats.t.interval(0.95, n - 1, loc=x.mean(), scale=stats.sem(x))
    assert mean == pytest.approx(x.mean(), rel=1e-12)
    assert (lo, hi) == pytest.approx(ref, rel=1e-6)


def test_mean_ci_ignores_nonfinite_and_small_samples():
    mean, lo, hi = rp.mean_ci([1.0, np.nan, 3.0, np.inf])
    ref = stats.t.interval(0.95, 1, loc=2.0, scale=stats.sem([1.0, 3.0]))
    assert mean == 2.0 and (lo, hi) == pytest.approx(ref, rel=1e-6)
    mean, lo, hi = rp.mean_ci([4.0])
    assert mean == 4.0 and math.isnan(lo) and math.isnan(hi)
    assert all(math.isnan(v) for v in rp.mean_ci([]))


# --------------------------------------------------------------------------------------
# summary
# --------------------------------------------------------------------------------------


def test_summarize_known_values():
    s = rp.summarize(known_table(), ["comm_radius"])
    assert list(s.columns) == ["comm_radius", "filter", *rp.SUMMARY_COLUMNS]
    assert list(zip(s["comm_radius"], s["filter"])) == [(50e3, "cif"), (50e3, "kcf"),
                                                        (100e3, "cif"), (100e3, "kcf")]
    assert s["n"].tolist() == [4, 4, 4, 4]
    assert s["diverged"].tolist() == [1, 2, 0, 0]
    assert s["n_ok"].tolist() == [3, 2, 4, 4]
    assert s["nonfinite"].tolist() == [0, 1, 0, 0]
    assert s["div_rate"].tolist() == [0.25, 0.5, 0.0, 0.0]
    lo, hi = rp.wilson_interval(2, 4)
    assert (s.loc[1, "div_ci_low"], s.loc[1, "div_ci_high"]) == (lo, hi)
    # rmse_mean: finite values only (the NaN of the non-finite kcf run is left out)
    assert s["rmse_mean"].tolist() == pytest.approx([259.0, 2042.0 / 3, 5.0, 9.5])
    assert s["rmse_ok_mean"].tolist() == pytest.approx([12.0, 21.0, 5.0, 9.5])
    ref = stats.t.interval(0.95, 2, loc=12.0, scale=stats.sem([10.0, 12.0, 14.0]))
    assert (s.loc[0, "rmse_ok_ci_low"], s.loc[0, "rmse_ok_ci_high"]) == pytest.approx(ref, rel=1e-6)
    # constant values: zero-width interval
    assert s.loc[2, "rmse_ci_low"] == s.loc[2, "rmse_ci_high"] == 5.0
    assert s["lambda2_mean"].tolist() == pytest.approx([0.25, 0.25, 1.5, 1.5])
    assert s["lambda2_min"].tolist() == pytest.approx([0.0, 0.0, 0.5, 0.5])
    assert s["disconnected_steps_mean"].tolist() == pytest.approx([1.0, 1.0, 0.0, 0.0])


def test_summarize_pools_and_orders_filters():
    df = synthetic_runs({"comm_radius": [60e3, 100e3], "sigma_accel": [10.0, 50.0]}, seeds=5,
                        filters=("local", "kcf", "cif", "zz_custom"))
    s = rp.summarize(df, [])
    assert s["filter"].tolist() == ["cif", "kcf", "local", "zz_custom"]
    assert s["n"].tolist() == [20] * 4
    two = rp.summarize(df, ["comm_radius", "sigma_accel"])
    assert len(two) == 4 * 4 and set(two["n"]) == {5}
    one = rp.summarize(df, "sigma_accel")
    assert len(one) == 2 * 4 and set(one["n"]) == {10}
    assert one.groupby("filter")["diverged"].sum().to_dict() == df.groupby("filter")["diverged"].sum().to_dict()


def test_summarize_list_valued_axis_and_missing_optional_columns():
    df = known_table().drop(columns=["lambda2_mean", "lambda2_min", "disconnected_steps", "nonfinite"])
    df["comm_radius"] = [np.array([r, r]) for r in df["comm_radius"]]  # per-agent values
    s = rp.summarize(df, ["comm_radius"])
    assert s["comm_radius"].tolist() == [(50e3, 50e3)] * 2 + [(100e3, 100e3)] * 2
    assert s["lambda2_mean"].isna().all()
    assert s["nonfinite"].tolist() == [0, 1, 0, 0]  # counted from non-finite RMSE
    with pytest.raises(ValueError, match="sigma_range"):
        rp.summarize(df, ["sigma_range"])


def test_swept_axes_from_metadata():
    cols = ["comm_radius", "sensing_radius", "sigma_accel", "filter"]
    meta = {"spec": {"grid": {"comm_radius": [1, 2]},
                     "zip": {"sensing_radius": [1, 2], "sigma_accel": [3, 4], "absent": [5, 6]}}}
    assert rp.swept_axes(meta, cols) == ["comm_radius", "sensing_radius", "sigma_accel"]
    assert rp.swept_axes({"spec": {"base": "x"}}, cols) == []
    assert rp.swept_axes({}, cols) == []


def test_axis_units_mirror_scenario_units():
    """report.py copies the units (it does not import JAX): every scenario's scalar Params
    are covered, and no unit disagrees with a scenario's."""
    from mcjax.scenarios import SCENARIOS

    for mod in SCENARIOS.values():
        defaults = mod.default_params(mod.Config())
        for field, unit in mod.PARAM_UNITS.items():
            if getattr(defaults, field).ndim == 0:
                assert field in rp.AXIS_UNITS, (mod.NAME, field)
            if field in rp.AXIS_UNITS:
                assert rp.AXIS_UNITS[field] == unit, (mod.NAME, field)


# --------------------------------------------------------------------------------------
# formats
# --------------------------------------------------------------------------------------


def test_formats():
    s = rp.summarize(known_table(), ["comm_radius"])
    text = rp.format_table(s, "text")
    lines = text.splitlines()
    assert len(lines) == 1 + len(s)
    assert lines[0].split() == list(s.columns)
    assert lines[1].split()[:3] == ["50000", "cif", "4"]
    assert "259" in lines[1]

    csv = rp.format_table(s, "csv")
    back = pd.read_csv(io.StringIO(csv))
    assert list(back.columns) == list(s.columns)
    np.testing.assert_allclose(back["rmse_mean"], s["rmse_mean"], rtol=1e-12)

    md = rp.format_table(s, "markdown").splitlines()
    assert len(md) == 2 + len(s)
    assert md[0] == "| " + " | ".join(s.columns) + " |"
    assert set(md[1].strip("|").split("|")) <= {"---:", ":---"}
    assert all(line.startswith("| ") and line.endswith(" |") and line.count("|") == len(s.columns) + 1
               for line in md[2:])
    assert md[1].split("|")[2] == ":---"  # filter column left-aligned

    assert rp.format_table(s.iloc[:0], "text").splitlines()[0].split() == list(s.columns)


@pytest.mark.parametrize("bad", ["html", "TEXT", "", None, 3])
def test_bad_format_raises(bad):
    s = rp.summarize(known_table(), ["comm_radius"])
    with pytest.raises(ValueError, match=r"fmt=.*'text', 'csv', 'markdown'"):
        rp.format_table(s, bad)


# --------------------------------------------------------------------------------------
# report + plots
# --------------------------------------------------------------------------------------


def check_png(path):
    assert path.is_file() and path.stat().st_size > 1000, path
    assert path.read_bytes()[:8] == PNG_SIGNATURE, path
    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100
    assert float(img[..., :3].std()) > 0.01, f"{path} looks blank"


def _pyplot_state():
    import matplotlib.pyplot as plt

    return matplotlib.get_backend(), list(plt.get_fignums())


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    root = tmp_path_factory.mktemp("report")
    one = {"comm_radius": [50e3, 70e3, 100e3]}
    two = {"comm_radius": [50e3, 100e3], "kcf_epsilon": [0.001, 0.01, 0.1, 1.0]}
    return {
        "one": write_dataset(root / "one", synthetic_runs(one), one),
        "two": write_dataset(root / "two", synthetic_runs(two, seeds=6), two),
        "zero": write_dataset(root / "zero", synthetic_runs({}), {}),
    }


def test_report_one_axis(datasets):
    before = _pyplot_state()
    table, paths = rp.report(datasets["one"], "markdown")
    assert _pyplot_state() == before  # no backend switch, no open pyplot figures
    assert table.splitlines()[0].startswith("| comm_radius | filter | n |")
    assert len(table.splitlines()) == 2 + 3 * len(FILTERS)
    assert sorted(p.name for p in paths) == sorted([
        "rmse_vs_comm_radius.png", "rmse_nondiverged_vs_comm_radius.png",
        "divergence_vs_comm_radius.png", "lambda2_vs_comm_radius.png"])
    for p in paths:
        assert p.parent == datasets["one"] / "report"
        check_png(p)


def test_report_two_axes(datasets):
    table, paths = rp.report(datasets["two"], "csv")
    s = pd.read_csv(io.StringIO(table))
    assert list(s.columns[:3]) == ["comm_radius", "kcf_epsilon", "filter"]
    assert len(s) == 2 * 4 * len(FILTERS) and set(s["n"]) == {6}
    names = {p.name for p in paths}
    assert {"rmse_vs_kcf_epsilon.png", "divergence_vs_kcf_epsilon.png", "lambda2_vs_kcf_epsilon.png",
            "rmse_vs_comm_radius.png", "heatmap_divergence_comm_radius__kcf_epsilon.png",
            "heatmap_rmse_comm_radius__kcf_epsilon.png",
            "heatmap_rmse_nondiverged_comm_radius__kcf_epsilon.png"} <= names
    assert len(names) == len(paths) == 2 * 4 + 3
    for p in paths:
        check_png(p)


def test_report_zero_axes(datasets):
    table, paths = rp.report(datasets["zero"])
    assert table.splitlines()[0].split()[:2] == ["filter", "n"]
    assert [p.name for p in paths] == ["summary_bars.png"]
    check_png(paths[0])
    table2, none = rp.report(datasets["zero"], "text", plots=False)
    assert table2 == table and none == []


def test_log_scale_only_beyond_two_decades():
    assert rp._XAxis("kcf_epsilon", [0.001, 0.01, 0.1, 1.0]).log
    assert not rp._XAxis("comm_radius", [50e3, 100e3]).log
    assert not rp._XAxis("heading_cmd", [-1.0, 0.01, 1.0]).log
    assert rp._axis_label("comm_radius") == "comm_radius [m]"
    assert rp._axis_label("sigma_bearing") == "sigma_bearing [rad]"


def test_report_errors(tmp_path, datasets):
    with pytest.raises(ValueError, match="no runs found in .*empty"):
        rp.report(tmp_path / "empty")
    with pytest.raises(ValueError, match="fmt='html'"):
        rp.report(datasets["zero"], "html")


def test_no_jax_import():
    code = ("import sys, pandas as pd, mcjax.report as r; "
            "df = pd.DataFrame({'filter': ['cif'], 'rmse': [1.0], 'diverged': [False]}); "
            "r.format_table(r.summarize(df, []), 'markdown'); "
            "assert 'jax' not in sys.modules and 'scipy' not in sys.modules, 'imported jax/scipy'")
    subprocess.run([sys.executable, "-c", code], check=True)
