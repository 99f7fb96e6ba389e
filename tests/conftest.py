import os

# One CPU device per test process: pytest-xdist already runs one process per core, and a
# second device would compile every batch program twice (tests that need several devices
# start a subprocess with MCJAX_CPU_DEVICES set; see tests/test_engine.py).
os.environ.setdefault("MCJAX_CPU_DEVICES", "1")
# No persistent compilation cache: each test compiles what it runs, as on a fresh machine
# (tests/test_engine.py tests the cache in subprocesses with their own folder).
os.environ.setdefault("MCJAX_CACHE_DIR", "off")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
