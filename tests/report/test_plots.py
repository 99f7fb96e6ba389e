"""Tests of mcjax.report.plots: which figures a dataset gets (by its declared roles), their axis
labels (read from the matplotlib Figures: units from the metadata), PNG output, and that
pyplot's global state is never touched."""

from __future__ import annotations

import matplotlib
import matplotlib.image as mpimg
import pytest
from tests.analysis.test_tables import make_metadata, synthetic_runs

from mcjax.report import plots

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def labels(fig) -> list[str]:
    """Every axis label and title of a figure (colour bars included)."""
    out = [fig._suptitle.get_text()] if fig._suptitle is not None else []
    for ax in fig.axes:
        out += [ax.get_xlabel(), ax.get_ylabel(), ax.get_title()]
    return [t for t in out if t]


def check_png(path):
    assert path.is_file() and path.stat().st_size > 1000, path
    assert path.read_bytes()[:8] == PNG_SIGNATURE, path
    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100
    assert float(img[..., :3].std()) > 0.01, f"{path} looks blank"


def _pyplot_state():
    import matplotlib.pyplot as plt

    return matplotlib.get_backend(), list(plt.get_fignums())


def test_single_agent_no_graph_labels_in_m():
    """(a) a single-agent scenario: no connectivity columns, error in m."""
    grid = {"turn_rate": [0.0, 0.05, 0.1]}
    meta = make_metadata(grid, error="rmse", error_unit="m", graph=False)
    df = synthetic_runs(grid, seeds=6, graph=False)
    figs = dict(plots.figures(df, meta))
    assert sorted(figs) == ["divergence_vs_turn_rate.png", "rmse_nondiverged_vs_turn_rate.png",
                            "rmse_vs_turn_rate.png"]
    ax = figs["rmse_vs_turn_rate.png"].axes[0]
    assert ax.get_ylabel() == "mean rmse [m]"
    assert ax.get_xlabel() == "turn_rate [deg/s]"  # radians are shown in degrees
    assert [t.get_text() for t in ax.get_legend().get_texts()] == list(meta["filters"])
    assert figs["rmse_nondiverged_vs_turn_rate.png"].axes[0].get_ylabel() == "mean rmse, non-divergent runs [m]"
    assert figs["divergence_vs_turn_rate.png"].axes[0].get_ylabel() == "divergence rate (% of runs)"


def test_error_in_m_per_s_never_labelled_m():
    """(b) an error metric in m/s: every label of every figure says m/s, none says [m]."""
    grid = {"sigma_wind": [0.5, 1.0, 2.0], "comm_range": [1.0, 3.0]}
    meta = make_metadata(grid, error="wind_rmse", error_unit="m/s")
    df = synthetic_runs(grid, seeds=3, error="wind_rmse")
    figs = dict(plots.figures(df, meta))
    assert {"wind_rmse_vs_sigma_wind.png", "connectivity_vs_comm_range.png",
            "heatmap_wind_rmse_sigma_wind__comm_range.png"} <= set(figs)
    assert figs["wind_rmse_vs_sigma_wind.png"].axes[0].get_ylabel() == "mean wind_rmse [m/s]"
    assert figs["wind_rmse_vs_sigma_wind.png"].axes[0].get_xlabel() == "sigma_wind [m/s]"
    assert figs["wind_rmse_vs_comm_range.png"].axes[0].get_xlabel() == "comm_range [km]"
    heat = labels(figs["heatmap_wind_rmse_sigma_wind__comm_range.png"])
    assert "mean wind_rmse [m/s]" in heat and "sigma_wind [m/s]" in heat and "comm_range [km]" in heat
    everything = [t for f in figs.values() for t in labels(f)]
    assert not any("[m]" in t for t in everything), [t for t in everything if "[m]" in t]
    assert sum("[m/s]" in t for t in everything) >= 10


def test_no_divergence_flag_no_divergence_plots():
    grid = {"eps": [0.001, 0.01, 0.1, 1.0]}
    meta = make_metadata(grid, divergence=False, nonfinite=False)
    df = synthetic_runs(grid, seeds=3, divergence=False, nonfinite=False)
    figs = dict(plots.figures(df, meta))
    assert sorted(figs) == ["connectivity_vs_eps.png", "rmse_vs_eps.png"]
    ax = figs["rmse_vs_eps.png"].axes[0]
    assert ax.get_xscale() == "log" and ax.get_xlabel() == "eps"  # no unit: no brackets
    conn = figs["connectivity_vs_eps.png"]
    assert [a.get_ylabel() for a in conn.axes] == ["lambda2_mean / lambda2_min", "mean disconnected_steps\nper run"]


@pytest.mark.parametrize("divergence", [True, False])
def test_single_point_bar_plot(divergence):
    meta = make_metadata({}, error="wind_rmse", error_unit="m/s", divergence=divergence, nonfinite=divergence)
    df = synthetic_runs({}, seeds=6, error="wind_rmse", divergence=divergence, nonfinite=divergence)
    ((name, fig),) = list(plots.figures(df, meta))
    assert name == "summary_bars.png"
    assert len(fig.axes) == (2 if divergence else 1)
    assert fig.axes[0].get_ylabel() == "mean wind_rmse [m/s]"
    assert [t.get_text() for t in fig.axes[0].get_xticklabels()] == list(meta["filters"])


def test_make_plots_writes_pngs_without_pyplot(tmp_path):
    grid = {"comm_radius": [50.0, 100.0]}
    meta = make_metadata(grid)
    df = synthetic_runs(grid, seeds=3)
    before = _pyplot_state()
    paths = plots.make_plots(df, meta, tmp_path)
    assert _pyplot_state() == before  # no backend switch, no open pyplot figures
    assert [p.name for p in paths] == ["rmse_vs_comm_radius.png", "rmse_nondiverged_vs_comm_radius.png",
                                       "divergence_vs_comm_radius.png", "connectivity_vs_comm_radius.png"]
    assert all(p.parent == tmp_path / "report" for p in paths)
    for p in paths:
        check_png(p)


def test_x_axis_scales_and_colours():
    assert plots.x_axis("eps", [0.001, 0.01, 0.1, 1.0]).log
    assert not plots.x_axis("r", [50e3, 100e3]).log
    assert not plots.x_axis("h", [-1.0, 0.01, 1.0]).log
    cat = plots.x_axis("pos", [(0.0, 1.0), (2.0, 3.0)])
    assert not cat.numeric and list(cat.x([(2.0, 3.0)])) == [1.0]
    colors = plots.filter_colors(["zz", "local", "kf", "aa"], ["kf", "local", "ekf"])
    assert colors == {"zz": plots.PALETTE[4], "local": plots.PALETTE[1], "kf": plots.PALETTE[0],
                      "aa": plots.PALETTE[3]}


def test_figures_errors():
    meta = make_metadata({"eps": [1.0]})
    with pytest.raises(ValueError, match="empty"):
        list(plots.figures(synthetic_runs({}, seeds=1).iloc[:0], meta))
    with pytest.raises(ValueError, match="older mcjax"):
        list(plots.figures(synthetic_runs({}, seeds=1), {"spec": {}}))


@pytest.mark.parametrize("scale, expected", [(30.0, "log"), (5.0, "linear")])
def test_the_error_axis_is_logarithmic_when_its_means_span_more_than_a_decade(scale, expected):
    """735 m beside 11 m on a linear axis flattens every value but the largest: past a decade
    (the ratio of the largest to the smallest plotted mean > 10) the y axis is logarithmic."""
    grid = {"eps": [0.1, 1.0]}
    df = synthetic_runs(grid, seeds=8, divergence=False)
    df["rmse"] = 10.0 * (1 + 0.01 * df["seed_index"]) * df["eps"].map({0.1: scale, 1.0: 1.0})
    figs = dict(plots.figures(df, make_metadata(grid, divergence=False)))
    assert figs["rmse_vs_eps.png"].axes[0].get_yscale() == expected


def test_plots_are_written_at_twice_the_layout_resolution(tmp_path):
    grid = {"eps": [0.1, 1.0]}
    written, _ = plots.write_plots(synthetic_runs(grid, seeds=6), make_metadata(grid), tmp_path)
    for p in written:
        data = p.path.read_bytes()
        width = int.from_bytes(data[16:20], "big")
        fig = dict(plots.figures(synthetic_runs(grid, seeds=6), make_metadata(grid)))[p.path.name]
        assert abs(width - 2 * fig.get_figwidth() * fig.dpi) <= 2, (p.path.name, width)
