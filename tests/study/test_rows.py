"""Stage 4, the rows (mcjax.study.rows): the Parquet key columns of the swept fields, taken from
the Params that ran, and the tidy rows of a chunk carrying their own point's values."""

import itertools
from pathlib import Path

import numpy as np
import pytest

from mcjax.study import Study, build_spec, chunk_keys, run_rows

ROOT = Path(__file__).resolve().parents[2]
SUN = str(ROOT / "configs" / "sun2011.toml")


def _study(**tables) -> Study:
    return build_spec({"base": SUN, **tables}, ROOT, seeds=3)


def test_swept_columns_come_from_the_params_that_ran():
    # integers written for a float field run as floats, and the column says so; an integer
    # field's column stays integer; a per-agent axis gives one list per row
    s = _study(grid={"comm_radius": [60000, 80000], "horizon": [4, 5]})
    keys = chunk_keys(s, 0, s.n_runs)
    assert keys["comm_radius"].dtype == np.float64 and keys["horizon"].dtype == np.int64
    # points: the grid's product in the order written, 3 seeds each, point-major
    np.testing.assert_array_equal(keys["point_id"], np.repeat([0, 1, 2, 3], 3))
    np.testing.assert_array_equal(keys["seed_index"], np.tile([0, 1, 2], 4))
    np.testing.assert_array_equal(keys["comm_radius"], np.repeat([60000.0, 60000.0, 80000.0, 80000.0], 3))
    np.testing.assert_array_equal(keys["horizon"], np.repeat([4, 5, 4, 5], 3))
    # and, run by run, the values of the grid as written: its product, seeds repeated point-major
    grid = {"comm_radius": [60000, 80000], "horizon": [4, 5]}
    expected = [(c, h) for c, h in itertools.product(*grid.values()) for _seed in range(3)]
    assert list(zip(keys["comm_radius"].tolist(), keys["horizon"].tolist())) == expected

    n = s.config.n_agents
    per_agent = [[50e3] * n, [70e3] * (n - 1) + [90e3]]
    s = _study(grid={"sensing_radius": per_agent})
    keys = chunk_keys(s, 0, s.n_runs)
    assert [list(v) for v in keys["sensing_radius"][::3]] == per_agent


@pytest.mark.parametrize("start, n", [(0, 6), (4, 5)])
def test_rows_carry_the_swept_values_of_their_own_point(start, n):
    s = _study(grid={"comm_radius": [60e3, 70e3, 80e3]})
    F = len(s.config.filters)
    outputs = {name: (np.zeros((n, F)) if o.per_filter else np.zeros(n))
               for name, o in s.scenario.outputs(s.config).items()}
    rows = run_rows(s.scenario, s.config, outputs, chunk_keys(s, start, n))
    assert len(rows) == n * F
    expected = np.array([60e3, 70e3, 80e3])[rows["point_id"].to_numpy()]
    np.testing.assert_array_equal(rows["comm_radius"].to_numpy(), expected)
    assert set(rows["point_id"]) == {r // 3 for r in range(start, start + n)}
