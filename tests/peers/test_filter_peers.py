"""The benchmark peers of benchmarks/speed/filter_throughput.py agree with mcjax to 1e-9 relative:
filterpy's ExtendedKalmanFilter loop (local filter) and the numba kernels (local filter, modified
ICF; skipped when numba is not installed — it is a benchmark-only dependency)."""


import numpy as np
import pytest

from mcjax.tracking.filters import run_filter

from benchmarks.peers import filterpy_peer as bench

TOL = 1e-9


@pytest.fixture(scope="module")
def tiny():
    z, s, a, truth, common = bench.make_runs(3, 30, seed=3)
    z[0, [4, 5], 1] = np.nan  # missed measurements: predict only
    z[1, 7, :, 1] = np.nan
    return dict(measurements=z, sensor_positions=s, adjacency=a, x0=truth[0, 0], **common)


@pytest.mark.xdist_group("test_filter_peers")  # one worker builds the module fixture once
def test_filterpy_loop_matches_mcjax_local(tiny):
    pytest.importorskip("filterpy")
    x, P = run_filter("local", **tiny)
    c = dict(tiny)
    z, s, x0 = c.pop("measurements"), c.pop("sensor_positions"), c.pop("x0")
    c.pop("adjacency")
    ref = [bench.filterpy_local(z[r], s[r], x0, **c) for r in range(len(z))]
    err = bench.max_relative_error(np.stack([r[0] for r in ref]), np.stack([r[1] for r in ref]), x, P)
    assert err <= TOL, err


@pytest.mark.parametrize("kind, options", [
    ("local", {}),
    ("modified_icf", {}),
    ("modified_icf", dict(consensus_steps=3, weights="metropolis")),
    ("modified_icf", dict(consensus_steps=2, weights="max_degree", contribution="one")),
])
@pytest.mark.xdist_group("test_filter_peers")  # one worker builds the module fixture once
def test_numba_kernel_matches_mcjax(tiny, kind, options):
    pytest.importorskip("numba")
    from benchmarks.peers import numba_peer

    x, P = run_filter(kind, **tiny, **options)
    xn, Pn = numba_peer.run_filter_numba(kind, **tiny, **options)
    assert bench.max_relative_error(xn, Pn, x, P) <= TOL
