"""The run_filter example of docs/library.md (once the README's) runs as written, in a fresh
process as a user runs it: float64 (it calls mcjax.configure()), no warning about 64-bit mode."""

import re
import subprocess
import sys
from pathlib import Path


def _example() -> str:
    text = (Path(__file__).parents[1] / "docs" / "library.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    return next(b for b in blocks if "run_filter(" in b)


def test_readme_run_filter_example_runs():
    example = _example()
    r = subprocess.run([sys.executable, "-W", "always::UserWarning", "-c", example + "\nprint('dtype', x.dtype)\n"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert "(50, 3, 4) (50, 3, 4, 4)" in out and "dtype float64" in out, out
    assert "64-bit mode is off" not in r.stderr, r.stderr
    errors = re.search(r"final position errors, m: \[(.*?)\]", out).group(1).split()
    assert all(float(e) < 200.0 for e in errors)  # a working filter, not a diverged one


def test_without_configure_the_example_says_so_once_and_computes_in_float32():
    example = _example().replace("mcjax.configure()", "pass")
    r = subprocess.run([sys.executable, "-W", "always::UserWarning", "-c", example + "\nprint('dtype', x.dtype)\n"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "dtype float32" in r.stdout and r.stderr.count("64-bit mode is off") == 1, (r.stdout, r.stderr)
