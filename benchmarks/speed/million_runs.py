"""One million runs in one ``mcjax sweep`` (issue 35, item 3): Sun et al. 2011 in open loop, 50
steps, the config's five filters, one point — beside the same sweep at 100,000 runs, and
``mcjax report`` on the result.

Each command runs as its own process under ``/usr/bin/time -v`` (peak resident memory, wall
time); the sweep's own "N runs in X s" line gives its time (compilation included: the program
store is warm after the first of them). Printed: runs, wall, ms per run, peak RSS, rows, dataset
size (and per run), ``mcjax report``'s wall and peak RSS.

    python benchmarks/speed/million_runs.py                       # 100,000 then 1,000,000 runs
    python benchmarks/speed/million_runs.py --runs 10000 100000   # a quick look

The datasets go to ``--out`` (default ``results/million``, ~0.5 GB at a million runs); delete
them afterwards.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

SPEC = """description = "One million runs: Sun et al. 2011, open loop, 50 steps (benchmarks/speed/million_runs.py)"
base = "{base}"
seeds = {runs}
chunk_size = {chunk}

[config]
planner = "none"     # open loop: every UAV holds heading_cmd
n_steps = 50
warmup_steps = 10
"""


def _timed(cmd: list[str]) -> dict:
    """Run ``cmd`` under /usr/bin/time -v: its output, wall time and peak resident memory."""
    t0 = time.perf_counter()
    r = subprocess.run(["/usr/bin/time", "-v", *cmd], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed ({r.returncode}):\n{r.stdout[-2000:]}\n{r.stderr[-3000:]}")
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", r.stderr)
    return {"out": r.stdout, "wall_s": wall, "peak_rss_gib": int(rss.group(1)) / 2**20 if rss else float("nan")}


def _size(folder: Path) -> int:
    return sum(f.stat().st_size for f in folder.rglob("*.parquet"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, nargs="+", default=[100_000, 1_000_000])
    ap.add_argument("--chunk-size", type=int, default=50_000)
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "million")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    mcjax = [sys.executable, "-m", "mcjax.cli"]
    print(f"load average at start: {os.getloadavg()[0]:.1f}", flush=True)
    for runs in a.runs:
        spec = a.out / f"sun2011_{runs}.toml"
        spec.write_text(SPEC.format(base=(ROOT / "configs" / "sun2011.toml").as_posix(), runs=runs,
                                    chunk=min(a.chunk_size, runs)))
        out = a.out / f"sun2011_{runs}"
        s = _timed([*mcjax, "sweep", str(spec), "--out", str(out), "--force"])
        m = re.search(r"(\d+) rows in .*?; (\d+) runs in ([0-9.]+) s", s["out"])
        rows, n, secs = int(m.group(1)), int(m.group(2)), float(m.group(3))
        size = _size(out / "runs")
        rep = _timed([*mcjax, "report", str(out)])
        print(f"runs {n:>9,}  sweep {secs:8.1f} s ({1e3 * secs / n:.3f} ms/run; process {s['wall_s']:.1f} s, "
              f"peak RSS {s['peak_rss_gib']:.2f} GiB)  rows {rows:,}  dataset {size / 2**20:.1f} MiB "
              f"({size / n:.0f} B/run)  report {rep['wall_s']:.1f} s (peak RSS {rep['peak_rss_gib']:.2f} GiB)  "
              f"load {os.getloadavg()[0]:.1f}", flush=True)


if __name__ == "__main__":
    main()
