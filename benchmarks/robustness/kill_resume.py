"""kill -9 at random moments across `mcjax sweep` and `mcjax tune`, then --resume (issue 36).

Two small studies, each run once uninterrupted (the reference): a sweep of Sun et al. 2011's
open loop (configs/sun2011.toml: 2 points x 200 seeds, 40 steps, 4 chunks of 100 runs) and a
tune of Chen & Lu 2013's consensus gain and wind process noise (configs/chen2013.toml, 40 steps,
6 optimisation steps on 32 training seeds, a held-out evaluation on 128 seeds in 2 chunks).
Then processes (sweeps and tunes in turn) are each sent SIGKILL at a moment drawn uniformly
between 0.2 s after the start and 1.1 times the reference's wall time, until ``--trials`` of
them were killed before they ended (half sweeps, half tunes; at most three times as many
started: one that ended first is checked all the same), and each is resumed with ``--resume`` (run without it when the kill came before the folder's identity
file was written: there is nothing to resume), the resume again until it ends with exit 0.
What must hold, for every trial:

* the resumed sweep's dataset equals the reference's exactly (every row and column, compared
  after sorting by the key columns); the resumed tune's trace equals the reference's in every
  column but the wall time (``wall_s``), and its held-out evaluation dataset exactly;
* the lock the killed process left in the folder is taken over by the resume, with one warning
  line; no lock is left at the end; no staging or temporary file is left.

The processes share one program store (a temporary ``MCJAX_CACHE_DIR``), filled by the
reference runs, so a trial's process loads its programs as a user's second run does, and the
kills land in loading, computing and writing alike. ``MCJAX_CPU_DEVICES=1``.

Usage::

    python benchmarks/robustness/kill_resume.py                  # 20 trials
    python benchmarks/robustness/kill_resume.py --trials 4 --seed 1

Exit code 0 when every trial held, 1 otherwise.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[2]
CLI = [sys.executable, "-m", "mcjax.cli"]
LOCK = ".mcjax.lock"

SWEEP = f'''base = "{ROOT / "configs" / "sun2011.toml"}"
seeds = 200
chunk_size = 100

[config]
n_steps = 40
warmup_steps = 2
planner = "none"
filters = ["cif", "modified_icf"]

[grid]
comm_radius = [60e3, 100e3]
'''

TUNE = f'''base = "{ROOT / "configs" / "chen2013.toml"}"
chunk_size = 64

[config]
filters = ["kcf"]
n_steps = 40

[tune]
optimizer = "adam"
learning_rate = 0.15
steps = 6
train_seeds = 32
train_base_seed = 1
heldout_seeds = 128
heldout_base_seed = 0
gradient = "forward"
gradient_window = 0

[tune.params.eta]
low = 1e-3
high = 0.1
scale = "log"

[tune.params.sigma_wind_process]
low = 0.05
high = 5.0
scale = "log"

[tune.loss]
filter = "kcf"
'''


def _run(kind: str, spec: Path, out: Path, env: dict, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, kind, str(spec), "--out", str(out), *extra], env=env, capture_output=True, text=True,
                          timeout=900)


def _runs(out: Path) -> pd.DataFrame:
    df = pd.read_parquet(out / "runs")
    keys = [c for c in ("point_id", "seed_index", "filter") if c in df.columns]
    df = df.assign(point_id=df["point_id"].astype(int)) if "point_id" in df.columns else df
    return df.sort_values(keys).reset_index(drop=True)[sorted(df.columns)]


def _trace(out: Path) -> pd.DataFrame:
    return pd.read_parquet(out / "trace.parquet").drop(columns=["wall_s"])


def _leftovers(out: Path) -> list[str]:
    bad = [str(p.relative_to(out)) for p in out.rglob("*") if p.name.endswith(".tmp") or p.name == LOCK]
    return bad + (["_staging/"] if (out / "_staging").exists() else [])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    work = Path(tempfile.mkdtemp(prefix="mcjax-kill-"))
    env = {**os.environ, "MCJAX_CACHE_DIR": str(work / "cache"), "MCJAX_CPU_DEVICES": "1"}
    specs = {"sweep": work / "sweep.toml", "tune": work / "tune.toml"}
    specs["sweep"].write_text(SWEEP)
    specs["tune"].write_text(TUNE)
    reference, wall = {}, {}
    for kind, spec in specs.items():
        _run(kind, spec, work / f"warm-{kind}", env)  # fills the program store
        t0 = time.perf_counter()
        done = _run(kind, spec, work / f"ref-{kind}", env)
        wall[kind] = time.perf_counter() - t0
        if done.returncode != 0:
            print(f"reference {kind} failed: {done.stderr.strip()[-800:]}")
            return 1
        reference[kind] = (_runs(work / f"ref-{kind}"), _trace(work / f"ref-{kind}") if kind == "tune" else None)
        print(f"reference {kind}: {wall[kind]:.1f} s")
    failures, rows, kills = 0, [], {"sweep": 0, "tune": 0}
    for trial in range(3 * args.trials):
        kind = ("sweep", "tune")[trial % 2]
        if kills[kind] >= (args.trials + (kind == "sweep")) // 2:
            if all(kills[k] >= (args.trials + (k == "sweep")) // 2 for k in kills):
                break
            continue
        spec, out = specs[kind], work / f"trial-{trial:02d}"
        at = float(rng.uniform(0.2, 1.1 * wall[kind]))
        proc = subprocess.Popen([*CLI, kind, str(spec), "--out", str(out)], env=env, stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        time.sleep(at)
        killed = proc.poll() is None
        if killed:
            proc.kill()
            kills[kind] += 1
        proc.wait()
        locked = (out / LOCK).exists()
        identity = out / ("sweep.json" if kind == "sweep" else "tune.json")
        resumes, took_over, last = 0, False, None
        while resumes < 3:
            last = _run(kind, spec, out, env, *(["--resume"] if identity.exists() else []))
            resumes += 1
            took_over |= "taking over the lock" in last.stderr
            if last.returncode == 0:
                break
        problems = []
        if last.returncode != 0:
            problems.append(f"resume exit {last.returncode}: {last.stderr.strip()[-300:]}")
        else:
            runs = _runs(out)
            try:
                pd.testing.assert_frame_equal(runs, reference[kind][0], check_exact=True)
            except AssertionError as exc:
                problems.append(f"dataset differs: {str(exc).splitlines()[0]}")
            if kind == "tune":
                try:
                    pd.testing.assert_frame_equal(_trace(out), reference[kind][1], check_exact=True)
                except AssertionError as exc:
                    problems.append(f"trace differs: {str(exc).splitlines()[0]}")
        if locked and killed and not took_over:
            problems.append("the killed process's lock was not taken over with a warning")
        if _leftovers(out):
            problems.append(f"left behind: {_leftovers(out)}")
        failures += bool(problems)
        state = "killed" if killed else "had finished"
        rows.append((trial, kind, at, state, locked, took_over, resumes, "ok" if not problems else "; ".join(problems)))
        print(f"trial {trial:2d} {kind:5s} kill at {at:5.2f} s ({state}; lock left: {locked}, taken over: "
              f"{took_over}); {resumes} resume(s): {'ok' if not problems else '; '.join(problems)}", flush=True)
        shutil.rmtree(out, ignore_errors=True)
    killed_n = sum(r[3] == "killed" for r in rows)
    print(f"{len(rows)} trials ({killed_n} killed mid-run: {kills['sweep']} sweeps, {kills['tune']} tunes), {failures} "
          f"failed; every resumed dataset and trace "
          f"{'bit-identical to the reference' if not failures else 'NOT all identical'}")
    shutil.rmtree(work, ignore_errors=True)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
