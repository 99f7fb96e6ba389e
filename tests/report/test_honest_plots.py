"""The report's plots say what they rest on: the number of runs per point where it varies,
points on fewer than 5 runs hollow and out of the lines, one panel per value of another
axis instead of pooling over it (pooling only when said), no plot of a metric against an
axis it does not depend on, axes in display units. Checked against counts and means
computed here with pandas, read back from the matplotlib figures."""

from __future__ import annotations

import numpy as np
import pytest
from tests.analysis.test_tables import make_metadata, synthetic_runs

from mcjax.report import plots

KM = {"display_unit": "km", "display_factor": 1e-3}


def _meta(grid, **kw):
    meta = make_metadata(grid, **kw)
    meta["params"] = {**meta["params"], "comm_radius": {**meta["params"]["comm_radius"], **KM}}
    return meta


def _lines(ax) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The labelled lines of an axes: label -> (x, y)."""
    return {ln.get_label(): (np.asarray(ln.get_xdata(), float), np.asarray(ln.get_ydata(), float))
            for ln in ax.get_lines() if not ln.get_label().startswith("_")}


def _hollow(ax) -> list[tuple[float, float]]:
    out = []
    for ln in ax.get_lines():
        if ln.get_linestyle() == "None" and ln.get_markerfacecolor() == "white":
            out += list(zip(np.asarray(ln.get_xdata(), float), np.asarray(ln.get_ydata(), float)))
    return out


@pytest.fixture(scope="module")
def one_axis():
    """comm_radius 50 / 100 / 150 km x 10 seeds; the kf filter diverges in 8 of 10 runs at
    50 km (2 left), local in 3 at 100 km: the non-divergent means rest on 2 to 10 runs."""
    grid = {"comm_radius": [50e3, 100e3, 150e3]}
    df = synthetic_runs(grid, seeds=10)
    df["diverged"] = False
    df.loc[(df["comm_radius"] == 50e3) & (df["filter"] == "kf") & (df["seed_index"] < 8), "diverged"] = True
    df.loc[(df["comm_radius"] == 100e3) & (df["filter"] == "local") & (df["seed_index"] < 3), "diverged"] = True
    meta = _meta(grid)
    items = list(plots.plots(df, meta))
    return df, {i.name: i for i in items}


@pytest.mark.xdist_group("test_honest_plots")  # one worker builds the module fixture once
def test_runs_per_point_shown_where_they_vary(one_axis):
    df, items = one_axis
    fig = items["rmse_nondiverged_vs_comm_radius.png"].figure
    ax = fig.axes[0]
    expected = (df[~df["diverged"]].groupby(["comm_radius", "filter"]).size())
    shown = {}
    for t in ax.texts:
        x, _ = t.xy
        shown.setdefault(round(float(x)), set()).add(int(t.get_text()))
    want = {}
    for (r, f), n in expected.items():
        want.setdefault(round(r / 1e3), set()).add(int(n))
    assert shown == want  # x in km, each point's count of non-divergent runs
    assert "numbers beside the points" in fig._suptitle.get_text()
    # where every point rests on the same number of runs, it is said once and no point is labelled
    err = items["rmse_vs_comm_radius.png"].figure
    assert not err.axes[0].texts
    assert "n = 10 runs per point and filter" in err._suptitle.get_text()
    assert "Every point rests on 10 runs" in items["rmse_vs_comm_radius.png"].caption


@pytest.mark.xdist_group("test_honest_plots")  # one worker builds the module fixture once
def test_points_on_fewer_than_five_runs_are_hollow_and_not_joined(one_axis):
    df, items = one_axis
    ax = items["rmse_nondiverged_vs_comm_radius.png"].figure.axes[0]
    lines = _lines(ax)
    x, y = lines["kf"]
    assert list(x) == [50.0, 100.0, 150.0]  # km
    assert np.isnan(y[0]) and np.all(np.isfinite(y[1:]))  # 2 runs at 50 km: out of the line
    ok = df[~df["diverged"] & (df["filter"] == "kf")].groupby("comm_radius")["rmse"].mean()
    np.testing.assert_allclose(y[1:], ok.to_numpy()[1:], rtol=1e-12)
    hollow = _hollow(ax)
    assert len(hollow) == 1 and hollow[0][0] == 50.0
    assert hollow[0][1] == pytest.approx(ok.loc[50e3], rel=1e-12)
    x, y = lines["local"]  # 7 runs at 100 km: joined
    assert np.all(np.isfinite(y))
    assert any("< 5 runs" in t.get_text() for t in ax.get_legend().get_texts())
    assert "1 point(s) rest on fewer than 5 runs" in items["rmse_nondiverged_vs_comm_radius.png"].caption


@pytest.mark.xdist_group("test_honest_plots")  # one worker builds the module fixture once
def test_axes_in_display_units(one_axis):
    _, items = one_axis
    fig = items["divergence_vs_comm_radius.png"].figure
    fig.canvas.draw()
    ax = fig.axes[0]
    assert ax.get_xlabel() == "comm_radius [km]"
    assert [t.get_text() for t in ax.get_xticklabels()] == ["50", "100", "150"]


def test_other_axis_gets_one_panel_per_value():
    grid = {"comm_radius": [50e3, 100e3, 150e3], "eps": [0.1, 1.0]}
    df = synthetic_runs(grid, seeds=6)
    items = {i.name: i for i in plots.plots(df, _meta(grid))}
    fig = items["rmse_vs_comm_radius.png"].figure
    panels = [ax for ax in fig.axes if ax.get_visible()]
    assert [ax.get_title() for ax in panels] == ["eps = 0.1", "eps = 1"]
    for ax, eps in zip(panels, [0.1, 1.0]):
        want = df[(df["eps"] == eps) & (df["filter"] == "kf")].groupby("comm_radius")["rmse"].mean()
        np.testing.assert_allclose(_lines(ax)["kf"][1], want.to_numpy(), rtol=1e-12)
    by_eps = items["rmse_vs_eps.png"].figure
    assert [ax.get_title() for ax in by_eps.axes if ax.get_visible()] == [
        "comm_radius = 50 km", "comm_radius = 100 km", "comm_radius = 150 km"]
    for item in items.values():
        title = item.figure._suptitle.get_text() if item.figure._suptitle else item.figure.axes[0].get_title()
        assert "pooled" not in title and "pooled" not in item.caption, item.name


def test_pooling_beyond_the_panel_limit_is_said():
    grid = {"comm_radius": [50e3, 100e3], "eps": [float(v) for v in np.arange(1, plots.MAX_PANELS + 2)]}
    df = synthetic_runs(grid, seeds=5)
    items = {i.name: i for i in plots.plots(df, _meta(grid))}
    fig = items["rmse_vs_comm_radius.png"].figure
    assert len([ax for ax in fig.axes if ax.get_visible()]) == 1
    assert f"pooled over eps ({plots.MAX_PANELS + 1} eps values)" in fig._suptitle.get_text()
    assert "pooled over eps" in items["rmse_vs_comm_radius.png"].caption
    want = df[df["filter"] == "kf"].groupby("comm_radius")["rmse"].mean()  # pooled: every eps
    np.testing.assert_allclose(_lines(fig.axes[0])["kf"][1], want.to_numpy(), rtol=1e-12)


def test_three_axes_heatmap_says_what_it_pools():
    grid = {"comm_radius": [50e3, 100e3], "eps": [0.1, 1.0], "sigma_wind": [0.5, 2.0]}
    df = synthetic_runs(grid, seeds=5)
    heat = next(i for i in plots.plots(df, _meta(grid)) if i.name == "heatmap_rmse_comm_radius__eps.png")
    assert "pooled over sigma_wind (2 sigma_wind values)" in heat.figure._suptitle.get_text()
    assert "pooled over sigma_wind" in heat.caption


def test_metric_that_does_not_depend_on_the_axis_is_not_plotted_against_it():
    """The comm graph of static agents depends on the comm radius, not on the target's turn
    rate: no connectivity-vs-turn-rate plot (a flat line), and the report says why."""
    grid = {"comm_radius": [50e3, 100e3], "turn_rate": [0.01, 0.05, 0.1]}
    df = synthetic_runs(grid, seeds=6)
    rng = np.random.default_rng(1)
    per_run = {(r, s): rng.uniform(0.1, 2.0) for r in grid["comm_radius"] for s in range(6)}
    df["lambda2_mean"] = [per_run[(r, s)] * (1 + 1e-13 * t) for r, s, t in  # last-bit noise across lanes
                          zip(df["comm_radius"], df["seed_index"], df["turn_rate"])]
    df["lambda2_min"] = df["lambda2_mean"] / 2
    df["disconnected_steps"] = (df["comm_radius"] < 60e3).astype(int) * (df["seed_index"] + 1)
    items = {i.name: i for i in plots.plots(df, _meta(grid))}
    skipped = items["connectivity_vs_turn_rate.png"]
    assert isinstance(skipped, plots.Skipped)
    assert "do not depend on turn_rate" in skipped.reason
    assert isinstance(items["connectivity_vs_comm_radius.png"], plots.Plot)
    assert isinstance(items["rmse_vs_turn_rate.png"], plots.Plot)  # the error does depend on it
    assert items["rmse_vs_turn_rate.png"].figure.axes[0].get_xlabel() in ("", "turn_rate [deg/s]")


def test_heatmap_cells_on_few_runs_are_greyed_with_their_count():
    grid = {"comm_radius": [50e3, 100e3], "eps": [0.1, 1.0]}
    df = synthetic_runs(grid, seeds=6)
    df["diverged"] = False
    df.loc[(df["comm_radius"] == 50e3) & (df["eps"] == 0.1) & (df["seed_index"] < 4), "diverged"] = True
    items = {i.name: i for i in plots.plots(df, _meta(grid))}
    fig = items["heatmap_rmse_nondiverged_comm_radius__eps.png"].figure
    panels = [ax for ax in fig.axes if ax.get_title() in ("kf", "local", "ekf")]
    assert len(panels) == 3
    for ax in panels:
        image = ax.get_images()[0].get_array()
        assert np.ma.is_masked(image[0, 0]) and not np.ma.getmaskarray(image)[1:, :].any()
        texts = [t.get_text() for t in ax.texts]
        assert any(t.endswith("n=2") and t.startswith("(") for t in texts), texts


def test_single_point_bars_carry_their_counts():
    df = synthetic_runs({}, seeds=6)
    df["diverged"] = df["seed_index"] < 3
    (item,) = list(plots.plots(df, make_metadata({})))
    texts = [t.get_text() for ax in item.figure.axes for t in ax.texts]
    assert texts.count("n=6") == 6 and texts.count("n=3") == 3  # all runs, divergence; non-divergent
    assert "3 bar(s) rest on fewer than 5 runs" in item.caption
