"""Claims files and `mcjax check`: the one-line refusals of a malformed file (before anything runs,
nothing written), the verdicts on hand-made runs against intervals computed here with scipy, the
check folder (resume gives the same claims.parquet) and the report's verdict table.

The five papers' claims files run at a small seed count in tests/claims/test_claims_files.py."""

from __future__ import annotations

import json
import math
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner
from scipy import stats

from mcjax.claims import evaluate
from mcjax.claims.folder import read_verdicts
from mcjax.claims.runner import run_check
from mcjax.claims.spec import Claim, ClaimsError, Side, load_claims
from mcjax.cli import main

ROOT = Path(__file__).resolve().parents[2]

# A small, cheap sweep: Chen & Lu 2013's three UAVs, 12 steps, two comm radii (the 3,200 m pair cut at 2.5 km).
SWEEP = f"""
paper = "Test paper"
seeds = 4

[sweeps.s]
base = "{(ROOT / 'configs' / 'chen2013.toml').as_posix()}"
chunk_size = 3
config = {{ n_steps = 12 }}
grid = {{ comm_radius = [100000.0, 2500.0] }}
"""

GOOD = """
[[claim]]
id = "kcf-below-local"
claim = "consensus beats each UAV's own filter"
where = "Table 1"
paper = "0.95 vs 1.2"
output = "wind_mean_x"
filter = "kcf"
at = { comm_radius = 100000.0 }
minus = { filter = "local" }
relation = "below"
value = 0.0
"""


def write(tmp_path: Path, body: str, name: str = "claims.toml") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(SWEEP) + textwrap.dedent(body), encoding="utf-8")
    return path


# ---------------------------------------------------------------- refusals: one line, exit 2, nothing written

BAD = [
    ("unknown output", GOOD.replace('output = "wind_mean_x"', 'output = "wind_mean"'),
     "claim 'kcf-below-local': output: must be an output of scenario wind_formation"),
    ("unknown filter", GOOD.replace('filter = "kcf"', 'filter = "ukf"'),
     "claim 'kcf-below-local': filter: must be one of the filters the sweep runs"),
    ("unknown statistic", GOOD.replace('relation = "below"', 'statistic = "mode"\nrelation = "below"'),
     "claim 'kcf-below-local': statistic: must be one of mean, median, quantile, rate"),
    ("unknown relation", GOOD.replace('relation = "below"', 'relation = "beneath"'),
     "claim 'kcf-below-local': relation: unknown; allowed: below, above"),
    ("within without a band", GOOD.replace('relation = "below"\nvalue = 0.0', 'relation = "within"'),
     "claim 'kcf-below-local': band: missing; relation 'within' needs band = [low, high]"),
    ("a band of three", GOOD.replace('relation = "below"\nvalue = 0.0', 'relation = "within"\nband = [0, 1, 2]'),
     "claim 'kcf-below-local': band: must be [low, high]"),
    ("below with a band", GOOD.replace('value = 0.0', 'value = 0.0\nband = [0, 1]'),
     "claim 'kcf-below-local': band: does not apply to relation 'below'"),
    ("below with value and than", GOOD.replace('value = 0.0', 'value = 0.0\nthan = { filter = "cif" }'),
     "claim 'kcf-below-local': value: relation 'below' takes a value or than"),
    ("an order of one", GOOD.replace('minus = { filter = "local" }\nrelation = "below"\nvalue = 0.0',
                                     'relation = "ordered"\norder = [{ filter = "cif" }]'),
     "claim 'kcf-below-local': order: must be a list of two or more sides"),
    ("a point not swept", GOOD.replace("comm_radius = 100000.0", "comm_radius = 5.0"),
     "claim 'kcf-below-local': at.comm_radius: must be one of the sweep's values 100000.0, 2500.0"),
    ("two points", GOOD.replace("at = { comm_radius = 100000.0 }\n", ""),
     "claim 'kcf-below-local': at: must select one point of the sweep; it selects 2 (pin also comm_radius)"),
    ("an axis not swept", GOOD.replace("at = { comm_radius = 100000.0 }", "at = { eta = 0.01 }"),
     "claim 'kcf-below-local': at.eta: is not swept by the sweep"),
    ("an unknown key", GOOD.replace('where = "Table 1"', 'wher = "Table 1"'),
     "claim 'kcf-below-local': wher: unknown key (did you mean 'where'?)"),
    ("no id", GOOD.replace('id = "kcf-below-local"\n', ""), "claim 1: id: missing"),
    ("the same id twice", GOOD + GOOD, "claim 'kcf-below-local': id: is given to two claims"),
    ("q without quantile", GOOD.replace('value = 0.0', 'value = 0.0\nq = 0.5'),
     "claim 'kcf-below-local': q: applies to statistic = \"quantile\" only"),
    ("consistent without runs", GOOD.replace('paper = "0.95 vs 1.2"', "paper = 0.95").replace(
        'minus = { filter = "local" }\nrelation = "below"\nvalue = 0.0', 'relation = "consistent"'),
     "claim 'kcf-below-local': paper_runs: missing; relation 'consistent' needs the paper's run count"),
    ("a claim with no runs", GOOD.replace('filter = "kcf"', 'filter = "kcf"\nsweep = "other"'),
     "claim 'kcf-below-local': sweep: must be one of the file's sweeps s; got 'other'"),
    ("no claims", "", "claim: must hold at least one claim"),
]


@pytest.mark.parametrize("body, expected", [(b, e) for _, b, e in BAD], ids=[n for n, _, _ in BAD])
def test_malformed_claims_file_exits_2_in_one_line_writing_nothing(tmp_path, body, expected):
    path = write(tmp_path, body)
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["check", str(path), "--out", str(out)])
    assert result.exit_code == 2, result.output
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: claims.toml: ") and expected in lines[0], result.output
    assert not out.exists()


def test_zero_seeds_and_a_file_without_sweeps_are_refused(tmp_path):
    path = write(tmp_path, GOOD)
    path.write_text(path.read_text(encoding="utf-8").replace("seeds = 4", "seeds = 0"), encoding="utf-8")
    with pytest.raises(ClaimsError, match=r"claims.toml: seeds: must be an integer in \[1, "):
        load_claims(path)
    (tmp_path / "c2.toml").write_text("paper = 'x'\n" + GOOD, encoding="utf-8")
    with pytest.raises(ClaimsError, match=r"c2.toml: sweeps: must name at least one sweep"):
        load_claims(tmp_path / "c2.toml")


def test_a_pairing_across_sweeps_with_other_seeds_is_refused_before_anything_runs(tmp_path):
    body = SWEEP.replace("[sweeps.s]", "[sweeps.t]\nbase = \"" + (ROOT / "configs" / "chen2013.toml").as_posix()
                         + "\"\nbase_seed = 7\nconfig = { n_steps = 12 }\ngrid = { comm_radius = [100000.0, 2500.0] }"
                         "\n\n[sweeps.s]")
    path = tmp_path / "claims.toml"
    path.write_text(textwrap.dedent(body) + GOOD.replace('minus = { filter = "local" }',
                                                         'sweep = "s"\nminus = { sweep = "t" }'), encoding="utf-8")
    result = CliRunner().invoke(main, ["check", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2
    assert "minus.sweep: a paired difference needs the same seeds on both sides" in result.output
    assert "base_seed 0" in result.output and "base_seed 7" in result.output
    assert not (tmp_path / "out").exists()


# ---------------------------------------------------------------- verdicts on hand-made runs

def _rows(values: dict, seeds=None) -> pd.DataFrame:
    """Rows of one sweep: ``values`` maps (point_id, filter) to per-seed values (shuffled, to show
    the sides are matched by seed and not by row order)."""
    frames = []
    rng = np.random.default_rng(0)
    for (pid, filt), x in values.items():
        s = np.arange(len(x)) if seeds is None else np.asarray(seeds[(pid, filt)])
        frames.append(pd.DataFrame({"point_id": pid, "seed_index": s, "filter": filt, "y": np.asarray(x, float),
                                    "axis": [0.1, 0.2, 0.3][pid]}))
    df = pd.concat(frames, ignore_index=True)
    return df.iloc[rng.permutation(len(df))]


def side(pid=0, filt="a", statistic="mean", **kw) -> Side:
    return Side("s", "y", filt, pid, {"axis": [0.1, 0.2, 0.3][pid]}, statistic, **kw)


def claim(s: Side, relation: str, **kw) -> Claim:
    return Claim("c", "text", "", kw.pop("paper", None), kw.pop("paper_runs", None), s, relation, **kw)


RNG = np.random.default_rng(42)
A = RNG.normal(1.0, 1.0, 60)
B = A + RNG.normal(0.3, 0.5, 60)   # paired: B − A has mean ~0.3 and a small spread


def t_interval(x):
    x = np.asarray(x, float)
    return stats.t.interval(0.95, len(x) - 1, loc=x.mean(), scale=stats.sem(x))


def test_a_mean_and_its_verdicts_follow_the_student_t_interval():
    rows = {"s": _rows({(0, "a"): A})}
    lo, hi = t_interval(A)
    verdict, (est,) = evaluate.judge(claim(side(), "below", value=hi + 0.01), rows)
    assert (verdict.verdict, est.low, est.high) == ("holds", pytest.approx(lo), pytest.approx(hi))
    assert evaluate.judge(claim(side(), "below", value=lo - 0.01), rows)[0].verdict == "fails"
    undecided = evaluate.judge(claim(side(), "below", value=A.mean() + 0.01), rows)[0]
    assert undecided.verdict == "undecided" and undecided.runs_to_decide > 60
    assert evaluate.judge(claim(side(), "above", value=lo - 0.01), rows)[0].verdict == "holds"
    assert evaluate.judge(claim(side(), "within", band=(lo - 0.01, hi + 0.01)), rows)[0].verdict == "holds"
    assert evaluate.judge(claim(side(), "within", band=(hi + 0.01, hi + 1)), rows)[0].verdict == "fails"
    assert evaluate.judge(claim(side(), "equal", value=A.mean(), band=(lo, hi + 1)), rows)[0].verdict == "holds"


def test_a_paired_difference_matches_seeds_and_uses_the_paired_t_interval():
    rows = {"s": _rows({(0, "a"): A, (0, "b"): B})}
    s = side(filt="b")._replace(minus=side(filt="a"))
    verdict, (est,) = evaluate.judge(claim(s, "above", value=0.0), rows)
    lo, hi = t_interval(B - A)
    assert (est.value, est.low, est.high) == (pytest.approx((B - A).mean()), pytest.approx(lo), pytest.approx(hi))
    assert verdict.verdict == "holds"
    # unpaired, the two intervals overlap: the same claim as an order of two is undecided
    assert evaluate.judge(claim(side(filt="a"), "below", others=(side(filt="b"),)), rows)[0].verdict == "undecided"


def test_a_pairing_whose_seeds_differ_is_refused():
    seeds = {(0, "a"): np.arange(10), (0, "b"): np.arange(1, 11)}
    rows = {"s": _rows({(0, "a"): A[:10], (0, "b"): B[:10]}, seeds)}
    s = side(filt="b")._replace(minus=side(filt="a"))
    with pytest.raises(ValueError, match="same seeds on both sides"):
        evaluate.judge(claim(s, "above", value=0.0), rows)


def test_a_rate_counts_flags_and_bounds_with_the_wilson_interval():
    y = np.r_[np.zeros(40), np.full(7, 2.0), np.full(3, np.nan)]  # 3 non-finite: above any bound
    rows = {"s": _rows({(0, "a"): y})}
    verdict, (est,) = evaluate.judge(claim(side(statistic="rate", over=1.0), "below", value=0.5), rows)
    ci = stats.binomtest(10, 50).proportion_ci(0.95, method="wilson")
    assert (est.value, est.n, est.low, est.high) == (0.2, 50, pytest.approx(ci.low), pytest.approx(ci.high))
    assert verdict.verdict == "holds"
    est = evaluate.side_estimate(side(statistic="rate", under=1.0), rows)
    assert (est.value, est.n) == (40 / 50, 50)
    est = evaluate.side_estimate(side(statistic="rate"), rows)  # a flag output: non-zero (NaN counts) is true
    assert est.value == 10 / 50


def test_a_quantile_uses_scipys_order_statistic_interval():
    rows = {"s": _rows({(0, "a"): A})}
    est = evaluate.side_estimate(side(statistic="quantile", q=0.9), rows)
    ci = stats.quantile_test(A, p=0.9).confidence_interval(0.95)
    assert (est.value, est.low, est.high) == (pytest.approx(np.quantile(A, 0.9)), ci.low, ci.high)


def test_ordered_and_monotone_need_apart_intervals():
    far = {(0, "a"): A, (1, "a"): A + 5, (2, "a"): A + 10}
    rows = {"s": _rows(far)}
    sides = tuple(side(p) for p in range(3))
    assert evaluate.judge(claim(sides[0], "monotone", others=sides, along="axis"), rows)[0].verdict == "holds"
    assert evaluate.judge(claim(sides[0], "monotone", others=sides, along="axis", direction="decreasing"),
                          rows)[0].verdict == "fails"
    near = {(0, "a"): A, (1, "a"): A + 0.05, (2, "a"): A + 10}
    assert evaluate.judge(claim(sides[0], "ordered", others=sides), {"s": _rows(near)})[0].verdict == "undecided"


def test_consistent_with_a_papers_number_from_its_run_count():
    rows = {"s": _rows({(0, "a"): A})}
    s = np.std(A, ddof=1)
    paper_half = stats.t.ppf(0.975, 19) * s / math.sqrt(20)
    own_half = stats.t.ppf(0.975, 59) * s / math.sqrt(60)
    edge = A.mean() + math.hypot(paper_half, own_half)
    assert evaluate.judge(claim(side(), "consistent", paper=edge - 0.01, paper_runs=20), rows)[0].verdict == "holds"
    assert evaluate.judge(claim(side(), "consistent", paper=edge + 0.01, paper_runs=20), rows)[0].verdict == "fails"
    flags = np.r_[np.ones(16), np.zeros(34)]  # rate 0.32; 20 paper runs: half-width 1.96 sqrt(.32 .68 / 20) = 0.204
    rows = {"s": _rows({(0, "a"): flags})}
    assert evaluate.judge(claim(side(statistic="rate"), "consistent", paper=0.5, paper_runs=20),
                          rows)[0].verdict == "holds"
    assert evaluate.judge(claim(side(statistic="rate"), "consistent", paper=0.75, paper_runs=20),
                          rows)[0].verdict == "fails"


# ---------------------------------------------------------------- the check folder

CLAIMS = GOOD + """
[[claim]]
id = "radius-does-not-help-local"
claim = "the local filter does not use the graph"
output = "wind_mean_x"
filter = "local"
at = { comm_radius = 100000.0 }
minus = { at = { comm_radius = 2500.0 } }
relation = "equal"
value = 0.0
tolerance = 1e-9

[[claim]]
id = "order"
claim = "cif below local"
output = "wind_mean_x"
at = { comm_radius = 2500.0 }
relation = "ordered"
order = [{ filter = "cif" }, { filter = "local" }]
"""


def test_check_writes_verdicts_beside_the_runs_and_resume_gives_the_same_table(tmp_path):
    path = write(tmp_path, CLAIMS)
    whole = run_check(path, out_dir=tmp_path / "whole")
    table, meta = read_verdicts(tmp_path / "whole")
    assert list(table["id"]) == ["kcf-below-local", "radius-does-not-help-local", "order"]
    assert table.loc[1, "verdict"] == "holds" and table.loc[1, "value"] == 0.0  # the local filter ignores links
    assert meta["paper"] == "Test paper" and meta["seeds"] == {"s": 4}
    assert (tmp_path / "whole" / "s" / "sweep.json").is_file()
    # stopped after the first chunk (of 3 runs), then resumed: the same claims.parquet
    calls = []
    stopped = run_check(path, out_dir=tmp_path / "cut", should_stop=lambda: calls.append(1) or len(calls) > 1)
    assert stopped.stopped and not (tmp_path / "cut" / "claims.parquet").exists()
    resumed = run_check(path, out_dir=tmp_path / "cut", resume=True)
    pd.testing.assert_frame_equal(read_verdicts(tmp_path / "cut")[0], table)
    assert resumed.table.equals(whole.table)


def test_check_cli_strict_report_and_markdown(tmp_path):
    body = CLAIMS.replace("value = 0.0\ntolerance = 1e-9", "value = 1.0\ntolerance = 1e-9")  # surely fails
    path = write(tmp_path, body)
    out = tmp_path / "out"
    runner = CliRunner()
    plain = runner.invoke(main, ["check", str(path), "--out", str(out)])
    assert plain.exit_code == 0, plain.output
    assert "radius-does-not-help-local" in plain.output and "fails" in plain.output
    strict = runner.invoke(main, ["check", str(path), "--out", str(out), "--resume", "--strict"])
    assert strict.exit_code == 1
    again = runner.invoke(main, ["check", str(path), "--out", str(out)])
    assert again.exit_code == 2 and "already holds this check (the same file and --seeds): pass --resume" in again.output
    md = runner.invoke(main, ["report", str(out), "--format", "markdown", "--no-plots"])
    assert md.exit_code == 0
    assert "| claim | where | paper | ours [95 %] | runs | verdict |" in md.output
    assert "| kcf-below-local: consensus beats each UAV's own filter | Table 1 | 0.95 vs 1.2 |" in md.output
    report = runner.invoke(main, ["report", str(out)])
    assert report.exit_code == 0 and "page: " + str(out / "s" / "report" / "index.html") in report.output
    assert json.loads((out / "check.json").read_text())["seeds"] == {"s": 4}


def test_a_check_killed_mid_run_resumes_to_the_same_claims_parquet(tmp_path):
    """kill -9 while the sweep's chunks are written, then --resume in a new process: the same
    verdict table in claims.parquet as an uninterrupted check (its provenance metadata differs). The sweep is the one
    tests/cli/test_commands.py kills, so the session's program store holds its program."""
    import signal
    import subprocess
    import sys
    import time

    claims = tmp_path / "claims.toml"
    claims.write_text(textwrap.dedent(f"""
        paper = "kill test"
        [sweeps.open]
        base = "{(ROOT / 'configs' / 'sun2011.toml').as_posix()}"
        seeds = 500
        chunk_size = 100
        config = {{ n_steps = 10, warmup_steps = 2, planner = "none", filters = ["cif", "modified_icf"] }}
        grid = {{ comm_radius = [60e3, 80e3, 100e3] }}

        [[claim]]
        id = "cif-below-modified-icf"
        claim = "the centralised filter is the more accurate at 60 km"
        output = "rmse"
        filter = "cif"
        at = {{ comm_radius = 60e3 }}
        minus = {{ filter = "modified_icf" }}
        relation = "below"
        value = 0.0

        [[claim]]
        id = "divergence-falls-with-radius"
        claim = "the modified ICF diverges less often as the comm radius grows"
        output = "diverged"
        filter = "modified_icf"
        statistic = "rate"
        relation = "monotone"
        along = "comm_radius"
        direction = "decreasing"
        """), encoding="utf-8")
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "mcjax.cli", "check", str(claims), "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    while time.time() < deadline and not (out / "open" / "runs" / "point_id=0" / "part-000001.parquet").exists():
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    written = list((out / "open" / "runs").glob("*/*.parquet"))
    assert 2 <= len(written) < 15 and not (out / "claims.parquet").exists(), written  # killed mid-way
    r = subprocess.run([*cmd, "--resume"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert f"{len(written)} of 15 chunk(s) already written" in r.stdout
    run_check(claims, out_dir=tmp_path / "whole")
    resumed, whole = read_verdicts(out)[0], read_verdicts(tmp_path / "whole")[0]
    pd.testing.assert_frame_equal(resumed, whole, check_exact=True)
