"""Stage 5, the store (mcjax.study.store): the default output folder, the identity file, a fresh
folder, --resume finding exactly the chunks whose parts are missing, and the refusals (a
different sweep, a folder not empty, --resume with --force) before anything is written."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from mcjax.study import (IDENTITY_FILE, OutputError, build_spec, default_out_dir, identity, missing_chunks,
                         prepare_output, read_identity, run_sweep)

ROOT = Path(__file__).resolve().parents[2]
WIND = str(ROOT / "configs" / "chen2013.toml")


def _study(seeds: int = 150):
    return build_spec({"base": WIND, "config": {"n_steps": 3, "warmup_steps": 0}, "grid": {"eta": [0.0, 0.01]}},
                      ROOT, seeds=seeds, chunk_size=100)


def test_the_default_folder_is_inside_results():
    for name, want in (("...toml", "results/sweep"), (".toml", "results/toml"), ("a b$.toml", "results/a_b_"),
                       ("x/.hidden.toml", "results/hidden"), ("sweeps/sun2011.toml", "results/sun2011")):
        assert default_out_dir(name) == Path(want), name


def test_a_fresh_folder_gets_the_identity_and_resume_finds_the_chunks_missing(tmp_path):
    s = _study()
    out = tmp_path / "out"
    assert prepare_output(s, out, spec_file=tmp_path / "spec.toml") is None  # fresh: every chunk to run
    saved = read_identity(out)
    assert saved == json.loads((out / IDENTITY_FILE).read_text()) and {k: saved[k] for k in identity(s)} == identity(s)
    assert identity(s)["n_runs"] == 300 and saved["set"] == {} and saved["spec_file"].endswith("spec.toml")
    run_sweep(s, out, chunks=[1])
    assert missing_chunks(s, out) == [0, 2]
    assert prepare_output(s, out, resume=True) == [0, 2]


def test_refusals_come_before_anything_is_written(tmp_path):
    s = _study()
    with pytest.raises(OutputError, match="exclude each other"):
        prepare_output(s, tmp_path / "a", resume=True, force=True)
    with pytest.raises(OutputError, match="nothing to resume"):
        prepare_output(s, tmp_path / "b", resume=True)
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "notes.txt").write_text("mine")
    with pytest.raises(OutputError):
        prepare_output(s, busy)
    with pytest.raises(OutputError):
        prepare_output(s, busy, force=True)  # not a sweep's folder: --force leaves it alone
    assert [p.name for p in busy.iterdir()] == ["notes.txt"]
    prepare_output(s, tmp_path / "c")
    with pytest.raises(OutputError, match="different sweep"):
        prepare_output(_study(seeds=149), tmp_path / "c", resume=True)
    assert read_identity(tmp_path / "c")["seeds"] == 150


def test_a_tune_into_the_folder_of_the_same_tune_is_told_it_is_there(tmp_path):
    """The same tune spec into its own folder: told it already holds this tune (--resume), not 'not empty'; a
    different spec there is still refused as before, --force replaces it, and a folder whose tune wrote nothing
    is reused."""
    from mcjax.study.store import TUNE_IDENTITY_FILE, prepare_tune_output

    out = tmp_path / "tune"
    prepare_tune_output({"spec": {"a": 1}}, out)
    (out / "trace.parquet").write_bytes(b"x")  # something the tune wrote
    with pytest.raises(OutputError, match=r"already holds this tune \(the same spec\): pass --resume"):
        prepare_tune_output({"spec": {"a": 1}}, out)
    with pytest.raises(OutputError, match="is not empty; pass --resume"):
        prepare_tune_output({"spec": {"a": 2}}, out)
    prepare_tune_output({"spec": {"a": 1}}, out, force=True)
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == [TUNE_IDENTITY_FILE]
    prepare_tune_output({"spec": {"a": 1}}, out)  # only the identity file: a tune that wrote nothing, reused
