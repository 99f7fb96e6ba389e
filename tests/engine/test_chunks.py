"""Runs to chunks and devices (mcjax.engine.chunks): the chunk plan, run -> (point, seed), bit-identity
across chunk sizes and device counts, NaN isolation."""

import numpy as np
import pytest

from mcjax import engine
from mcjax.scenarios import sun2011 as lf

from tests.engine.cases import CFG, collect as _collect, points as _points


def test_chunk_plan_covers_every_run_once():
    plan = engine.chunk_plan(1003, 100)
    covered = np.concatenate([np.arange(a, b) for a, b in plan])
    np.testing.assert_array_equal(covered, np.arange(1003))
    assert all(b - a == 100 for a, b in plan[:-1]) and plan[-1] == (1000, 1003)


@pytest.mark.xdist_group("test_engine.batch100")  # one worker compiles the 100-run program once
def test_1000_runs_bit_identical_for_chunk_sizes_100_and_1000():
    points = _points({"comm_radius": 80e3}, {"comm_radius": 100e3})  # 2 points x 500 seeds
    a = _collect(CFG, points, 500, 100)
    b = _collect(CFG, points, 500, 1000)
    assert a["rmse"].shape == (1000, len(CFG.filters))
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    # and an uneven chunk size (three batches per chunk: the devices take them in turn), on
    # its first two chunks
    outs = [out for *_, out in engine.run_chunks(lf.SCENARIO, CFG, points, 500, chunk_size=300, chunks=[0, 1])]
    for key in a:
        np.testing.assert_array_equal(a[key][:600], np.concatenate([o[key] for o in outs]), err_msg=key)


@pytest.mark.xdist_group("test_engine.batch100")
def test_nan_in_one_run_is_flagged_and_isolated():
    good = lf.default_params(CFG)
    bad = lf.default_params(CFG, p0_diag=[np.nan, 100.0, 1e4, 100.0])
    # 2 points x 50 seeds: the 100-run program the chunk-size test compiles too
    clean = _collect(CFG, engine.stack_points([good, good]), 50, 100)
    mixed = _collect(CFG, engine.stack_points([good, bad]), 50, 100)
    assert mixed["nonfinite"][50:].all() and mixed["diverged"][50:].all()
    assert not clean["nonfinite"].any()
    for key in clean:
        np.testing.assert_array_equal(clean[key][:50], mixed[key][:50], err_msg=key)


def test_results_do_not_depend_on_the_device_count(tmp_path):
    """The same sweep on 3 CPU devices (a subprocess: the count is fixed when JAX starts) and on
    one (chunks of one batch use one device) gives the same bits; the subprocess really has 3.
    There the program is compiled once and loaded on the other two devices; and again with that
    loading failing (as with a JAX that refuses it), when each device compiles its own."""
    import os
    import subprocess
    import sys

    from mcjax.scenarios import chen2013 as wf

    cfg = wf.Config(n_steps=20)
    points = engine.stack_points([wf.default_params(cfg), wf.default_params(cfg, comm_radius=2500.0)])
    one = [o for *_, o in engine.run_chunks(wf.SCENARIO, cfg, points, 150, chunk_size=100)]
    one = {k: np.concatenate([o[k] for o in one]) for k in one[0]}
    script = tmp_path / "three.py"
    script.write_text(
        "import sys, numpy as np\n"
        "from mcjax import engine, runtime\nfrom mcjax.runtime import jaxcompat\n"
        "from mcjax.scenarios import chen2013 as wf\n"
        "assert runtime.settings()['cpu_devices'] == 3, runtime.settings()\n"
        "cfg = wf.Config(n_steps=20)\n"
        "pts = engine.stack_points([wf.default_params(cfg), wf.default_params(cfg, comm_radius=2500.0)])\n"
        "def run(name):\n"
        "    out = [o for *_, o in engine.run_chunks(wf.SCENARIO, cfg, pts, 150, chunk_size=1000)]\n"
        "    np.savez(sys.argv[1] + name, **{k: np.concatenate([o[k] for o in out]) for k in out[0]})\n"
        "run('three.npz')\n"
        "def refuse(*args):\n"
        "    raise RuntimeError('no')\n"
        "jaxcompat.deserialise = refuse\n"
        "engine.forget('programs')\n"
        "run('fallback.npz')\n")
    env = {**os.environ, "MCJAX_CPU_DEVICES": "3", "MCJAX_CACHE_DIR": "off"}  # compiled here, not loaded
    subprocess.run([sys.executable, str(script), str(tmp_path) + "/"], check=True, env=env, timeout=300)
    for name in ("three.npz", "fallback.npz"):
        three = np.load(tmp_path / name)
        assert set(three.files) == set(one)
        for key in one:
            np.testing.assert_array_equal(one[key], three[key], err_msg=f"{name}: {key}")


@pytest.mark.parametrize("start, stop, n_seeds", [(0, 12, 3), (4, 11, 3), (250, 400, 100), (7, 8, 1)])
def test_runs_map_to_points_and_seeds_point_major(start, stop, n_seeds):
    """Run r of a sweep is (point, seed) in the order of itertools.product(points, seeds), for a
    chunk that starts and ends mid-point too; the points a chunk touches are those of its runs."""
    import itertools

    n_points = -(-stop // n_seeds)
    expected = list(itertools.product(range(n_points), range(n_seeds)))[start:stop]
    point, seed = engine.point_and_seed(np.arange(start, stop), n_seeds)
    assert list(zip(point.tolist(), seed.tolist())) == expected
    assert list(engine.points_of(start, stop, n_seeds)) == sorted({p for p, _ in expected})
    # and the Params and keys a chunk runs are those of its own (point, seed)
    values = np.arange(n_points, dtype=np.float64) * 10.0
    params, keys = engine.chunk_inputs({"v": values}, n_seeds, 5, start, stop, stop - start + 2)
    np.testing.assert_array_equal(params["v"][:stop - start], [10.0 * p for p, _ in expected])
    np.testing.assert_array_equal(params["v"][stop - start:], 10.0 * expected[-1][0])  # padding repeats the last run
    np.testing.assert_array_equal(keys[:stop - start], engine.run_keys(5, np.array([s for _, s in expected])))
