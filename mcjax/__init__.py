"""mcjax — batched Monte-Carlo simulation of distributed cooperative target tracking in JAX.

Precision: importing any mcjax module that computes with JAX switches on JAX's 64-bit mode
(in :mod:`mcjax.numerics`, the one place that does it), so computations run in the dtype of
their input: float64 by default, float32 where a Config or caller asks for it. The Parquet,
report and contract modules import no JAX.
"""

__version__ = "0.1.0"
