"""The stored-row tests on another CPU model's code: XLA compiles other vector code for another CPU, so a
newcomer's laptop rounds otherwise than the machine that wrote tests/golden/ and tests/fixtures/legacy/.
``--xla_cpu_max_isa`` makes that code on this machine: here the stored-row tests run again in a process
whose XLA may use nothing newer than AVX2 (AVX where this CPU has no AVX-512), and pass by the golden-row
rule (tests/golden/rule.py). The whole suite passes so too (``XLA_FLAGS=--xla_cpu_max_isa=AVX2 python -m
pytest``; docs/benchmarks.md, "The suite on another CPU's code"), where this test skips itself."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
STORED_ROW_TESTS = ["tests/product/test_golden_rows.py", "tests/product/test_legacy_outputs.py"]


def lower_isa(flags: set[str]) -> str | None:
    """The ISA one step below this CPU's best that XLA knows (``--xla_cpu_max_isa``), or None."""
    if "avx512f" in flags:
        return "AVX2"
    if "avx2" in flags:
        return "AVX"
    return None


def cpu_flags() -> set[str]:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            return set(next((line.split(":", 1)[1].split() for line in f if line.startswith("flags")), []))
    except OSError:
        return set()


def test_the_lower_isa_is_one_xla_knows():
    assert lower_isa({"avx2", "avx512f"}) == "AVX2"
    assert lower_isa({"avx2", "fma"}) == "AVX"
    assert lower_isa({"sse4_2"}) is None


@pytest.mark.skipif("xla_cpu_max_isa" in os.environ.get("XLA_FLAGS", ""),
                    reason="this run's XLA is already held to an older ISA")
@pytest.mark.skipif(lower_isa(cpu_flags()) is None, reason="no x86-64 vector ISA to step down from here")
def test_the_stored_row_tests_pass_on_an_older_cpus_code():
    isa = lower_isa(cpu_flags())
    env = {**os.environ, "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} --xla_cpu_max_isa={isa}".strip()}
    env.pop("PYTEST_XDIST_WORKER", None)
    r = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-n", "0", "-q",
                        *STORED_ROW_TESTS], cwd=ROOT, env=env, capture_output=True, text=True, timeout=1800)
    assert r.returncode == 0, r.stdout[-6000:] + r.stderr[-2000:]
    assert " passed" in r.stdout and " failed" not in r.stdout
