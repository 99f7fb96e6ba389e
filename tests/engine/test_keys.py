"""Run keys (mcjax.engine.keys): the numpy Threefry gives JAX's keys; common random numbers across points."""

import jax
import numpy as np
import pytest

from mcjax import engine
from mcjax.scenarios import sun2011 as lf

from tests.engine.cases import CFG, points as _points


@pytest.mark.xdist_group("test_engine.records")  # one worker compiles the 6-run records program once
@pytest.mark.parametrize("base_seed", [0, 1, 2**31 - 1, 2**32 - 1, 2**32, 2**40 + 5, -1, -2**63, 2**63 - 1])
def test_numpy_run_keys_are_jax_keys(base_seed):
    """The engine's numpy Threefry gives JAX's own PRNGKey/fold_in keys, bit for bit (seed
    indices from 0 up, random 32-bit ones and the largest), also for base seeds past 32 bits."""
    idx = np.concatenate([np.arange(40), np.random.default_rng(3).integers(0, 2**32, 100), [2**32 - 1]]).astype(np.uint32)
    want = np.stack([np.asarray(jax.random.fold_in(jax.random.PRNGKey(base_seed), int(i))) for i in idx[::7]])
    got = engine.run_keys(base_seed, idx)
    assert got.dtype == np.uint32 and got.shape == (len(idx), 2)
    np.testing.assert_array_equal(got[::7], want)
    np.testing.assert_array_equal(got, np.asarray(jax.vmap(lambda s: engine.run_key(base_seed, s))(idx)))


def test_common_random_numbers_across_points():
    """Seed s draws the same target and the same measurement noise at every point: with a comm
    radius that changes nothing for the CIF (it ignores the graph), the target path, the
    measurements and the CIF's errors are the same at both points, while the graph-based
    modified ICF differs. (The CIF is compared to 1e-12: XLA may round a lane of a batch
    differently from another in the last bit; runs keep their lanes whatever the chunk size.)"""
    fn = engine.compiled(lf.SCENARIO, CFG, records=True)
    rec = fn(*engine.chunk_inputs(_points({"comm_radius": 60e3}, {"comm_radius": 100e3}), 3, 0, 0, 6, 6))
    for name in ("target", "positions", "measurements"):
        a = np.asarray(getattr(rec, name))
        np.testing.assert_array_equal(a[:3], a[3:], err_msg=name)
    err = np.asarray(rec.error)
    cif, mod = CFG.filters.index("cif"), CFG.filters.index("modified_icf")
    np.testing.assert_allclose(err[:3, :, cif], err[3:, :, cif], rtol=1e-12, atol=1e-9)
    assert not np.allclose(err[:3, :, mod], err[3:, :, mod])
    assert len({float(err[s, -1, cif, 0]) for s in range(3)}) == 3  # different seeds differ
