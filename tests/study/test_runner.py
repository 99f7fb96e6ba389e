"""The sweep runner (mcjax.study.runner) called directly, without click: its rows are the
pipeline's own (study.run_sweep), a run stopped after a chunk leaves whole parts and resumes to
the rows of an uninterrupted run, and its callbacks count what the study holds."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from mcjax.study import ChunkError, OutputError, SpecError, check_parts, run_sweep
from mcjax.study.runner import SweepProgress, load_sweep, run_sweep_folder, summary_columns, sweep_headline

ROOT = Path(__file__).parents[2]
WIND = ROOT / "configs" / "chen2013.toml"


def _spec(folder: Path, seeds: int = 150) -> Path:
    """A small wind_formation sweep: 2 points x ``seeds`` seeds, chunks of 100 runs (150 seeds: 3 chunks)."""
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / "spec.toml"
    p.write_text(f'base = "{WIND}"\nseeds = {seeds}\nchunk_size = 100\n[config]\nn_steps = 3\nwarmup_steps = 0\n'
                 f'[grid]\neta = [0.0, 0.01]\n')
    return p


def _sorted(df: pd.DataFrame) -> pd.DataFrame:
    """The rows in one order whatever order they came in (by every column)."""
    return df.sort_values(list(df.columns)).reset_index(drop=True)


@pytest.fixture(scope="module")
def whole(tmp_path_factory):
    """An uninterrupted run of the runner, with everything its callbacks were told."""
    folder = tmp_path_factory.mktemp("whole")
    spec = _spec(folder)
    told = {"message": [], "warn": [], "progress": []}
    study = load_sweep(spec, out_dir=folder / "out")
    result = run_sweep_folder(study, spec_file=spec, message=told["message"].append, warn=told["warn"].append,
                              progress=told["progress"].append)
    return spec, study, result, told


def test_the_runners_rows_are_the_pipelines_own(whole):
    spec, study, result, _ = whole
    assert not result.stopped and result.out_dir == study.out_dir
    assert result.chunks_run == len(study.plan) > 1 and result.runs_run == study.n_runs
    alone = run_sweep(study, out_dir=None)  # the same study, computed and kept in memory, nothing written
    columns = summary_columns(study)
    assert list(result.rows.columns) == columns
    pd.testing.assert_frame_equal(_sorted(result.rows), _sorted(alone[columns]), check_dtype=False)


def test_the_callbacks_count_the_studys_chunks_and_runs(whole):
    _, study, _, told = whole
    steps = told["progress"]
    assert all(isinstance(p, SweepProgress) for p in steps)
    assert steps[0] == SweepProgress(0, len(study.plan), 0, study.n_runs)  # told once the folder is ready
    assert steps[-1] == SweepProgress(len(study.plan), len(study.plan), study.n_runs, study.n_runs)
    added = [b.runs_done - a.runs_done for a, b in zip(steps, steps[1:])]
    assert added == [stop - start for start, stop in study.plan] and sum(added) == study.n_runs
    assert told["message"] == [sweep_headline(study)] and told["warn"] == []


def test_stopped_after_a_chunk_the_parts_are_whole_and_resume_gives_the_same_rows(whole, tmp_path):
    spec, _, result, _ = whole
    out = tmp_path / "out"
    study = load_sweep(spec, out_dir=out)
    steps = []
    first = run_sweep_folder(study, spec_file=spec, progress=steps.append, should_stop=lambda: len(steps) > 1)
    assert first.stopped and first.rows is None and first.chunks_run == 1
    todo, problems = check_parts(study, out)
    assert todo == list(range(1, len(study.plan)))  # chunk 0 whole, the rest to run: missing, none damaged
    assert problems and all(p.startswith("chunk ") and p.endswith("is missing; re-running it") for p in problems)

    again = load_sweep(spec, out_dir=out, resume=True)
    told, warned, steps = [], [], []
    second = run_sweep_folder(again, spec_file=spec, resume=True, message=told.append, warn=warned.append,
                              progress=steps.append)
    assert warned == [f"resume: {p}" for p in problems]
    assert told[1] == f"resuming: 1 of {len(study.plan)} chunk(s) already written"
    start = study.plan[0][1]
    assert steps[0] == SweepProgress(1, len(study.plan), start, study.n_runs) and steps[-1].runs_done == study.n_runs
    assert second.runs_run == study.n_runs - start and not second.stopped
    pd.testing.assert_frame_equal(_sorted(second.rows), _sorted(result.rows))


def test_resume_takes_the_saved_seeds_and_set_values(tmp_path):
    spec = _spec(tmp_path, seeds=3)
    out = tmp_path / "out"
    with pytest.raises(OutputError, match="nothing to resume"):
        load_sweep(spec, out_dir=out, resume=True)
    from mcjax.study import prepare_output

    first = load_sweep(spec, out_dir=out, seeds=5, chunk_size=200, overrides={"config.n_steps": 4})
    prepare_output(first, out, spec_file=spec)
    again = load_sweep(spec, out_dir=out, resume=True)
    assert (again.seeds, again.chunk_runs, again.config.n_steps) == (5, first.chunk_runs, 4)
    assert load_sweep(spec, out_dir=out, resume=True, seeds=7).seeds == 7


def test_errors_are_the_pipelines_exceptions_before_anything_is_written(tmp_path):
    spec = _spec(tmp_path)
    with pytest.raises(SpecError):
        load_sweep(spec, out_dir=tmp_path / "out", overrides={"config.n_steps": -1})
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "keep.txt").write_text("x")
    with pytest.raises(OutputError):
        run_sweep_folder(load_sweep(spec, out_dir=busy), spec_file=spec)
    assert sorted(p.name for p in busy.iterdir()) == ["keep.txt"]
    assert issubclass(ChunkError, RuntimeError)
