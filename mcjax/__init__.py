"""mcjax — batched Monte-Carlo simulation of distributed cooperative target tracking in JAX.

float64 is switched on by the entry points (CLI, engine, ``run_filter``), never as an import
side effect; see :func:`mcjax.enable_float64`.
"""

__version__ = "0.1.0"


def enable_float64() -> None:
    """Switch JAX to 64-bit floats (the default precision of every mcjax entry point)."""
    import jax

    jax.config.update("jax_enable_x64", True)
