"""`mcjax check --base-seed N` and `--replicate K` (issue 62, item 2) on a tiny claims file (Chen & Lu 2013's
three UAVs, 12 steps, two sweeps of 4 seeds at two comm radii each, one program): the same verdict tables as
hand-edited copies of the file with `base_seed` written into each sweep; a replication killed (SIGKILL) in
its second range resumes to the same claims.parquet; bad options exit 2 in one line, before anything is
written."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from mcjax.claims.evaluate import COLUMNS, REPLICATE_COLUMNS
from mcjax.claims.folder import read_verdicts
from mcjax.claims.runner import SEEDS_PER_RANGE, run_check
from mcjax.cli import main
from mcjax.engine.keys import run_keys

ROOT = Path(__file__).resolve().parents[2]
SWEEP = """
[sweeps.s]
base = "{base}"
config = {{ n_steps = 12 }}
grid = {{ comm_radius = [100000.0, 2500.0] }}{seed}

[sweeps.t]
base = "{base}"
config = {{ n_steps = 12 }}
grid = {{ comm_radius = [100000.0, 50000.0] }}{seed}
"""
CLAIMS = """
[[claim]]
id = "kcf-below-local"
claim = "consensus beats each UAV's own filter"
sweep = "s"
output = "wind_mean_x"
filter = "kcf"
at = { comm_radius = 100000.0 }
minus = { filter = "local" }
relation = "below"
value = 0.0

[[claim]]
id = "cif-error-small"
claim = "the centralised filter's wind error is below 3 m/s"
sweep = "s"
output = "wind_mean_x"
filter = "cif"
at = { comm_radius = 2500.0 }
relation = "below"
value = 3.0

[[claim]]
id = "order"
claim = "cif below local"
sweep = "s"
output = "wind_mean_x"
at = { comm_radius = 2500.0 }
relation = "ordered"
order = [{ filter = "cif" }, { filter = "local" }]

[[claim]]
id = "kcf-below-local-at-50km"
claim = "consensus beats each UAV's own filter at a 50 km comm radius"
sweep = "t"
output = "wind_mean_x"
filter = "kcf"
at = { comm_radius = 50000.0 }
minus = { filter = "local" }
relation = "below"
value = 0.0
"""
BASE = 5


def write(folder: Path, name: str = "claims.toml", base_seed: int | None = None, head: str = "") -> Path:
    """The claims file; with `base_seed`, the hand-edited copy: `base_seed = N` written into each sweep."""
    seed = "" if base_seed is None else f"\nbase_seed = {base_seed}"
    base = (ROOT / "configs" / "chen2013.toml").as_posix()
    text = 'paper = "Test paper"\nseeds = 4\n' + head + SWEEP.format(base=base, seed=seed) + CLAIMS
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).write_text(textwrap.dedent(text), encoding="utf-8")
    return folder / name


@pytest.fixture(scope="module")
def replicated(tmp_path_factory):
    """`mcjax check claims.toml --base-seed 5 --replicate 2`, uninterrupted: (claims file, output folder)."""
    folder = tmp_path_factory.mktemp("replicated")
    path = write(folder)
    out = folder / "out"
    r = CliRunner().invoke(main, ["check", str(path), "--out", str(out), "--base-seed", str(BASE), "--replicate", "2"])
    assert r.exit_code == 0, r.output
    return path, out


def _table(folder: Path) -> pd.DataFrame:
    return read_verdicts(folder)[0]


def test_base_seed_and_replicate_give_the_verdicts_of_hand_edited_copies(replicated, tmp_path):
    """Range r of `--base-seed 5 --replicate 2` runs from base seed 5 + r x 1,000,000: its claims.parquet is
    the check of a copy of the file with that base seed written into the sweep, and so is `--base-seed 5`
    alone; the replication's table is range 0's with each range's verdicts (family level and alone)."""
    path, out = replicated
    ranges = []
    for r in range(2):
        copy = write(tmp_path / f"copy{r}", base_seed=BASE + r * SEEDS_PER_RANGE)
        edited = run_check(copy, out_dir=tmp_path / f"edited{r}").table
        pd.testing.assert_frame_equal(_table(out / f"range_{r}"), edited, check_exact=True)
        for sweep in ("s", "t"):
            saved = json.loads((out / f"range_{r}" / sweep / "sweep.json").read_text())
            assert saved["base_seed"] == BASE + r * SEEDS_PER_RANGE
        ranges.append(edited)
    assert not ranges[0]["ours"].equals(ranges[1]["ours"])  # two seed ranges, two sets of runs
    alone = run_check(path, base_seed=BASE, out_dir=tmp_path / "alone").table
    pd.testing.assert_frame_equal(alone, ranges[0], check_exact=True)
    table, meta = read_verdicts(out)
    assert list(table.columns) == [*COLUMNS, *REPLICATE_COLUMNS]
    pd.testing.assert_frame_equal(table[list(COLUMNS)], ranges[0], check_exact=True)
    each = list(zip(ranges[0]["family_verdict"], ranges[1]["family_verdict"]))
    assert table["range_verdicts"].tolist() == [", ".join(v) for v in each]
    assert table["replicates"].tolist() == [a == b for a, b in each]
    assert meta["ranges"] == [{"s": BASE, "t": BASE}, {"s": BASE + SEEDS_PER_RANGE, "t": BASE + SEEDS_PER_RANGE}]
    assert meta["replicate"] == 2
    # disjoint: no run key of one range is a run key of the other (each base seed its own Threefry key)
    keys = [{tuple(k) for k in run_keys(BASE + r * SEEDS_PER_RANGE, np.arange(10_000)).tolist()} for r in range(2)]
    assert len(keys[0]) == 10_000 and not keys[0] & keys[1]


def test_a_killed_replicate_resumes_to_the_same_claims_parquet(replicated, tmp_path):
    """A replication SIGKILLed in range 1, right after its first sweep is written (range 0 whole, range 1's
    second sweep not begun), then `--resume`: the same claims.parquet, each range's too, as the uninterrupted
    one."""
    path, reference = replicated
    out = tmp_path / "killed"
    script = textwrap.dedent(f"""
        import os, signal
        import mcjax
        mcjax.configure()
        from mcjax.claims.runner import run_check
        def progress(stage, at):
            if stage == "range_1/s" and at.chunks_done == at.chunks:
                os.kill(os.getpid(), signal.SIGKILL)
        run_check({str(path)!r}, out_dir={str(out)!r}, base_seed={BASE}, replicate=2, progress=progress)
        """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert proc.returncode == -9, proc.stderr
    assert (out / "range_0" / "claims.parquet").is_file() and not (out / "range_1" / "claims.parquet").exists()
    assert list((out / "range_1" / "s" / "runs").glob("*/*.parquet")) and not (out / "range_1" / "t").exists()
    assert not (out / "claims.parquet").exists()
    again = ["check", str(path), "--out", str(out), "--base-seed", str(BASE), "--replicate", "2", "--resume"]
    r = CliRunner().invoke(main, again)
    assert r.exit_code == 0, r.output
    assert r.output.count("resuming: 1 of 1 chunk(s) already written") == 3  # range 0's two sweeps, range 1's first
    for folder in ("", "range_0", "range_1"):
        pd.testing.assert_frame_equal(_table(out / folder), _table(reference / folder), check_exact=True)


@pytest.mark.parametrize("args, expected", [
    (["--replicate", "0"], "--replicate: must be an integer >= 2 (the number of seed ranges); got 0"),
    (["--replicate", "two"], "--replicate: must be an integer >= 2 (the number of seed ranges); got 'two'"),
    (["--base-seed", "-1"], "--base-seed: must be an integer in [0, 4294967295]; got -1"),
    (["--base-seed", str(2**32)], "--base-seed: must be an integer in [0, 4294967295]; got 4294967296"),
    (["--base-seed", "4294000000", "--replicate", "2"], "--replicate 2: range 1 would run sweep s from base seed "
                                                        "4,295,000,000, past the largest, 4,294,967,295"),
    (["--family", "sidak"], "--family: must be one of holm, bonferroni; got 'sidak'"),
    (["--family", "bonferroni"], "--family bonferroni: claims.toml fixes family = 'holm' (chosen before the runs)"),
])
def test_bad_replication_and_family_options_exit_2_in_one_line(tmp_path, args, expected):
    path = write(tmp_path, head='family = "holm"\n' if "bonferroni" in args else "")
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["check", str(path), "--out", str(out), *args])
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert r.exit_code == 2 and len(lines) == 1 and lines[0].startswith(f"error: {expected}"), r.output
    assert not out.exists()


def test_resume_refuses_another_base_seed_or_range_count_and_a_file_names_a_known_family(tmp_path):
    path = write(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / "check.json").write_text(json.dumps({"base_seed": BASE, "replicate": 2}), encoding="utf-8")
    for args, option in ((["--replicate", "2"], "--base-seed 5"), (["--base-seed", "5"], "--replicate 2")):
        r = CliRunner().invoke(main, ["check", str(path), "--out", str(out), "--resume", *args])
        assert r.exit_code == 2 and r.output.strip().count("\n") == 0, r.output
        assert f"holds a check with {option}; --resume needs the same {option.split()[0]}" in r.output
    bad = write(tmp_path, "bad.toml", head='family = "fdr"\n')
    r = CliRunner().invoke(main, ["check", str(bad), "--out", str(tmp_path / "o2")])
    assert r.exit_code == 2 and "error: bad.toml: family: must be one of holm, bonferroni" in r.output
