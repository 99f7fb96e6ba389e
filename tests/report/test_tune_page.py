"""mcjax report on a tune's folder (mcjax.report.tune_page): its own page with the trace, the initial
and tuned values and the held-out comparison paired by seed (checked against scipy's paired
t interval), no sweep plots; which point is initial is read from what the folder records,
never from the row order alone. And mcjax report on a folder of datasets lists them."""

from __future__ import annotations

import base64
import json

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from scipy import stats
from tests.analysis.test_tables import make_metadata, synthetic_runs, write_dataset
from tests.report.test_html_page import parse

from mcjax.cli import main
from mcjax.report import tune_page

DESCRIPTION = "A toy tune — held-out evaluation of mcjax tune: point 0 = initial, point 1 = tuned Params"


def _tune_folder(out, *, role=True, trace=True, description=DESCRIPTION, values=(0.5, 0.2), seeds=20):
    """A tune's folder as mcjax tune writes it: the evaluation (eps zipped over initial, tuned),
    tune.json, trace.parquet and trace.png."""
    meta = make_metadata(zipped={"eps": list(values)})
    meta["spec"]["description"] = description
    df = synthetic_runs({"eps": list(values)}, seeds=seeds)
    first = df[df["point_id"] == 0].set_index(["seed_index", "filter"])["rmse"]
    tuned = df["point_id"] == 1  # the tuned point tracks 10 % better, seed by seed
    df.loc[tuned, "rmse"] = 0.9 * first.loc[list(zip(df.loc[tuned, "seed_index"], df.loc[tuned, "filter"]))].to_numpy()
    if role:
        df.insert(df.columns.get_loc("filter"), "role", np.where(df["point_id"] == 0, "initial", "tuned"))
    write_dataset(out, df, meta)
    (out / "tune.json").write_text(json.dumps({"spec": {"base": "x.toml", "tune": {
        "steps": 3, "params": {"eps": {"low": 0.01, "high": 1.0, "scale": "log"}}}}}))
    if trace:
        pd.DataFrame({"step": [0, 1, 2, 3], "loss": [1.0, 0.7, 0.6, 0.55],
                      "eps": [values[0], 0.4, 0.3, values[1]]}).to_parquet(out / "trace.parquet")
        fig = Figure(figsize=(3, 2))
        FigureCanvasAgg(fig)
        fig.subplots().plot([0, 1, 2, 3], [1.0, 0.7, 0.6, 0.55])
        fig.savefig(out / "trace.png")
    return df, meta


def test_a_tune_gets_its_own_page_and_no_sweep_plots(tmp_path):
    out = tmp_path / "tune"
    df, _ = _tune_folder(out)
    r = CliRunner().invoke(main, ["report", str(out)])
    assert r.exit_code == 0, r.output
    table = [line.split() for line in r.output.splitlines() if line.split()[:1] in (["role"], ["initial"], ["tuned"])]
    assert table[0][:3] == ["role", "eps", "filter"] and [row[0] for row in table[1:]] == ["initial"] * 3 + ["tuned"] * 3
    assert [row[1] for row in table[1:]] == ["0.5"] * 3 + ["0.2"] * 3
    written = sorted(p.name for p in (out / "report").iterdir())
    assert written == ["index.html"]  # no sweep plots of the two-point zip
    page = parse(out / "report" / "index.html")
    headings = [" ".join(t.split()) for t in page.text.get("h2", [])]
    assert headings[:4] == ["What this shows", "Initial and tuned values", "Optimisation trace",
                            "Held-out comparison"], headings
    # the trace figure, embedded: the very bytes of trace.png
    srcs = [a["src"] for tag, a in page.tags if tag == "img"]
    assert [base64.b64decode(s.removeprefix("data:image/png;base64,")) for s in srcs] == [
        (out / "trace.png").read_bytes()]
    values = next(t for t in page.tables if t and t[0][:3] == ["Param", "initial", "tuned"])
    assert values[1][:3] == ["eps", "0.5", "0.2"]
    comparison = next(t for t in page.tables if t and t[0][:2] == ["filter", "output"])
    assert [row[:2] for row in comparison[1:]] == [[f, o] for f in ("kf", "local", "ekf")
                                                   for o in ("rmse", "diverged")]
    # tuned − initial, paired by seed: scipy's paired t interval, independently
    for row in comparison[1:]:
        f, o = row[:2]
        g = df[df["filter"] == f].sort_values("seed_index")
        a = g[g["point_id"] == 0][o].astype(float).to_numpy()
        b = g[g["point_id"] == 1][o].astype(float).to_numpy()
        if o == "rmse":
            ci = stats.ttest_rel(b, a).confidence_interval(0.95)
            m = f"{np.mean(b - a):.4g}"
            assert row[4].startswith(m) and f"{ci.low:.4g}" in row[4] and f"{ci.high:.4g}" in row[4], (row, ci)
        else:
            assert row[4].endswith("]") and "percentage points" in row[4], row
    sentences = " ".join(page.text.get("li", []))
    assert "the tuned Params lower kf's mean rmse" in sentences, sentences
    assert "no change of kf's divergence rate beyond the 95 % interval" in sentences, sentences


def test_which_point_is_initial_comes_from_what_the_folder_records(tmp_path):
    df, meta = _tune_folder(tmp_path / "a", role=False)
    assert tune_page.roles(tmp_path / "a", df, meta) == (
        {0: "initial", 1: "tuned"}, "each point's values matched to the trace's first (initial) and last (tuned) values")
    # the trace decides, not the row order: a trace that ran from 0.2 to 0.5 makes point 1 the initial one
    pd.DataFrame({"step": [0, 1], "loss": [1.0, 0.5], "eps": [0.2, 0.5]}).to_parquet(tmp_path / "a" / "trace.parquet")
    assert tune_page.roles(tmp_path / "a", df, meta)[0] == {0: "tuned", 1: "initial"}
    r = CliRunner().invoke(main, ["report", str(tmp_path / "a"), "--no-plots"])  # the printed table says it too
    assert [line.split()[:2] for line in r.output.splitlines() if line.split()[:1] in (["initial"], ["tuned"])] == [
        ["initial", "0.2"]] * 3 + [["tuned", "0.5"]] * 3, r.output
    df, meta = _tune_folder(tmp_path / "b", role=False, trace=False)
    assert tune_page.roles(tmp_path / "b", df, meta)[1].startswith("the evaluation's description")
    df, meta = _tune_folder(tmp_path / "c", role=False, trace=False, description="something else")
    with pytest.raises(ValueError, match="cannot tell which point"):
        tune_page.roles(tmp_path / "c", df, meta)
    r = CliRunner().invoke(main, ["report", str(tmp_path / "c")])
    assert r.exit_code == 2 and "cannot tell which point" in r.output, r.output
    df, meta = _tune_folder(tmp_path / "d")
    assert tune_page.roles(tmp_path / "d", df, meta)[1] == "the dataset's role column"
    bad = df.assign(role="initial")
    with pytest.raises(ValueError, match="two roles or an unknown role"):
        tune_page.roles(tmp_path / "d", bad.assign(role=np.where(bad["seed_index"] == 0, "tuned", "initial")), meta)


def test_report_on_a_folder_of_datasets_lists_them(tmp_path):
    for name, grid in (("first", {"eps": [0.1, 1.0]}), ("second", {"comm_radius": [5e4, 1e5]})):
        meta = make_metadata(grid)
        meta["spec"]["description"] = f"the {name} sweep"
        meta["n_runs"] = 8
        write_dataset(tmp_path / "results" / name, synthetic_runs(grid, seeds=4), meta)
    (tmp_path / "results" / "notes").mkdir()  # not a dataset: not listed
    r = CliRunner().invoke(main, ["report", str(tmp_path / "results")])
    assert r.exit_code == 0, r.output
    lines = r.output.splitlines()
    assert lines[0] == f"{tmp_path / 'results'} holds 2 dataset(s), not one; report on one of them:"
    assert lines[1].split("#")[0].strip() == f"mcjax report {tmp_path / 'results' / 'first'}"
    assert "toy; 8 runs planned; the first sweep" in lines[1] and "the second sweep" in lines[2]
    assert not (tmp_path / "results" / "report").exists()
    r = CliRunner().invoke(main, ["report", str(tmp_path / "results" / "notes")])
    assert r.exit_code == 2 and "no runs found" in r.output
