"""mcjax — batched Monte-Carlo simulation of distributed cooperative target tracking in JAX.

``import mcjax`` imports no JAX and changes no setting. JAX's process-wide settings are applied
by :func:`configure` — called by the CLI and by the engine's entry points, and to be called
first by a program that uses mcjax's library functions (graph, filters, numerics) directly.
"""

__version__ = "0.1.0"


def configure() -> None:
    """Apply the JAX settings mcjax computes with, once per process (later calls do nothing):

    * JAX's 64-bit mode (``jax_enable_x64``): computations run in the dtype of their input,
      float64 by default, float32 where a Config or caller asks for it. A library function
      called without it warns once (:func:`mcjax.tracking.numerics.require_x64`) and computes in
      float32.
    * one CPU device per core, or ``$MCJAX_CPU_DEVICES`` (the engine spreads a sweep's batches
      over them). If JAX's backend already runs (something computed with JAX before), its
      devices are kept.

    :func:`mcjax.runtime.settings` tells what applies."""
    from mcjax import runtime

    runtime.configure()
