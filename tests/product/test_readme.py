"""The run_filter example of docs/library.md (once the README's) runs as written, in a fresh
process as a user runs it: float64 (it calls mcjax.configure()), no warning about 64-bit mode."""

import re
import subprocess
import sys
from pathlib import Path


def _example() -> str:
    text = (Path(__file__).parents[2] / "docs" / "library.md").read_text()
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


def test_library_md_sentence_on_the_example_sweep_is_what_the_sweep_gives(tmp_path):
    """docs/library.md's sentence on its example sweep (which filter wins where, with the RMSEs it
    quotes) is computed from the sweep as documented (50 seeds): the radius it names has the
    largest gap, paired by seed against each other radius (common random numbers: seed i draws
    the same noise at every point) with the whole 95 % interval above 0, and every quoted RMSE is
    the sweep's."""
    import numpy as np
    from click.testing import CliRunner
    from scipy import stats

    from mcjax.base.parquet import read_table
    from mcjax.cli import main

    text = (Path(__file__).parents[2] / "docs" / "library.md").read_text()
    section = text.split("## Writing a scenario", 1)[1].split("\n## ", 1)[0]
    for name, body in re.findall(r"`([\w.]+)`:\n\n```(?:python|toml)\n(.*?)```", section, flags=re.S):
        (tmp_path / name).write_text(body)
    r = CliRunner().invoke(main, ["sweep", str(tmp_path / "static_sweep.toml"), "--out", str(tmp_path / "out")])
    assert r.exit_code == 0, r.output
    df = read_table(tmp_path / "out")
    wide = df.pivot_table(index=["sensing_radius", "seed_index"], columns="filter", values="rmse", observed=True)
    gap = (wide["local"] - wide["pooled"]).unstack("sensing_radius")  # seeds x radii
    sentence = " ".join(section.split("The sweep prints", 1)[1].split("The test suite", 1)[0].split())
    best = float(re.search(r"`pooled` beats `local` at every radius and most at (\d+) m", sentence).group(1))
    quoted = {float(m[0]): (float(m[1]), float(m[2]))
              for m in re.findall(r"(\d+) m \(([\d.]+) against ([\d.]+) m\)", sentence)}
    assert sorted(quoted) == sorted(gap.columns), (quoted, list(gap.columns))
    means = df.groupby(["sensing_radius", "filter"], observed=True)["rmse"].mean()
    for radius, (pooled, local) in quoted.items():
        assert abs(means[(radius, "pooled")] - pooled) < 0.006 and abs(means[(radius, "local")] - local) < 0.006
        low = stats.t.interval(0.95, len(gap) - 1, loc=gap[radius].mean(), scale=stats.sem(gap[radius]))[0]
        assert low > 0, radius  # pooled beats local at every radius
    for other in gap.columns.drop(best):
        d = (gap[best] - gap[other]).to_numpy()
        low = stats.t.interval(0.95, len(d) - 1, loc=d.mean(), scale=stats.sem(d))[0]
        assert np.isfinite(low) and low > 0, (best, other, d.mean())
