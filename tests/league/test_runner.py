"""The league run through the study pipeline: its table, a stopped and resumed league giving the same
table as an uninterrupted one, the timing pass and the command's formats."""

import io

import pandas as pd
import pandas.testing as pdt
from click.testing import CliRunner

from mcjax.cli import main
from mcjax.league.folder import TABLE_FILE, read_league
from mcjax.league.runner import run_league
from mcjax.league.table import COLUMNS, league_text

from .conftest import TINY


def test_a_league_stopped_and_resumed_gives_the_same_table(league_file, tmp_path):
    path = league_file()
    whole = run_league(path, out_dir=tmp_path / "whole")
    assert not whole.stopped and list(whole.table.columns) == list(COLUMNS)
    t = whole.table
    assert len(t) == 2 * 2 and set(t["status"]) == {"run"} and (t["runs"] == 8).all()
    assert t.groupby("point")["rank"].min().eq(1).all()
    assert (t["rmse_low"] <= t["rmse"]).all() and (t["rmse"] <= t["rmse_high"]).all()
    assert t["unit"].eq("m/s").all() and t["error_output"].eq("rmse").all()
    leaders = t[t["rank"] == 1]
    assert (leaders["vs_best"].abs() < 1e9).all()

    written = []
    stopped = run_league(path, out_dir=tmp_path / "killed",
                         progress=lambda name, at: written.append((name, at.chunks_done)),
                         should_stop=lambda: any(done >= 1 for _, done in written))  # after the first chunk
    assert stopped.stopped and stopped.table is None
    assert not (tmp_path / "killed" / TABLE_FILE).exists()
    resumed = run_league(path, out_dir=tmp_path / "killed", resume=True)
    pdt.assert_frame_equal(resumed.table, whole.table)
    pdt.assert_frame_equal(read_league(tmp_path / "killed")[0], read_league(tmp_path / "whole")[0])


def test_the_command_times_each_filter_and_prints_every_format(league_file, tmp_path):
    path = league_file(TINY.replace("timing_runs = 0", "timing_runs = 2").replace("seeds = 8", "seeds = 4"))
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["league", str(path), "--out", str(out), "--format", "csv"])
    assert result.exit_code == 0, result.output
    csv = result.output[result.output.index("scenario,scenario_name"):]
    table = pd.read_csv(io.StringIO(csv))
    assert list(table.columns) == list(COLUMNS) and len(table) == 4
    assert (table["cost_per_run_s"] > 0).all() and table["cost_note"].eq("alone").all()
    assert table["machine"].str.contains("device").all()
    saved, meta = read_league(out)
    assert meta["seeds"] == 4 and meta["machine"] == table["machine"][0]
    text = league_text(saved, meta, "text")
    assert "rank: lowest mean error first" in text and " *" in text
    markdown = league_text(saved, meta, "markdown")
    assert "| scenario | point | filter | rank |" in markdown
    again = CliRunner().invoke(main, ["league", str(path), "--out", str(out)])
    assert again.exit_code == 2 and "already holds this league (the same file and --seeds): pass --resume" in again.output
    shown = CliRunner().invoke(main, ["report", str(out), "--markdown"])  # mcjax report leads with the table
    assert shown.exit_code == 0, shown.output
    assert shown.output.startswith(markdown.split("\n")[0]) and "| scenario | point | filter | rank |" in shown.output
    page = (out / "report" / "index.html").read_text(encoding="utf-8")
    assert "<table" in page and "tiny league" in page and page.index("<table") < page.index("</main>")

