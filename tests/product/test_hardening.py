"""Issue 17: damaged datasets, resume that verifies, output folders that cannot escape, the
small CLI fixes, run_filter's errors and Ctrl-C on real processes (the corpus of malformed
specs is in tests/product/test_hardening_corpus.py; the many-SIGINT stress is benchmarks/stress/interrupt_stress.py --signal int)."""

from __future__ import annotations

import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

from mcjax.base.interrupt import ACK
from mcjax.cli import main
from mcjax.study import check_parts, default_out_dir, load_spec

ROOT = Path(__file__).parents[2]
WIND = ROOT / "configs" / "chen2013.toml"
#: Subprocesses share the test session's program store (tests/conftest.py): the programs the
#: first of them compiles, the others load.
ENV = dict(os.environ)
CLI = [sys.executable, "-m", "mcjax.cli"]


def _spec(folder: Path, name="spec.toml", seeds=150, steps=3, extra="") -> Path:
    """A small wind_formation sweep: 2 points x ``seeds`` seeds, chunks of 100 runs (with 150
    seeds: 3 chunks, 4 part files, chunk 1 touching both points)."""
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / name
    p.write_text(f'base = "{WIND}"\nseeds = {seeds}\nchunk_size = 100\n{extra}[config]\nn_steps = {steps}\n'
                 f'warmup_steps = 0\n[grid]\neta = [0.0, 0.01]\n')
    return p


def _runs(out: Path) -> pd.DataFrame:
    df = pd.read_parquet(out / "runs")
    df["point_id"] = df["point_id"].astype(np.int64)
    return df.sort_values(["point_id", "seed_index", "filter"]).reset_index(drop=True)


def _one_line(r) -> str:
    lines = [line for line in r.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in r.output, r.output
    return lines[0]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """A finished sweep (spec, folder) to copy and damage."""
    folder = tmp_path_factory.mktemp("wind")
    spec = _spec(folder)
    out = folder / "whole"
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert not (out / "_staging").exists()  # no empty staging folder left
    return spec, out


def _copy(dataset, tmp_path) -> Path:
    out = tmp_path / "copy"
    shutil.copytree(dataset[1], out)
    return out


@pytest.mark.xdist_group("test_hardening")  # one worker builds the module fixture once
def test_damaged_parts_are_named_by_report_and_repaired_by_resume(dataset, tmp_path):
    spec, whole = dataset
    out = _copy(dataset, tmp_path)
    parts = sorted((out / "runs").glob("*/*.parquet"))
    assert len(parts) == 4
    truncated, empty, garbage, missing = parts
    truncated.write_bytes(truncated.read_bytes()[:300])
    empty.write_bytes(b"")
    garbage.write_bytes(b"not a parquet file\n" * 50)
    missing.unlink()
    r = CliRunner().invoke(main, ["report", str(out), "--no-plots"])
    assert r.exit_code == 2
    line = _one_line(r)
    assert "is damaged" in line and "point_id=0/part-000000.parquet" in line and "--resume" in line
    assert str(spec.resolve()) in line  # the command names the spec the folder was made from
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out), "--resume"])
    assert r.exit_code == 0, r.output
    for part, what in ((truncated, "damaged"), (empty, "damaged"), (garbage, "damaged"), (missing, "missing")):
        name = f"runs/{part.parent.name}/{part.name} is {what}"
        assert any(line.startswith("resume: chunk") and name in line for line in r.output.splitlines()), (name, r.output)
    pd.testing.assert_frame_equal(_runs(out), _runs(whole), check_exact=True)


@pytest.mark.xdist_group("test_hardening")  # one worker builds the module fixture once
def test_missing_part_makes_report_warn_and_resume_finish(dataset, tmp_path):
    spec, whole = dataset
    out = _copy(dataset, tmp_path)
    (out / "runs" / "point_id=1" / "part-000002.parquet").unlink()
    r = CliRunner().invoke(main, ["report", str(out), "--format", "markdown"])
    assert r.exit_code == 0, r.output
    first = r.output.splitlines()[0]
    assert first.startswith("- WARNING: incomplete dataset: 200 of 300 planned runs present (100 missing)")
    assert f"mcjax sweep {spec.resolve()} --out {out} --resume" in first
    assert any(line.startswith("plot: ") for line in r.output.splitlines())
    r = CliRunner().invoke(main, ["report", str(out), "--format", "csv", "--no-plots"])
    assert r.exit_code == 0 and "warning: incomplete dataset: 200 of 300" in r.output
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out), "--resume"])
    assert r.exit_code == 0 and "resuming: 2 of 3 chunk(s) already written" in r.output, r.output
    pd.testing.assert_frame_equal(_runs(out), _runs(whole), check_exact=True)
    r = CliRunner().invoke(main, ["report", str(out), "--no-plots"])
    assert r.exit_code == 0 and "WARNING" not in r.output


@pytest.mark.xdist_group("test_hardening")  # one worker builds the module fixture once
def test_damaged_sweep_json_is_one_line_and_report_still_reads(dataset, tmp_path):
    spec, _ = dataset
    out = _copy(dataset, tmp_path)
    state = out / "sweep.json"
    for damage in (state.read_bytes()[:40], b"", b"[1, 2]", b"\xff\xfe"):
        state.write_bytes(damage)
        r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out), "--resume"])
        assert r.exit_code == 2
        line = _one_line(r)
        assert "sweep.json is damaged" in line and "--force" in line
    r = CliRunner().invoke(main, ["report", str(out), "--no-plots"])
    assert r.exit_code == 0 and "WARNING: " in r.output and "sweep.json is damaged" in r.output.splitlines()[0]
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out), "--force"])  # a sweep's folder: replaced
    assert r.exit_code == 0, r.output


def test_resume_takes_seeds_chunk_size_and_set_from_sweep_json(tmp_path):
    spec = _spec(tmp_path, steps=4)
    out = tmp_path / "o"
    args = ["--seeds", "120", "--chunk-size", "100", "--set", "config.n_steps=3"]
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out), *args])
    assert r.exit_code == 0, r.output
    whole = _runs(out)
    (out / "runs" / "point_id=1" / "part-000002.parquet").unlink()
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out), "--resume"])  # no other option
    assert r.exit_code == 0 and "2 point(s) x 120 seed(s)" in r.output, r.output
    pd.testing.assert_frame_equal(_runs(out), whole, check_exact=True)
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", str(out), "--resume", "--seeds", "121"])
    assert r.exit_code == 2 and "different sweep (n_runs, seeds differ)" in _one_line(r)


def test_default_output_folder_stays_inside_results(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for name, want in (("...toml", "results/sweep"), ("..toml", "results/sweep"), (".toml", "results/toml"),
                       ("a b$.toml", "results/a_b_"), ("x/.hidden.toml", "results/hidden"),
                       ("sun2011.toml", "results/sun2011")):
        got = default_out_dir(name)
        assert got == Path(want) and got.resolve().parent == (tmp_path / "results").resolve(), (name, got)
    spec = _spec(tmp_path, name="...toml")
    (tmp_path / "results" / "other").mkdir(parents=True)
    (tmp_path / "results" / "other" / "keep.txt").write_text("x")
    r = CliRunner().invoke(main, ["sweep", str(spec)])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "results" / "sweep" / "sweep.json").is_file() and (tmp_path / "results" / "other" / "keep.txt").exists()
    r = CliRunner().invoke(main, ["sweep", str(spec), "--force"])  # replaces results/sweep only
    assert r.exit_code == 0 and (tmp_path / "results" / "other" / "keep.txt").exists() and spec.exists()


def test_force_replaces_only_a_sweeps_own_folder(tmp_path, monkeypatch):
    work = tmp_path / "work"
    spec = _spec(work / "specs")
    (work / "results" / "old").mkdir(parents=True)
    (work / "results" / "old" / "sweep.json").write_text("{}")
    (work / "notes").mkdir()
    (work / "notes" / "todo.txt").write_text("x")
    monkeypatch.chdir(work)
    for out, why in ((".", "the current folder"), ("results", "results/ itself"), (str(tmp_path), "the current folder"),
                     ("specs", "spec.toml"), ("notes", "holds no sweep.json")):
        r = CliRunner().invoke(main, ["sweep", str(spec), "--out", out, "--force"])
        assert r.exit_code == 2, (out, r.output)
        line = _one_line(r)
        assert line.startswith("error: --force:") and why in line, (out, line)
    assert (work / "notes" / "todo.txt").exists() and spec.exists() and (work / "results" / "old").exists()
    r = CliRunner().invoke(main, ["sweep", str(spec), "--out", "results/old", "--force"])
    assert r.exit_code == 0, r.output


def test_set_filters_and_which_command_a_file_is_for(tmp_path):
    spec = _spec(tmp_path, seeds=2)
    for value, shown in (("kcf", "filters kcf\n"), ("[kcf,cif]", "filters kcf, cif\n"), ('["local"]', "filters local\n")):
        r = CliRunner().invoke(main, ["sweep", str(spec), "--dry-run", "--set", f"config.filters={value}"])
        assert r.exit_code == 0 and shown in r.output, (value, r.output)
    r = CliRunner().invoke(main, ["run", str(spec)])
    assert r.exit_code == 2 and "is a sweep spec" in _one_line(r) and f"mcjax sweep {spec}" in r.output
    r = CliRunner().invoke(main, ["sweep", str(WIND), "--dry-run"])
    assert r.exit_code == 2 and "is a config file" in _one_line(r) and f"mcjax run {WIND}" in r.output
    r = CliRunner().invoke(main, ["sweep", str(tmp_path), "--dry-run"])
    assert r.exit_code == 2 and "is a folder" in _one_line(r)


@pytest.mark.parametrize("value", ["zero", "0", "-2", "1.5", ""])
def test_a_bad_cpu_device_count_is_one_line_naming_the_variable(value, tmp_path):
    spec = _spec(tmp_path, seeds=2)
    for args in (["list"], ["sweep", str(spec), "--dry-run"], ["run", str(WIND)]):
        r = CliRunner().invoke(main, args, env={"MCJAX_CPU_DEVICES": value})
        assert r.exit_code == 2 and "MCJAX_CPU_DEVICES must be a positive integer" in _one_line(r), (args, r.output)
        assert "Traceback" not in r.output
    r = CliRunner().invoke(main, ["sweep", str(spec), "--dry-run"], env={"MCJAX_CPU_DEVICES": "2"})
    assert r.exit_code == 0, r.output


@pytest.mark.parametrize("name, value, message", [
    ("MCJAX_CACHE_MAX_GB", "-1", "MCJAX_CACHE_MAX_GB must be a positive number of gigabytes"),
    ("MCJAX_CACHE_MAX_GB", "0", "MCJAX_CACHE_MAX_GB must be a positive number of gigabytes"),
    ("MCJAX_CACHE_MAX_GB", "lots", "MCJAX_CACHE_MAX_GB must be a positive number of gigabytes"),
    ("MCJAX_CACHE_MAX_GB", "inf", "MCJAX_CACHE_MAX_GB must be a positive number of gigabytes"),
    ("MCJAX_NATIVE", "maybe", "MCJAX_NATIVE must be 'on' or 'off'"),
])
def test_other_bad_environment_variables_are_one_line_naming_them(name, value, message, tmp_path):
    spec = _spec(tmp_path, seeds=2)
    r = CliRunner().invoke(main, ["sweep", str(spec), "--dry-run"], env={name: value})
    assert r.exit_code == 2 and message in _one_line(r) and repr(value) in r.output, r.output
    assert "Traceback" not in r.output
    good = {"MCJAX_CACHE_MAX_GB": "0.5", "MCJAX_NATIVE": "off"}[name]
    r = CliRunner().invoke(main, ["sweep", str(spec), "--dry-run"], env={name: good})
    assert r.exit_code == 0, r.output


def test_axes_of_vectors_stack_into_one_array_per_field(tmp_path):
    """A per-agent axis may mix one number for all agents with one per agent; every axis's
    points stack into one array with a leading point axis (what the engine is given)."""

    spec = tmp_path / "v.toml"
    spec.write_text(f'base = "{ROOT / "configs" / "ren2017.toml"}"\nseeds = 2\n[config]\nn_steps = 3\n'
                    'warmup_steps = 1\n[grid]\ncomm_radius = [450.0, [400.0, 450.0, 500.0, 450.0, 450.0, 450.0]]\n'
                    'mu0 = [[0.5, 0.5], [0.3, 0.7]]\n')
    p = load_spec(spec).params
    assert p.comm_radius.shape == (4, 6) and p.mu0.shape == (4, 2) and p.comm_radius[0, 0] == 450.0


# --------------------------------------------------------------------------- run_filter


def _filter_args():
    T, n = 3, 2
    z = np.tile([[1000.0, 0.1]], (T, n, 1))
    return dict(measurements=z, sensor_positions=np.zeros((T, n, 2)), adjacency=np.tile(1 - np.eye(n), (T, 1, 1)),
                x0=np.zeros(4), P0=np.eye(4), F=np.eye(4), Q=np.eye(4) * 0.1, R=np.diag([1.0, 0.01]))


BAD_FILTER_ARGS = [
    ("kind", None), ("kind", 5), ("kind", ["cif"]), ("kind", "ukf"),
    ("kcf_epsilon", None), ("kcf_epsilon", "0.1"), ("kcf_epsilon", float("nan")), ("kcf_epsilon", -1.0),
    ("kcf_epsilon", True), ("kcf_epsilon", [0.1]), ("kcf_epsilon", {"a": 1}),
    ("consensus_steps", 1.5), ("consensus_steps", -1), ("consensus_steps", True), ("consensus_steps", "1"),
    ("consensus_steps", None),
    ("dtype", None), ("dtype", "float16"), ("dtype", ["float64"]),
    ("weights", "x"), ("weights", None), ("weights", ["eq11"]), ("contribution", 1), ("icf_variant", None),
    ("kcf_gain", {"a": 1}),
    ("measurements", None), ("measurements", "x"), ("measurements", [[1.0]]), ("measurements", [[[1.0, 2.0]], [[1.0]]]),
    ("measurements", np.zeros((0, 2, 2))), ("measurements", {"a": 1}),
    ("sensor_positions", None), ("sensor_positions", np.zeros((3, 2, 3))), ("sensor_positions", np.full((3, 2, 2), np.nan)),
    ("adjacency", None), ("adjacency", np.full((3, 2, 2), 0.5)), ("adjacency", np.tile([[0, 1], [0, 0]], (3, 1, 1))),
    ("adjacency", np.ones((3, 2, 2))),
    ("x0", None), ("x0", np.zeros(3)), ("x0", [np.nan, 0, 0, 0]), ("x0", "abcd"),
    ("P0", None), ("P0", -np.eye(4)), ("P0", np.triu(np.ones((4, 4)))), ("P0", np.full((4, 4), np.nan)), ("P0", np.eye(3)),
    ("F", None), ("F", np.full((4, 4), np.inf)), ("Q", -np.eye(4)), ("Q", None), ("R", np.eye(3)), ("R", None),
    ("R", np.zeros((2, 2))),
]


@pytest.mark.parametrize("name, value", BAD_FILTER_ARGS, ids=[f"{n}-{i}" for i, (n, _) in enumerate(BAD_FILTER_ARGS)])
def test_every_bad_run_filter_argument_raises_value_error(name, value):
    from mcjax.tracking.filters.recorded import run_filter

    args = {"kind": "cif", **_filter_args(), name: value}
    with pytest.raises(ValueError, match=name if name not in ("weights", "contribution", "icf_variant", "kcf_gain")
                       else name):
        run_filter(**args)


# --------------------------------------------------------------------------- Ctrl-C on real processes


def _start(cmd, cwd):
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV, cwd=cwd)


def _wait_for(cond, timeout=240.0):
    t0 = time.time()
    while not cond():
        assert time.time() - t0 < timeout, "timed out"
        time.sleep(0.01)


def test_ctrl_c_twice_stops_a_sweep_now_and_the_printed_resume_works(tmp_path):
    """First Ctrl-C acknowledged at once, the second one exits 130 within seconds; only
    complete parts on disk; the resume command, run exactly as printed, completes the sweep."""
    spec = _spec(tmp_path, seeds=400, steps=20)
    out = tmp_path / "o"
    proc = _start([*CLI, "sweep", str(spec), "--out", str(out)], tmp_path)
    _wait_for(lambda: proc.poll() is not None or list((out / "runs").glob("*/*.parquet")))
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGINT)
    time.sleep(0.3)
    proc.send_signal(signal.SIGINT)
    t = time.time()
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130 and time.time() - t < 5.0, (proc.returncode, stderr)
    assert ACK in stderr and "Traceback" not in stderr and "Aborted" not in stderr, stderr
    problems = check_parts(load_spec(spec), out)[1]
    assert problems and all("is missing" in p for p in problems), problems  # interrupted; nothing damaged
    hint = next(line for line in stderr.splitlines() if "finish with: " in line).split("finish with: ")[1]
    words = shlex.split(hint)
    assert words[0] == "mcjax" and words[-1] == "--resume" and "--seeds" not in words
    r = subprocess.run([*CLI, *words[1:]], capture_output=True, text=True, env=ENV, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    df = _runs(out)
    assert len(df) == 2 * 400 * 3 and not df.duplicated(["point_id", "seed_index", "filter"]).any()
    assert not (out / "_staging").exists()


def test_ctrl_c_once_stops_a_run_after_the_chunk_in_flight(tmp_path):
    proc = _start([*CLI, "run", str(WIND), "--seeds", "200", "--set", "config.n_steps=10"], tmp_path)
    _wait_for(lambda: proc.poll() is not None or "scenario" in (proc.stdout.readline() or "x"))
    assert proc.poll() is None
    t = time.time()
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=240)
    assert proc.returncode == 130, (proc.returncode, stderr)
    assert stderr.strip().splitlines()[0] == ACK and "interrupted: " in stderr and "Traceback" not in stderr, stderr
    assert time.time() - t < 120
