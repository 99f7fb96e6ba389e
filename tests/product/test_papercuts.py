"""The first hour's papercuts stay fixed: a fresh clone's datasets say "no uncommitted changes" with the
README's .venv in it; a folder left by a sweep that wrote nothing is reused without --force; one warning
without mcjax.configure(); no undated timing in a sweep file's comments; the stored-program warning reads
as English. Issue 61's: the README states the divergence rule the code applies and the suite's size and
time once, dated; an xdist worker ends before execnet interrupts it; an unknown key's line is short; a
wrong kind says what it got; a spec's mistakes one per line; a complete dataset run again is told so.
Issue 67's: `pytest -q` ends with its pass count; a report of a missing folder and a mistyped path get the
name meant; a resumed complete sweep prints no rate; check and league say which --resume applies; a
claims file's wrong kind reads as a spec's; the table and the page agree on an angle's unit; a check's
sweep page says what it is for, keeps n off the caps and draws no empty divergence bars (the default
page's λ2 and repeated intervals: tests/analysis/test_connectivity.py)."""

import gc
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from click.testing import CliRunner

from mcjax import runtime
from mcjax.cli import main
from mcjax.study import OutputError, load_spec, prepare_output

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_a_fresh_clone_with_its_venv_and_results_is_clean(tmp_path):
    """The README makes .venv in the checkout and writes results/: neither makes git report a change."""
    repo = tmp_path / "clone"
    repo.mkdir()
    shutil.copy(ROOT / ".gitignore", repo / ".gitignore")

    def git(*args):
        return subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args], cwd=repo, check=True,
                              capture_output=True, text=True).stdout

    git("init", "-q")
    git("add", ".gitignore")
    git("commit", "-qm", "init")
    for path in (".venv/bin/python", "results/default/runs/part.parquet", "mcjax.egg-info/PKG-INFO"):
        (repo / path).parent.mkdir(parents=True, exist_ok=True)
        (repo / path).write_text("x")
    assert git("status", "--porcelain") == ""


def _study(out):
    return load_spec(ROOT / "sweeps" / "floors.toml", seeds=2, out_dir=out,
                     overrides={"base": "../configs/chen2013.toml", "config.wind_noise": "gaussian"})


def test_a_folder_left_by_a_sweep_that_wrote_nothing_is_reused(tmp_path):
    out = tmp_path / "out"
    (out / "runs").mkdir(parents=True)
    (out / "sweep.json").write_text("{}")
    said = []
    assert prepare_output(_study(out), out, note=said.append) is None
    assert said == [f"{out} held only the identity file of a sweep that wrote nothing; reusing it"]
    assert (out / "sweep.json").read_text() != "{}"  # this sweep's identity now
    # a folder with a part in it is still refused without --force or --resume
    (out / "runs" / "point_id=0").mkdir(parents=True)
    (out / "runs" / "point_id=0" / "part-000000.parquet").write_bytes(b"PAR1")
    with pytest.raises(OutputError, match="not empty"):
        prepare_output(_study(out), out)


def test_one_warning_without_configure(tmp_path):
    """docs/library.md's example without mcjax.configure(): the one warning the docs promise, not JAX's too."""
    text = (ROOT / "docs" / "library.md").read_text(encoding="utf-8")
    code = re.search(r"```python\n(.*?)```", text, flags=re.S).group(1).replace("mcjax.configure()", "pass")
    script = tmp_path / "example.py"
    script.write_text(code, encoding="utf-8")
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300,
                          env={"PATH": "/usr/bin:/bin", "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu"})
    assert done.returncode == 0, done.stderr
    warnings = [line for line in done.stderr.splitlines() if "Warning" in line]
    assert len(warnings) == 1 and "mcjax.configure()" in warnings[0], done.stderr


def test_no_undated_timing_in_a_sweep_files_comments():
    """A measured duration in a comment block of sweeps/*.toml (a time with "took", "takes", a compile, a
    machine) comes with the date it was measured."""
    duration = re.compile(r"\b\d+(\.\d+)?\s?(s|min|minutes|seconds|h|hours)\b")
    measured = re.compile(r"took|takes|compil|machine|\bVM\b|load average|wall")
    date = re.compile(r"20\d\d-\d\d-\d\d")
    for spec in sorted((ROOT / "sweeps").glob("*.toml")):
        blocks, block = [], []
        for line in spec.read_text(encoding="utf-8").splitlines():
            comment = line.split("#", 1)[1] if "#" in line else None
            if comment is None:
                if block:
                    blocks.append(" ".join(block))
                block = []
            else:
                block.append(comment)
        blocks.append(" ".join(block))
        for text in blocks:
            if duration.search(text) and measured.search(text):
                assert date.search(text), (spec.name, text)


def test_the_stored_program_warning_reads_as_english(tmp_path, capsys):
    folder = tmp_path / "store"
    folder.mkdir(mode=0o700)
    path = folder / f"program-{'0' * 64}.bin"
    path.write_bytes(b"altered")
    path.chmod(0o600)
    data, why = runtime.trusted_read(path)
    assert data is None
    runtime.distrust(path, why)
    err = capsys.readouterr().err
    assert f"{path}: it does not match the hash recorded when it was written" in err
    assert "it its" not in err


def test_library_md_states_run_filters_conventions():
    """The state order, the bearing convention and why run_filter's icf_variant default differs from the
    paper's config are in docs/library.md's prose (they were only in docstrings)."""
    text = (ROOT / "docs" / "library.md").read_text(encoding="utf-8")
    assert "`[x, ẋ, y, ẏ]`" in text and "atan2(y − s_y, x − s_x)" in text
    default = re.search(r'icf_variant: str = "(\w+)"', (ROOT / "mcjax" / "tracking" / "filters" / "recorded.py").read_text())
    paper = re.search(r'icf_variant = "(\w+)"', (ROOT / "configs" / "sun2011.toml").read_text())
    assert default and paper and default.group(1) != paper.group(1)
    assert f'`icf_variant =\n"{default.group(1)}"`' in text or f'`icf_variant = "{default.group(1)}"`' in text
    assert f'`"{paper.group(1)}"`' in text


def test_the_readme_states_the_divergence_rule_the_code_applies():
    """`div_rate`'s sentence: the error passed the threshold at any step after the warm-up (not "ended"), with
    the default sweep's threshold and warm-up; and the rule is that: an error that passes and comes back counts."""
    import jax.numpy as jnp

    from mcjax.tracking.metrics import diverged

    text = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    sentence = re.search(r"`div_rate` is the share of runs in which (.*?)\. ", text).group(1)
    config = tomllib.loads((ROOT / "configs" / "sun2011.toml").read_text(encoding="utf-8"))["config"]
    assert f"more than {config['divergence_threshold'] / 1000:g} km off at any step after the " \
           f"{config['warmup_steps']} warm-up steps" in sentence, sentence
    assert "ended" not in sentence and "not finite" in sentence, sentence
    errors = jnp.array([[5000.0], [10.0], [1500.0], [10.0]])  # (steps, agents): off at step 2, back by the end
    assert bool(diverged(errors, 1000.0, warmup=1)) and not bool(diverged(errors, 1000.0, warmup=3))


def test_the_readme_states_the_suites_size_and_time_once_with_its_date():
    """One place in the README says how many tests the suite has and how long it took, with its date (the
    other copies went stale); pyproject.toml's comment points there."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    counts = re.findall(r"(?<!-n )\b\d[\d,]* tests\b", text)  # not `pytest -n 2 tests/…`
    assert len(counts) == 1, counts
    sentence = next(s for s in " ".join(text.split()).split(". ") if counts[0] in s)
    assert re.search(r"20\d\d-\d\d-\d\d", sentence) and re.search(r"\d+ min", sentence), sentence
    assert "README: one place" in (ROOT / "pyproject.toml").read_text(encoding="utf-8")


def test_an_xdist_worker_ends_before_execnet_interrupts_it():
    """The green run ended with a KeyboardInterrupt traceback in XLA's garbage-collection callback: once every
    worker has finished, execnet gives each 5 s to end, then sends it a SIGINT, and a worker spent them in
    pytest's five full collections of its heap (reproduced with 8 million objects held in each worker). A
    worker now collects once before it reports it has finished and freezes the rest (tests/conftest.py), so
    those collections traverse only what is newer; the controller's own session is left alone."""
    from tests import conftest

    class Session:
        def __init__(self, worker: bool):
            self.config = type("Config", (), {"workerinput": {}} if worker else {})()

    held = [[i] for i in range(50_000)]  # objects alive at the session's end
    try:
        conftest.pytest_sessionfinish(Session(worker=False))
        assert gc.get_freeze_count() == 0
        conftest.pytest_sessionfinish(Session(worker=True))
        assert gc.get_freeze_count() > len(held)
        assert not {id(x) for x in held[:100]} & {id(x) for x in gc.get_objects()}  # no collection traverses them
    finally:
        gc.unfreeze()


def _spec(tmp_path, body: str = "") -> Path:
    spec = tmp_path / "spec.toml"
    spec.write_text(f'base = "{ROOT / "configs" / "sun2011.toml"}"\nseeds = 2\n{body}', encoding="utf-8")
    return spec


def _refusal(spec: Path, *args: str) -> list[str]:
    r = CliRunner().invoke(main, ["sweep", str(spec), "--dry-run", *args])
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    return r.output.splitlines()


def test_an_unknown_keys_line_is_short(tmp_path):
    """Not every one of a scenario's 32 Params on one line: the closest names and where to see them all."""
    lines = _refusal(_spec(tmp_path, "[params]\nsigma_rang = 20.0\n"))
    assert lines == ["error: params.sigma_rang: unknown key (did you mean 'sigma_range'?); also close: sigma_bearing, "
                     "sigma_accel; all 32 listed by `mcjax list leader_follower`"], lines
    assert len(lines[0]) <= 160
    listed = CliRunner().invoke(main, ["list", "leader_follower"]).output
    assert "sigma_bearing" in listed and "alpha_phi" in listed  # where it says they are
    # a short list of keys is still given whole
    assert _refusal(_spec(tmp_path, "sedes = 3\n"))[0].endswith(
        "allowed: scenario, base, seeds, base_seed, chunk_size, config, params, grid, zip, description, timeseries, "
        "sensitivity")


def test_a_wrong_kind_says_what_it_got(tmp_path):
    lines = _refusal(_spec(tmp_path, '[params]\ncomm_radius = "100e3"\n'))
    assert lines[0].endswith("got the string '100e3' (a number is written without quotes: 100e3)"), lines
    assert _refusal(_spec(tmp_path, "[config]\nn_steps = true\n"))[0].endswith("got the boolean true")
    assert _refusal(_spec(tmp_path, "timeseries = \"yes\"\n"))[0] == \
        "error: timeseries: must be true or false; got the string 'yes'"


def test_a_spec_with_several_mistakes_lists_each_on_its_own_line(tmp_path):
    """Every independent mistake, one line each, exit 2: an unknown key in [config], a bad value in [params]
    (and another), a bad axis, a bad seed count; the checks across values wait until those are right."""
    spec = _spec(tmp_path, 'chunk_size = 0\n[config]\nn_agnts = 4\n[params]\ncomm_radius = "100e3"\n'
                           'sigma_range = -1.0\n[grid]\nsigma_bearing = []\n')
    lines = _refusal(spec)
    assert [line.split(":")[1].strip() for line in lines] == [
        "config.n_agnts", "params.comm_radius", "params.sigma_range", "grid.sigma_bearing", "chunk_size"], lines
    assert all(line.startswith("error: ") for line in lines)
    # from Python, the same mistakes in one SpecError, one per line, the arguments named as written
    import mcjax.notebook as mc

    with pytest.raises(mc.SpecError) as caught:
        mc.sweep(spec, seeds=0, chunk_size=0, set={"params.sigma_accel": "x"})
    assert [line.split(":")[0] for line in str(caught.value).splitlines()] == [
        "config.n_agnts", "params.comm_radius", "params.sigma_range", "params.sigma_accel", "grid.sigma_bearing",
        "seeds", "chunk_size"], str(caught.value)


def test_a_complete_dataset_run_again_is_told_it_is_complete(tmp_path):
    """Not "pass --resume to finish it": it is finished. An unfinished one is told --resume, another sweep
    --force; exit 2 each, nothing written."""
    spec = tmp_path / "tiny.toml"
    spec.write_text(f'base = "{ROOT / "configs" / "chen2013.toml"}"\nseeds = 3\nchunk_size = 3\n'
                    "[grid]\neta = [0.0, 0.01]\n", encoding="utf-8")
    out = tmp_path / "out"
    study = load_spec(spec, out_dir=out)
    prepare_output(study, out, spec_file=spec)
    from mcjax.study.rows import chunk_parts

    parts = [part for i, (a, b) in enumerate(study.plan) for part in chunk_parts(study, i, a, b)]
    for part in parts:  # the names are what marks a chunk written
        (out / "runs" / f"{part}.parquet").parent.mkdir(parents=True, exist_ok=True)
        (out / "runs" / f"{part}.parquet").write_bytes(b"PAR1")

    def again(*args):
        r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out), *args])
        assert r.exit_code == 2, r.output
        return r.output.strip()

    n = len(study.plan)
    assert again() == (f"error: output folder {out} already holds this sweep, complete ({n} of {n} chunk(s) written): "
                       f"`mcjax report {out}` reads it; pass --force to run it again, or choose another --out")
    assert re.search(r"holds another sweep \(.*seeds differ\); pass --force to replace it", again("--seeds", "4"))
    (out / "runs" / f"{parts[-1]}.parquet").unlink()
    assert f"it holds this sweep, {n - 1} of {n} chunk(s) written; pass --resume to finish it" in again()
    assert len(list(out.rglob("*.parquet"))) == len(parts) - 1  # nothing written


# ---------------------------------------------------------------- issue 67, item 7

def test_pytest_q_ends_with_its_pass_count(tmp_path):
    """addopts held -q, so `pytest -q` was -qq and printed no "N passed" line at the end."""
    (tmp_path / "test_tiny.py").write_text("def test_one():\n    pass\n\n\ndef test_two():\n    pass\n")
    done = subprocess.run([sys.executable, "-m", "pytest", "-c", str(ROOT / "pyproject.toml"), "--rootdir", str(ROOT),
                           "-q", "-n", "0", "-p", "no:cacheprovider", str(tmp_path / "test_tiny.py")],
                          capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert done.returncode == 0, done.stdout + done.stderr
    assert re.match(r"2 passed in [\d.]+s", done.stdout.strip().splitlines()[-1]), done.stdout


def _error(*args: str, cwd: Path | None = None) -> str:
    """The one line a refused command prints (exit 2, no traceback), from ``cwd``."""
    import os

    here = Path.cwd()
    try:
        if cwd is not None:
            os.chdir(cwd)
        r = CliRunner().invoke(main, list(args))
    finally:
        os.chdir(here)
    assert r.exit_code == 2 and "Traceback" not in r.output, r.output
    assert len(r.output.strip().splitlines()) == 1, r.output
    return r.output.strip()


def test_report_of_a_folder_that_does_not_exist_says_so(tmp_path):
    """Not "no runs found" in a folder that is not there: that it does not exist, and the sibling meant."""
    (tmp_path / "results" / "default").mkdir(parents=True)
    (tmp_path / "results" / "other_sweep").mkdir()
    assert _error("report", "results/defualt", cwd=tmp_path) == \
        "error: folder results/defualt does not exist; did you mean results/default?"
    assert _error("report", "results/zzz", cwd=tmp_path) == "error: folder results/zzz does not exist"
    assert not (tmp_path / "results" / "defualt").exists()
    # a folder that is there but holds no runs is still told that
    assert "no runs found" in _error("report", "results/default", cwd=tmp_path)


def test_a_config_path_with_a_typo_gets_the_file_it_meant(tmp_path):
    """`mcjax run configs/sun2011.tom`, a spec's base and a spec's own path: the file beside it with the
    closest name."""
    (tmp_path / "configs").mkdir()
    shutil.copy(ROOT / "configs" / "sun2011.toml", tmp_path / "configs" / "sun2011.toml")
    shutil.copy(ROOT / "configs" / "ren2017.toml", tmp_path / "configs" / "ren2017.toml")
    assert _error("run", "configs/sun2011.tom", cwd=tmp_path) == \
        "error: config file not found: configs/sun2011.tom; did you mean configs/sun2011.toml?"
    assert _error("run", "configs/nothing_like_it.toml", cwd=tmp_path) == \
        "error: config file not found: configs/nothing_like_it.toml"
    (tmp_path / "sweeps").mkdir()
    (tmp_path / "sweeps" / "mine.toml").write_text('base = "../configs/sun2011.tom"\nseeds = 2\n', encoding="utf-8")
    assert _error("sweep", "sweeps/mine.toml", "--dry-run", cwd=tmp_path) == (
        f"error: base: config file not found: {tmp_path / 'configs' / 'sun2011.tom'}; did you mean "
        f"../configs/sun2011.toml?")
    assert _error("sweep", "sweeps/mien.toml", "--dry-run", cwd=tmp_path) == \
        "error: sweep spec not found: sweeps/mien.toml; did you mean sweeps/mine.toml?"


def test_a_sweeps_printed_table_and_its_page_agree_on_the_unit_and_the_legend_names_only_its_columns(tmp_path):
    """turn_rate was printed in rad/s (0.0523599) while the page and the plots showed deg/s (3); the legend
    defined anees, which the table does not show. Now the printed table and both of the page's tables show an
    angle in degrees, and every metric the legend names is a column."""
    import math

    from tests.analysis.test_tables import make_metadata, synthetic_runs, write_dataset

    grid = {"turn_rate": [math.radians(3.0), math.radians(6.0)]}
    meta = make_metadata(grid)
    meta["outputs"]["anees"] = {"unit": "", "description": "mean NEES over the run", "per_filter": True,
                                "role": "nees"}
    out = write_dataset(tmp_path / "turn", synthetic_runs(grid, seeds=4).assign(anees=4.0), meta)
    r = CliRunner().invoke(main, ["report", str(out)])
    assert r.exit_code == 0, r.output
    legend, _, table = r.output.partition("\n\n")
    header, *rows = table.splitlines()
    assert header.split()[:2] == ["turn_rate", "filter"]
    assert sorted({row.split()[0] for row in rows if row.split()[1:2] and row.split()[1] in meta["filters"]}) == \
        ["3", "6"]
    assert "turn_rate: deg/s (stored as rad/s) — target turn rate" in legend.splitlines()
    named = [line.split(":")[0] for line in legend.splitlines()[1:-1]]  # between the scenario and the statistics
    assert named == ["rmse", "diverged", "nonfinite", "lambda2_mean", "lambda2_min", "disconnected_steps",
                     "turn_rate"], named
    page = (out / "report" / "index.html").read_text(encoding="utf-8")
    glance, every = page.split("<h3>Every statistic</h3>")
    for part in (glance.split('id="summary"')[1], every):  # the page's two tables: the first column of each row
        table = part.split("</table>")[0]
        assert sorted(set(re.findall(r"<tr>\s*<td>([^<]*)</td>", table))) == ["3", "6"], table
    assert "turn_rate: deg/s (stored as rad/s)" in every
    # a CSV keeps the dataset's units (a program's table)
    csv = CliRunner().invoke(main, ["report", str(out), "--format", "csv", "--no-plots"]).output
    assert csv.splitlines()[1].startswith(f"{math.radians(3.0)!r},")
    # a length stays as the spec writes it (the README's table: 50000), its legend line unchanged
    grid = {"comm_radius": [50e3, 100e3]}
    out = write_dataset(tmp_path / "radius", synthetic_runs(grid, seeds=4), make_metadata(grid))
    printed = CliRunner().invoke(main, ["report", str(out), "--no-plots"]).output
    assert re.search(r"^\s*50000\s+kf\s", printed, flags=re.M) and "comm_radius: m — " in printed, printed


def test_resume_of_a_complete_sweep_says_it_was_complete_not_a_rate(tmp_path):
    """--resume of a sweep already whole printed "0 runs in 0.0 s (0.0 runs/s incl. compilation)"."""
    spec = tmp_path / "tiny.toml"
    spec.write_text(f'base = "{ROOT / "configs" / "chen2013.toml"}"\nseeds = 2\n[config]\nn_steps = 20\n',
                    encoding="utf-8")
    out = tmp_path / "out"
    first = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out)])
    assert first.exit_code == 0 and re.search(r"2 runs in [\d.]+ s \([\d.]+ runs/s", first.output), first.output
    assert "(0.0 runs/s" not in first.output  # two runs in a few seconds: 0.22, not 0.0
    again = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out), "--resume"])
    assert again.exit_code == 0, again.output
    assert f"6 rows in {out / 'runs'}; the sweep was already complete (nothing to run)" in again.output.splitlines()
    assert "runs/s" not in again.output and "0 runs in" not in again.output


def test_check_and_league_run_again_say_whether_their_folder_is_complete(tmp_path):
    """Not "pass --resume to finish it, or to print its table again if it is complete": which one it is."""
    from mcjax.study.store import hold_run_folder

    out = tmp_path / "check"
    ident = {"claims": {"paper": "P"}, "seeds": {"s": 2}}

    def hold():
        return hold_run_folder(out, ident, identity_file="check.json", kind="check", compare=("claims", "seeds"),
                               other="the check of another claims file")

    with hold():  # a check that wrote a part of its sweep, then stopped
        (out / "s" / "runs").mkdir(parents=True)
        (out / "s" / "runs" / "part-000000.parquet").write_bytes(b"PAR1")
    for table, state in ((None, "to finish it (it is not complete: its table is not written yet)"),
                         ("claims.parquet", "to print its table again (it is complete: claims.parquet is written)")):
        if table:
            (out / table).write_bytes(b"PAR1")
        with pytest.raises(OutputError) as caught:
            with hold():
                pass
        assert str(caught.value) == (f"{out} already holds this check (the same file and --seeds): pass --resume "
                                     f"{state}; --force to run it again, or choose another --out")
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == ["check.json", "claims.parquet", "s"]


def test_a_claims_files_wrong_kind_says_what_it_got_as_a_spec_does(tmp_path):
    """`seeds = "1000"` in a claims file said `got '1000'`; a spec says it got the string, and how to write a
    number. Both now say the same."""
    tail = "; got the string '1000' (a number is written without quotes: 1000)"
    spec = _spec(tmp_path).read_text(encoding="utf-8").replace("seeds = 2", 'seeds = "1000"')
    (tmp_path / "spec.toml").write_text(spec, encoding="utf-8")
    assert _refusal(tmp_path / "spec.toml")[0].endswith(tail)
    claims = tmp_path / "claims.toml"
    body = (f'paper = "P"\nseeds = "1000"\n[sweeps.s]\nbase = "{(ROOT / "configs" / "chen2013.toml").as_posix()}"\n'
            '[[claim]]\nid = "c"\nclaim = "x"\noutput = "wind_mean_x"\nfilter = "kcf"\nrelation = "below"\n'
            'value = 0.0\n')
    claims.write_text(body, encoding="utf-8")
    line = _error("check", str(claims), "--out", str(tmp_path / "out"))
    assert line.startswith("error: claims.toml: seeds: must be an integer in [1, ") and line.endswith(tail), line
    claims.write_text(body.replace('seeds = "1000"', "seeds = 2").replace("value = 0.0", 'value = "0.5"'),
                      encoding="utf-8")
    assert _error("check", str(claims), "--out", str(tmp_path / "out")).endswith(
        "value: must be a finite number; got the string '0.5' (a number is written without quotes: 0.5)")
    assert not (tmp_path / "out").exists()


def _calm_runs(grid: dict, seeds: int = 6):
    """Synthetic runs in which no run diverged."""
    from tests.analysis.test_tables import synthetic_runs

    runs = synthetic_runs(grid, seeds=seeds)
    runs["diverged"] = False
    return runs


def test_a_single_points_n_labels_clear_the_caps_and_no_divergence_is_drawn_where_none_diverged():
    """The check's single-point page put "n=…" on the error bars' caps and drew a panel of empty divergence
    bars: each label now sits above its bar's upper cap (its text box and the cap's apart, as drawn), and a
    sweep in which no run diverged gets one panel and a title that says so."""
    from matplotlib.lines import Line2D

    from mcjax.report.plots import plots
    from tests.analysis.test_tables import make_metadata, synthetic_runs

    for runs, panels in ((synthetic_runs({}, seeds=8), 2), (_calm_runs({}), 1)):
        (plot,) = list(plots(runs, make_metadata({})))
        fig = plot.figure
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        assert len(fig.axes) == panels
        assert ("no run diverged" in fig._suptitle.get_text()) == (panels == 1)
        assert ("and the divergence rate" in plot.caption) == (panels == 2)
        assert ("No run diverged" in plot.caption) == (panels == 1)
        for ax in fig.axes:
            labels = [t for t in ax.texts if t.get_text().startswith("n=")]
            caps = [line for line in ax.lines if isinstance(line, Line2D) and line.get_marker() == "_"]
            assert labels and caps
            for t in labels:
                box = t.get_window_extent(renderer)
                for cap in caps:
                    for x, y in cap.get_xydata():
                        px, py = ax.transData.transform((x, y))
                        assert not (box.x0 - 1 <= px <= box.x1 + 1 and box.y0 - 1 <= py <= box.y1 + 1), \
                            (t.get_text(), (px, py), box)


def test_a_sweep_in_which_no_run_diverged_gets_no_empty_divergence_figures():
    from mcjax.report.plots import Plot, Skipped, plots
    from tests.analysis.test_tables import make_metadata

    grid = {"comm_radius": [50e3, 100e3], "eps": [0.1, 1.0]}
    made = list(plots(_calm_runs(grid), make_metadata(grid)))
    names = [p.name for p in made if isinstance(p, Plot)]
    left = {s.name: s.reason for s in made if isinstance(s, Skipped)}
    assert not [n for n in names if "diverg" in n], names
    assert {"divergence_vs_comm_radius.png", "rmse_nondiverged_vs_eps.png", "heatmap_divergence_comm_radius__eps.png",
            "heatmap_rmse_nondiverged_comm_radius__eps.png"} <= set(left)
    assert all(reason.startswith("no run diverged") for reason in left.values()), left


def test_a_checks_sweep_page_opens_with_what_it_is_for(tmp_path):
    """The page of a sweep that `mcjax check` ran (no description in its inline spec) opened with "(The spec
    gives no description.)": it now names the check and the claims that read the sweep; a sweep with no
    description that no check ran has no such sentence."""
    import json

    from tests.analysis.test_tables import make_metadata, synthetic_runs, write_dataset

    grid = {"comm_radius": [50e3, 100e3]}
    check = tmp_path / "check"
    source = {"paper": "Sun et al. 2011", "sweeps": {"table1": {}, "other": {}},
              "claim": [{"id": "icf-diverges", "sweep": "table1"}, {"id": "elsewhere", "sweep": "other"},
                        {"id": "paired", "sweep": "other", "minus": {"sweep": "table1"}}]}
    for folder in (check / "table1", tmp_path / "plain"):
        write_dataset(folder, synthetic_runs(grid, seeds=4), make_metadata(grid))
    (check / "check.json").write_text(json.dumps({"claims": source, "claims_file": "/x/sun2011.toml"}),
                                      encoding="utf-8")
    for folder in (check / "table1", tmp_path / "plain"):
        r = CliRunner().invoke(main, ["report", str(folder)])
        assert r.exit_code == 0, r.output
    page = (check / "table1" / "report" / "index.html").read_text(encoding="utf-8")
    assert "no description" not in page
    assert ("<p>Sweep table1 of mcjax check on Sun et al. 2011&#x27;s claims (sun2011.toml): claims icf-diverges "
            "and paired read it.</p>") in page
    plain = (tmp_path / "plain" / "report" / "index.html").read_text(encoding="utf-8")
    assert "no description" not in plain and "mcjax check on" not in plain
