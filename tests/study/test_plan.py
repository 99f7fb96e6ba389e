"""Stage 2, the plan (mcjax.study.plan): the Study's points table, each point's Params and its
chunk plan, built once and again for a changed Study."""

import dataclasses
from pathlib import Path

import numpy as np

from mcjax.study import Study, build_spec

ROOT = Path(__file__).resolve().parents[2]
SUN = str(ROOT / "configs" / "sun2011.toml")


def _study(**tables) -> Study:
    return build_spec({"base": SUN, **tables}, ROOT, seeds=3)


def test_points_params_and_plan_are_built_once_and_again_for_a_changed_study():
    s = _study(grid={"comm_radius": [60e3, 80e3]}, zip={"horizon": [4, 5], "sigma_bearing": [0.01, 0.02]})
    assert s.points is s.points and s.params is s.params and s.plan is s.plan
    assert list(s.points.columns) == ["point_id", "comm_radius", "horizon", "sigma_bearing"]
    assert len(s.points) == s.n_points == 4 and s.n_runs == 12
    np.testing.assert_array_equal(s.params.comm_radius, [60e3, 60e3, 80e3, 80e3])
    np.testing.assert_array_equal(s.params.horizon, [4, 5, 4, 5])
    other = dataclasses.replace(s, seeds=5)
    assert other.points is not s.points and other.n_runs == 20
    np.testing.assert_array_equal(other.params.comm_radius, s.params.comm_radius)
    one = s.point(3)
    assert float(one.comm_radius) == 80e3 and float(one.horizon) == 5
    assert np.shape(one.initial_positions) == np.shape(s.base_params.initial_positions)


def test_the_chunk_plan_covers_every_run_once_in_order():
    s = dataclasses.replace(_study(grid={"comm_radius": [60e3, 70e3, 80e3]}), seeds=50, chunk_size=40)
    starts, stops = zip(*s.plan)
    assert starts[0] == 0 and stops[-1] == s.n_runs == 150 and list(starts[1:]) == list(stops[:-1])
    assert all(b - a == s.chunk_runs for a, b in s.plan[:-1]) and s.runs_in(None) == s.n_runs
    assert s.runs_in([0, len(s.plan) - 1]) == (s.plan[0][1] - s.plan[0][0]) + (s.plan[-1][1] - s.plan[-1][0])
