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
    # the legend wraps (a list, not a box that scrolls sideways), then the table, the sweeps, the provenance
    assert "<pre" not in page and page.index('<ul class="legend">') < page.index("<table")
    assert "filter alone" in page and "load average" in page
    import re

    links = re.findall(r'<a href="([^"]+)">', page[page.index('id="sweeps"'):])
    assert len(links) == 2 and all((out / "report" / href).resolve() in {(out / "wind" / p).resolve() for p in
                                                                        ("none", "iid")} for href in links)
    provenance = page[page.index('id="provenance"'):]
    assert "git revision of mcjax" in provenance and str(path) in provenance



#: The league table's columns that are measurements of this machine's clock.
MEASURED = ["cost_per_run_s", "cost_low", "cost_high"]


def test_the_timing_pass_times_three_repeats_and_a_league_stopped_in_it_resumes(league_file, tmp_path):
    """timing_runs = 6 with 8 runs per cell: 3 timed repeats of 2 runs per filter, after one untimed;
    the progress counts every repeat (2 filters x 4); the table's cost is the median of timing.json's
    repeats, its range their lowest and highest. Stopped in the timing pass, the league resumes to the
    table of one run straight through but for the measured columns, the filter timed before the stop
    keeping what was measured."""
    import json
    import statistics

    path = league_file(TINY.replace("timing_runs = 0", "timing_runs = 6"))
    ticks = []
    whole = run_league(path, out_dir=tmp_path / "whole", progress=lambda name, at: ticks.append((name, at)))
    timed = [(at.chunks_done, at.chunks, at.runs_done) for name, at in ticks if name == "timing wind"]
    assert timed == [(i, 8, 2 * i) for i in range(9)]
    saved = json.loads((tmp_path / "whole" / "timing.json").read_text(encoding="utf-8"))
    assert (saved["repeats"], saved["repeat_runs"]) == (3, 2)
    t = whole.table.set_index(["point", "filter"])
    for f in ("kcf", "local"):
        seconds = saved["costs"]["wind"][f]["seconds"]
        assert len(seconds) == 3 and all(s > 0 for s in seconds)
        for point in ("none", "iid"):
            assert t.loc[(point, f), "cost_per_run_s"] == statistics.median(seconds)
            assert (t.loc[(point, f), "cost_low"], t.loc[(point, f), "cost_high"]) == (min(seconds), max(seconds))
    meta = read_league(tmp_path / "whole")[1]
    assert meta["timing"]["repeats"] == 3 and meta["timing"]["repeat_runs"] == 2

    seen = []
    stopped = run_league(path, out_dir=tmp_path / "killed", progress=lambda name, at: seen.append((name, at)),
                         should_stop=lambda: any(n == "timing wind" and at.chunks_done >= 5 for n, at in seen))
    assert stopped.stopped and not (tmp_path / "killed" / TABLE_FILE).exists()
    kept = json.loads((tmp_path / "killed" / "timing.json").read_text(encoding="utf-8"))["costs"]["wind"]
    assert list(kept) == ["kcf"]            # local was stopped in its second repeat
    resumed = run_league(path, out_dir=tmp_path / "killed", resume=True)
    pdt.assert_frame_equal(resumed.table.drop(columns=MEASURED), whole.table.drop(columns=MEASURED))
    kcf = resumed.table[resumed.table["filter"] == "kcf"]
    assert (kcf["cost_per_run_s"] == statistics.median(kept["kcf"]["seconds"])).all()


def test_a_stop_in_the_timing_pass_does_not_wait_for_the_repeat_in_flight():
    """The repeat runs in a thread of its own: a stop is acted on while it still runs (here: it waits
    for an event the test sets only afterwards); an error of the repeat reaches the caller."""
    import threading

    import pytest

    from mcjax.league.timing import run_unless_stopped

    release, asked = threading.Event(), []
    assert run_unless_stopped(lambda: release.wait(60), lambda: asked.append(1) or len(asked) >= 2) is False
    assert not release.is_set()      # returned while the repeat was still in flight
    release.set()
    assert run_unless_stopped(lambda: None, lambda: False) is True

    def fails():
        raise RuntimeError("a chunk failed")

    with pytest.raises(RuntimeError, match="a chunk failed"):
        run_unless_stopped(fails, lambda: False)


def test_the_warm_up_compiles_every_filter_still_to_time_and_skips_those_timed(league_file):
    """The untimed repeats run in the background (beside the sweeps): every filter of the tiny league
    warmed on 2 runs, none of those a saved timing.json holds with the same repeats."""
    from mcjax.league.spec import load_league
    from mcjax.league.timing import REPEATS, Warmup

    league = load_league(league_file(TINY.replace("timing_runs = 0", "timing_runs = 6")))
    warm = Warmup(league, {})
    assert warm.wait(lambda: False) and warm.pending() == 0
    assert all(warm.ready("wind", f)[0].n_runs == 2 and warm.ready("wind", f)[1] == "alone" for f in ("kcf", "local"))
    saved = {"repeat_runs": 2, "repeats": REPEATS, "costs": {"wind": {"kcf": {"seconds": [1, 1, 1], "note": "alone"}}}}
    part = Warmup(league, saved)
    assert part.wait(lambda: False) and part.ready("wind", "kcf") is None and part.ready("wind", "local") is not None
    other = Warmup(league, {**saved, "repeat_runs": 5})   # other repeats: timed again
    assert other.wait(lambda: False) and other.ready("wind", "kcf") is not None
