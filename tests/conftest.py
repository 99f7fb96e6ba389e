import os

# One CPU device per test process: pytest-xdist already runs one process per core, and a
# second device would compile every batch program twice (tests that need several devices
# start a subprocess with MCJAX_CPU_DEVICES set; see tests/test_engine.py).
os.environ.setdefault("MCJAX_CPU_DEVICES", "1")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
