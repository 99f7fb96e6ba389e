"""The tune runner (mcjax.tune.runner) called directly, without click: its held-out rows are the
pipeline's own run of the evaluation sweep, a tune stopped after a step resumes to the trace of
an uninterrupted one, and its callbacks count the steps and runs the spec asks for."""

from __future__ import annotations

import pandas as pd
import pytest

from mcjax import tune
from mcjax.study import OutputError, run_sweep
from mcjax.tune.runner import TuneProgress, run_tune, tune_headline
from tests.tune.test_tune import SPEC, _write


def _steady(trace: pd.DataFrame) -> pd.DataFrame:
    """A trace without its wall times (the only columns that differ between two runs)."""
    return trace.drop(columns=[c for c in trace.columns if c.startswith("wall") or "time" in c]).reset_index(drop=True)


@pytest.fixture(scope="module")
def whole(tmp_path_factory):
    """An uninterrupted tune, with the order of everything its callbacks were told."""
    folder = tmp_path_factory.mktemp("tune_runner")
    spec_file = _write(folder, SPEC)
    spec = tune.load_tune_spec(spec_file)
    told = []
    result = run_tune(spec, out_dir=folder / "out", spec_file=spec_file, message=told.append,
                      progress=told.append, started=lambda: told.append("started"))
    return spec_file, spec, result, told


def test_the_callbacks_count_the_steps_and_the_held_out_runs(whole):
    _, spec, result, told = whole
    assert not result.stopped and told[:2] == ["started", tune_headline(spec)]
    train = [t for t in told if isinstance(t, TuneProgress) and t.stage == "train"]
    assert [t.done for t in train] == list(range(spec.steps + 2)) and {t.total for t in train} == {spec.steps + 1}
    assert train[0].row is None and [t.row["loss"] for t in train[1:]] == list(result.trace["loss"])
    evaluate = [t for t in told if isinstance(t, TuneProgress) and t.stage == "evaluate"]
    assert evaluate[0].done == 0 and evaluate[-1].done == evaluate[0].total == result.evaluation.n_runs
    assert result.evaluation.n_runs == 2 * spec.heldout_seeds


def test_the_held_out_rows_are_the_pipelines_run_of_the_evaluation(whole):
    _, spec, result, _ = whole
    ev = tune.evaluation_spec(spec, tune.final_values(spec, result.trace))
    alone = run_sweep(ev, out_dir=None)  # the evaluation sweep, computed in memory, nothing written
    columns = [c for c in alone.columns if c in result.runs.columns]
    assert len(columns) > 5 and len(result.runs) == len(alone)
    order = ["point_id", "seed_index", "filter"]
    pd.testing.assert_frame_equal(result.runs[columns].sort_values(order).reset_index(drop=True),
                                  alone[columns].sort_values(order).reset_index(drop=True), check_dtype=False,
                                  check_categorical=False)
    assert len(result.paired) > 0


def test_stopped_after_a_step_resumes_to_the_uninterrupted_trace(whole, tmp_path):
    spec_file, spec, result, _ = whole
    out = tmp_path / "out"
    seen = []
    first = run_tune(spec, out_dir=out, spec_file=spec_file, progress=seen.append, should_stop=lambda: len(seen) > 1)
    assert first.stopped and first.runs is None and len(first.trace) < spec.steps + 1
    with pytest.raises(OutputError, match="holds a previous tune|not empty|already"):
        run_tune(spec, out_dir=out, spec_file=spec_file)  # a fresh tune into it: refused, nothing changed
    told = []
    second = run_tune(spec, out_dir=out, spec_file=spec_file, resume=True, message=told.append)
    assert not second.stopped and told[1].startswith(f"resuming: {len(first.trace)} of {spec.steps + 1} ")
    pd.testing.assert_frame_equal(_steady(second.trace), _steady(result.trace))
    pd.testing.assert_frame_equal(second.paired, result.paired)
