"""What the engine's test files share: a 10-step leader-follower Config, its sweep points and
the outputs of a sweep collected over its chunks.

10 steps: what these tests check (chunking, keys, NaN isolation, bit-identity) does not depend
on the length of a run, and the 1000-run test runs 2,600 of them."""

import numpy as np

from mcjax import engine
from mcjax.scenarios import sun2011 as lf

CFG = lf.Config(n_steps=10, warmup_steps=5)


def points(*overrides):
    """One leader-follower Params per override dict, stacked along a point axis."""
    return engine.stack_points([lf.default_params(CFG, **o) for o in overrides])


def collect(cfg, point_params, n_seeds, chunk_size):
    """A sweep's outputs, every chunk's concatenated in run order."""
    outs = [out for _, _, _, out in engine.run_chunks(lf.SCENARIO, cfg, point_params, n_seeds, chunk_size=chunk_size)]
    return {k: np.concatenate([o[k] for o in outs]) for k in outs[0]}
