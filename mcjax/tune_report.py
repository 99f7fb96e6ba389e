"""``mcjax report`` on the output folder of ``mcjax tune``: the trace, the initial and tuned
values and the held-out comparison paired by seed. This module does not import JAX."""
