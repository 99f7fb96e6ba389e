"""The time loop and simulate (mcjax.engine.loop): records kept, float32, NaN-aware reductions in a batch."""

import dataclasses

import numpy as np
import pytest

from mcjax import engine
from mcjax.scenarios import sun2011 as lf

from tests.engine.cases import CFG, collect as _collect, points as _points


@pytest.mark.xdist_group("test_engine.records")
def test_records_can_be_kept():
    fn = engine.compiled(lf.SCENARIO, CFG, records=True)
    params, keys = engine.chunk_inputs(_points({}), 6, 0, 0, 6, 6)  # the CRN test's program
    rec = fn(params, keys)
    assert rec.error.shape == (6, CFG.n_steps, len(CFG.filters), CFG.n_agents)
    assert rec.lambda2.shape == (6, CFG.n_steps)


def test_float32_config_runs():
    cfg = dataclasses.replace(CFG, dtype="float32", filters=("modified_icf",))
    out = _collect(cfg, _points({}), 4, 4)
    assert out["rmse"].dtype == np.float32
    assert np.isfinite(out["rmse"]).all()


@pytest.mark.parametrize("emitters", [True, False], ids=["fusion-emitters", "older-emitters"])
def test_nan_aware_max_and_min_keep_a_nan_in_a_large_batch(emitters):
    """XLA's CPU min/max over (100, 300) can drop a NaN; mcjax.tracking.metrics.nan_max / nan_min
    must not, since max_error and min_distance are how a blow-up shows in a summary. With both
    of XLA's CPU code generators (the suite's flags pick the older one; users get the newer one
    for a scenario without compiler options)."""
    import jax
    import jax.numpy as jnp

    from mcjax.tracking.metrics import nan_max, nan_min

    x = np.ones((100, 300))
    x[-1, 5] = np.nan
    opts = {"xla_cpu_use_fusion_emitters": emitters}
    got_max = np.asarray(jax.jit(jax.vmap(nan_max), compiler_options=opts)(jnp.asarray(x)))
    got_min = np.asarray(jax.jit(jax.vmap(nan_min), compiler_options=opts)(jnp.asarray(x)))
    assert np.isnan(got_max[-1]) and np.isnan(got_min[-1])
    np.testing.assert_array_equal(got_max[:-1], 1.0)
    np.testing.assert_array_equal(got_min[:-1], 1.0)
