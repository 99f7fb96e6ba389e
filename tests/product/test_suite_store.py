"""The test suite keeps out of the user's program store whatever MCJAX_CACHE_DIR says
(tests/conftest.py): a pytest session started with MCJAX_CACHE_DIR pointing at a user's
folder compiles a program, and that folder stays empty."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

PROBE = "MCJAX_SUITE_STORE_PROBE"  # set only in the subprocess below: the probe runs there alone


@pytest.mark.skipif(PROBE not in os.environ, reason="runs inside test_the_suite_leaves_the_users_store_alone")
def test_probe_compiles_through_the_engine():
    from mcjax import runtime

    user = Path(os.environ[PROBE])
    store = runtime.cache_dir()
    print("store", store)
    assert store is not None and store.resolve() != user.resolve()
    from mcjax import engine
    from mcjax.scenarios import chen2013 as wf

    cfg = wf.Config(n_steps=15)  # a small program (as in tests/engine/test_chunks.py), compiled and stored
    list(engine.run_chunks(wf.SCENARIO, cfg, engine.stack_points([wf.default_params(cfg)]), 20, chunk_size=100))
    print("stats", runtime.STATS)
    assert runtime.STATS["stored"] + runtime.STATS["loaded"] >= 1  # the store was used, not bypassed

def test_the_suite_leaves_the_users_store_alone(tmp_path):
    user = tmp_path / "my-store"
    user.mkdir()
    env = {k: v for k, v in os.environ.items() if k != "MCJAX_TEST_PROGRAMS"}  # a fresh session, as a user starts it
    env.update({"MCJAX_CACHE_DIR": str(user), PROBE: str(user)})
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", "0", "-p", "no:cacheprovider", "-s",
                        f"{__file__}::test_probe_compiles_through_the_engine"],
                       cwd=Path(__file__).parents[2], env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert "store " in r.stdout and "stats " in r.stdout, r.stdout[-2000:]  # the probe ran, not skipped
    assert list(user.iterdir()) == []
