import gc
import os
import shutil
import tempfile

import pytest

# One CPU device per test process: pytest-xdist already runs one process per core, and a
# second device would compile every batch program twice (tests that need several devices
# start a subprocess with MCJAX_CPU_DEVICES set; see tests/engine/test_chunks.py).
os.environ.setdefault("MCJAX_CPU_DEVICES", "1")
# Tests compile small programs once and run them briefly, so XLA's cheapest backend options
# (no LLVM optimisation) are set for the suite and the subprocesses it starts: the suite's CPU
# time falls by a quarter (measured: 19.0 -> 13.9 min; compiling the closed loop 22 -> 15 s,
# running it 3x slower). What the tests check — numbers against independent references to
# 1e-8..1e-12, and bit-identity across chunk sizes, devices and processes (the same program on
# the same lanes, whatever the compiler's options) — does not depend on the optimisation level;
# users and benchmarks/ compile with XLA's defaults. The program store's key includes XLA_FLAGS.
# XLA's older CPU fusion emitters too, for every program (the built-in scenarios but Ren & Lv 2017's
# already ask for them, mcjax.contract.FAST_COMPILE): the tests' own jitted functions compile with
# ~30 % less CPU time (measured on 5 test files: 116 -> 83 s); Ren & Lv 2017's golden rows moved by
# round-off (< 5e-12 relative) and were written again. tests/engine/test_loop.py and the reference
# program of tests/study/test_sensitivity.py ask for the newer emitters by name.
_FAST_COMPILE = "--xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true --xla_cpu_use_fusion_emitters=false"
if _FAST_COMPILE not in os.environ.get("XLA_FLAGS", ""):  # xdist workers inherit it from the controller
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {_FAST_COMPILE}".strip()
# The engine's program store in a folder of this test session's own, shared by the xdist
# workers and the CLI subprocesses the tests start (they inherit the environment): a batch
# program is compiled once per session instead of once per process, and no program stored
# by an earlier session or another mcjax version is ever used. It replaces a MCJAX_CACHE_DIR
# the user exported (the tests write nothing into the user's store, counted against its size
# limit; tests/product/test_suite_store.py checks). tests/engine/test_compilation.py tests the store itself in
# subprocesses with folders of their own.
if "MCJAX_TEST_PROGRAMS" not in os.environ:  # the controller (or a plain run): make the folder
    os.environ["MCJAX_TEST_PROGRAMS"] = tempfile.mkdtemp(prefix="mcjax-test-programs-")
    _OWN_FOLDER = True
else:
    _OWN_FOLDER = False
os.environ["MCJAX_CACHE_DIR"] = os.environ["MCJAX_TEST_PROGRAMS"]


def pytest_unconfigure(config):
    """The controller removes the session's program folder when the run ends."""
    if _OWN_FOLDER and not hasattr(config, "workerinput"):
        shutil.rmtree(os.environ["MCJAX_TEST_PROGRAMS"], ignore_errors=True)


@pytest.hookimpl(trylast=True)  # after the session's fixtures are torn down
def pytest_sessionfinish(session):
    """An xdist worker's end, before it tells the controller it has finished: one garbage collection,
    then what survives it is frozen (``gc.freeze``). Once every worker has finished, the controller
    gives each 5 s to end (execnet) and then sends it a SIGINT; a worker spent them in pytest's five
    full collections of the session's heap (a second or more each after a few hundred tests), and the
    KeyboardInterrupt landed in XLA's garbage-collection callback — a traceback printed before
    "passed". The collection here is made while the controller waits, and pytest's five traverse only
    what is newer (tests/product/test_papercuts.py)."""
    if hasattr(session.config, "workerinput"):
        gc.collect()
        gc.freeze()

# xdist's workers start with COLUMNS=80 and LINES=24 in their environment (execnet); the printed tables fit
# COLUMNS when it is set (mcjax.analysis.tables.terminal_width), so the suite drops both: a test that wants a
# terminal's width sets COLUMNS itself.
for _name in ("COLUMNS", "LINES"):
    os.environ.pop(_name, None)

import mcjax  # noqa: E402

mcjax.configure()  # 64-bit mode and the CPU devices (above: one), as the CLI and the engine do
