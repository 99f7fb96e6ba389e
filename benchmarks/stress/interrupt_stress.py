"""Interrupt real `mcjax` processes at random moments, finish what they leave, compare with an uninterrupted run.

Every study is run once uninterrupted (the reference, timed); then processes are started with
their environment and sent the signal at a moment drawn uniformly from a start offset to 1.1
times the reference's wall time (a process that has finished by then gets none), until
``--trials`` of them got it (at most three times as many started; one that ended first is
checked all the same). Each interrupted study is finished and compared with the reference
exactly (row by row, after sorting by the key columns). Exit code 0 when every trial held, 1
otherwise.

``--signal kill`` (issue 36): kill -9 across `mcjax sweep` and `mcjax tune`, then ``--resume``.
A sweep of Sun et al. 2011's open loop (configs/sun2011.toml: 2 points x 200 seeds, 40 steps, 4
chunks of 100 runs) and a tune of Chen & Lu 2013's consensus gain and wind process noise
(configs/chen2013.toml, 40 steps, 6 optimisation steps on 32 training seeds, a held-out
evaluation on 128 seeds in 2 chunks), in turn (half sweeps, half tunes), SIGKILL from 0.2 s
after the start. Each is resumed with ``--resume`` (run without it when the kill came before the
folder's identity file was written: there is nothing to resume), again until it ends with exit 0
(three tries). The processes share one program store (a temporary ``MCJAX_CACHE_DIR``, filled by
a warm-up run of each study), so a trial's process loads its programs as a user's second run
does and the kills land in loading, computing and writing alike; ``MCJAX_CPU_DEVICES=1``. What
must hold, for every trial:

* the resumed sweep's dataset equals the reference's exactly (every row and column); the resumed
  tune's trace equals the reference's in every column but the wall time (``wall_s``), and its
  held-out evaluation dataset exactly;
* the lock the killed process left in the folder is taken over by the resume, with one warning
  line; no lock is left at the end; no staging or temporary file is left.

``--signal int`` (issue 17): Ctrl-C (SIGINT) to `mcjax sweep` and `mcjax run`. Per scenario — by
default leader_follower (the sweep above) and uuv_imm (configs/ren2017.toml); ``--scenarios``
adds the others — the same small sweep (2 points x 200 seeds, 40 steps, 4 chunks of 100 runs)
and ``mcjax run`` of its point, ``--trials`` each, SIGINT from 0.3 s after the start; in half of
the trials (drawn) a second SIGINT follows 0.05-1.5 s later. Every interrupted sweep is resumed
with the command it printed, run as printed. What must hold:

* exit code 130 (0 only if the process had finished its work before the signal landed), never
  139 or a traceback; the first SIGINT is acknowledged ("stopping after the chunk in flight");
* after a second SIGINT the process is gone within 5 s (the time is printed);
* only complete part files: every part on disk reads and holds exactly its runs;
* the printed resume command works as printed and yields the reference dataset.

The processes run with ``MCJAX_CACHE_DIR=off``, so every one traces and compiles (the longest
window for a Ctrl-C inside XLA). With the persistent cache of commit 423cd6f on, a run that
loaded a cached program failed now and then with ``JaxRuntimeError: NOT_FOUND: Function ...
not found`` (2026-12-01, without any Ctrl-C); not seen again after c3682a1.

Usage (a given ``--seed`` makes the random draws the two scripts this one replaced made)::

    python benchmarks/stress/interrupt_stress.py --signal kill                    # 20 trials
    python benchmarks/stress/interrupt_stress.py --signal kill --trials 4 --seed 1
    python benchmarks/stress/interrupt_stress.py --signal int                     # 10 per scenario and command
    python benchmarks/stress/interrupt_stress.py --signal int --trials 3 --seed 1
"""

from __future__ import annotations

import argparse
import os
import shlex
import signal
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
ACK = "stopping after the chunk in flight"
SEEDS, CHUNK = 200, 100
SCENARIOS = {  # config file, its [config] overrides, the sweep's [grid]
    "leader_follower": ("sun2011", {"n_steps": 40, "warmup_steps": 2, "planner": '"none"',
                                    "filters": '["cif", "modified_icf"]'}, "comm_radius = [60e3, 100e3]"),
    "uuv_imm": ("ren2017", {"n_steps": 40, "warmup_steps": 2}, "comm_radius = [0.0, 450.0]"),
    "urban_bearing": ("chen2022", {"n_steps": 40, "warmup_steps": 2}, "c3 = [-0.3, 0.0]"),
    "flocking": ("lou2013", {"n_steps": 40, "warmup_steps": 2}, "R = [7.0, 8.4]"),
    "wind_formation": ("chen2013", {"n_steps": 40, "warmup_steps": 0}, "eta = [0.0, 0.01]"),
}
DEFAULT_SCENARIOS = ("leader_follower", "uuv_imm")  # the two issue 17 measured
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


def config_file(name: str) -> Path:
    return ROOT / "configs" / f"{SCENARIOS[name][0]}.toml"


def sweep_spec(folder: Path, name: str) -> Path:
    """The small sweep of scenario ``name`` as a spec file in ``folder``."""
    _, config, grid = SCENARIOS[name]
    lines = [f'base = "{config_file(name)}"', f"seeds = {SEEDS}", f"chunk_size = {CHUNK}", "[config]",
             *(f"{k} = {v}" for k, v in config.items()), "[grid]", grid]
    path = folder / f"{name}.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def run_command(name: str) -> list[str]:
    """`mcjax run` of the small sweep's config (its first point's config file, the same overrides)."""
    sets = [x for k, v in SCENARIOS[name][1].items() for x in ("--set", f"config.{k}={v}")]
    return [*CLI, "run", str(config_file(name)), "--seeds", str(SEEDS), *sets]


def start(cmd: list[str], env: dict, cwd: Path, times=(), sig: int = signal.SIGINT) -> dict:
    """Run ``cmd``, sending ``sig`` at each of ``times`` (s after the start) while it still runs: its
    exit code, output, the signals sent, the time from the last one to the exit, the wall time."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=cwd)
    sent = []
    for at in times:
        while proc.poll() is None and time.perf_counter() - t0 < at:
            time.sleep(0.005)
        if proc.poll() is None:
            proc.send_signal(sig)
            sent.append(time.perf_counter())
    out, err = proc.communicate(timeout=900)
    end = time.perf_counter()
    return {"rc": proc.returncode, "stdout": out, "stderr": err, "signals": len(sent),
            "exit_after": (end - sent[-1]) if sent else None, "wall": end - t0}


def sorted_runs(out: Path) -> pd.DataFrame:
    """The folder's dataset sorted by its key columns (and its columns by name)."""
    df = pd.read_parquet(out / "runs")
    if "point_id" in df.columns:
        df["point_id"] = df["point_id"].astype(np.int64)
    keys = [c for c in ("point_id", "seed_index", "filter") if c in df.columns]
    return df.sort_values(keys).reset_index(drop=True)[sorted(df.columns)]


def differs(what: str, got: pd.DataFrame, want: pd.DataFrame) -> list[str]:
    try:
        pd.testing.assert_frame_equal(got, want, check_exact=True)
        return []
    except AssertionError as exc:
        return [f"{what} differs: {' '.join(str(exc).split())[:200]}"]


def kill_trials(args, rng, work: Path) -> list[str]:
    env = {**os.environ, "MCJAX_CACHE_DIR": str(work / "cache"), "MCJAX_CPU_DEVICES": "1"}
    specs = {"sweep": sweep_spec(work, "leader_follower"), "tune": work / "tune.toml"}
    specs["tune"].write_text(TUNE)

    def cmd(kind: str, out: Path, *extra: str) -> list[str]:
        return [*CLI, kind, str(specs[kind]), "--out", str(out), *extra]

    def trace(out: Path) -> pd.DataFrame:
        return pd.read_parquet(out / "trace.parquet").drop(columns=["wall_s"])

    reference, wall = {}, {}
    for kind in specs:
        start(cmd(kind, work / f"warm-{kind}"), env, work)  # fills the program store
        ref = start(cmd(kind, work / f"ref-{kind}"), env, work)
        if ref["rc"] != 0:
            print(f"reference {kind} failed: {ref['stderr'].strip()[-800:]}")
            return [f"reference {kind} failed"]
        wall[kind] = ref["wall"]
        reference[kind] = sorted_runs(work / f"ref-{kind}"), trace(work / f"ref-{kind}") if kind == "tune" else None
        print(f"reference {kind}: {wall[kind]:.1f} s", flush=True)
    quota = {"sweep": (args.trials + 1) // 2, "tune": args.trials // 2}
    kills, failures, started = dict.fromkeys(quota, 0), [], 0
    for trial in range(3 * args.trials):
        kind = ("sweep", "tune")[trial % 2]
        if kills[kind] >= quota[kind]:
            if all(kills[k] >= quota[k] for k in kills):
                break
            continue
        out, at = work / f"trial-{trial:02d}", float(rng.uniform(0.2, 1.1 * wall[kind]))
        killed = start(cmd(kind, out), env, work, [at], signal.SIGKILL)["signals"] > 0
        kills[kind] += killed
        started += 1
        locked = (out / LOCK).exists()
        identity = out / f"{kind}.json"
        resumes, took_over = 0, False
        while True:
            last = start(cmd(kind, out, *(["--resume"] if identity.exists() else [])), env, work)
            resumes += 1
            took_over |= "taking over the lock" in last["stderr"]
            if last["rc"] == 0 or resumes == 3:
                break
        if last["rc"] != 0:
            problems = [f"resume exit {last['rc']}: {last['stderr'].strip()[-300:]}"]
        else:
            problems = differs("dataset", sorted_runs(out), reference[kind][0])
            if kind == "tune":
                problems += differs("trace", trace(out), reference[kind][1])
        if locked and killed and not took_over:
            problems.append("the killed process's lock was not taken over with a warning")
        left = [str(p.relative_to(out)) for p in out.rglob("*") if p.name.endswith(".tmp") or p.name == LOCK]
        left += ["_staging/"] if (out / "_staging").exists() else []
        if left:
            problems.append(f"left behind: {left}")
        result = "; ".join(problems) or "ok"
        failures += [f"trial {trial} {kind}: {result}"] if problems else []
        print(f"trial {trial:2d} {kind:5s} kill at {at:5.2f} s ({'killed' if killed else 'had finished'}; lock left: "
              f"{locked}, taken over: {took_over}); {resumes} resume(s): {result}", flush=True)
    print(f"{started} trials ({sum(kills.values())} killed mid-run: {kills['sweep']} sweeps, {kills['tune']} tunes), "
          f"{len(failures)} failed; every resumed dataset and trace "
          f"{'bit-identical to the reference' if not failures else 'NOT all identical'}")
    return failures


def int_trials(args, rng, work: Path) -> list[str]:
    from mcjax.study import check_parts, load_spec

    env = {**os.environ, "MCJAX_CACHE_DIR": "off"}
    failures, rows = [], []
    for name in args.scenarios:
        spec = sweep_spec(work, name)

        def sweep(out: Path, spec: Path = spec) -> list[str]:
            return [*CLI, "sweep", str(spec), "--out", str(out)]

        ref = start(sweep(work / f"{name}-ref"), env, work)
        if ref["rc"] != 0:
            print(ref["stderr"][-2000:])
            raise SystemExit(f"{name}: the reference sweep failed (exit {ref['rc']})")
        reference = sorted_runs(work / f"{name}-ref")
        t_run = start(run_command(name), env, work)["wall"]
        print(f"# {name}: reference sweep {ref['wall']:.1f} s, run {t_run:.1f} s", flush=True)
        for command, t_ref in (("sweep", ref["wall"]), ("run", t_run)):
            signalled, trial = 0, -1
            while signalled < args.trials and trial + 1 < 3 * args.trials:  # until --trials got a SIGINT
                trial += 1
                first = float(rng.uniform(0.3, 1.1 * t_ref))
                second = first + float(rng.uniform(0.05, 1.5)) if rng.random() < 0.5 else None
                out = work / f"{name}-{command}-{trial}"
                r = start(sweep(out) if command == "sweep" else run_command(name), env, work,
                          [first] + ([second] if second is not None else []))
                signalled += r["signals"] > 0
                row = {"scenario": name, "command": command, "trial": trial, "first_s": round(first, 2),
                       "second_s": None if second is None else round(second, 2), "signals": r["signals"],
                       "rc": r["rc"], "exit_after_s": None if r["exit_after"] is None else round(r["exit_after"], 2),
                       "ack": ACK in r["stderr"], "traceback": "Traceback" in r["stderr"], "damaged": 0,
                       "resumed_equal": None}
                bad = []
                finished = "rows in" in r["stdout"] if command == "sweep" else "filter" in r["stdout"]
                # 130 when stopped; 0 only when the work had finished before the signal landed
                if not (r["rc"] == 130 and r["signals"]) and not (r["rc"] == 0 and finished):
                    bad.append(f"exit code {r['rc']}")
                if row["traceback"]:
                    bad.append("a traceback")
                if r["signals"] and r["rc"] == 130 and not row["ack"]:
                    bad.append("no acknowledgement")
                if r["signals"] == 2 and r["rc"] == 130 and r["exit_after"] > 5.0:
                    bad.append(f"exit {r['exit_after']:.1f} s after the second SIGINT")
                if command == "sweep" and out.exists():
                    identity = (out / "sweep.json").exists()
                    # damaged or foreign part files (missing ones are the resume's to write)
                    damage = [p for p in check_parts(load_spec(spec), out)[1]
                              if "is missing" not in p] if identity else []
                    row["damaged"] = len(damage)
                    bad += damage
                    if r["rc"] == 130:
                        hint = [line.split("finish with: ", 1)[1] for line in r["stderr"].splitlines()
                                if "finish with: " in line]
                        words = shlex.split(hint[0]) if hint else []
                        if not hint:
                            bad.append("no resume hint")
                        elif words[:2] != ["mcjax", "sweep"]:
                            bad.append(f"the resume hint is not an mcjax sweep command: {hint[0]}")
                        elif identity:
                            res = subprocess.run([*CLI, *words[1:]], capture_output=True, text=True, env=env,
                                                 cwd=work)
                            if res.returncode != 0:
                                bad.append(f"the printed resume failed (exit {res.returncode}): "
                                           f"{res.stderr.strip().splitlines()[-1:]}")
                    if (out / "runs").exists() and not bad:
                        equal = differs("resumed dataset", sorted_runs(out), reference)
                        row["resumed_equal"] = not equal
                        bad += equal
                if bad:
                    failures.append(f"{name} {command} trial {trial}: {'; '.join(bad)}")
                    print("  FAIL", failures[-1], "\n", r["stderr"][-1500:], flush=True)
                rows.append(row)
                print("  " + ", ".join(f"{k}={v}" for k, v in row.items()), flush=True)
    print("\n# summary (per scenario and command)")
    for (name, command), g in pd.DataFrame(rows).groupby(["scenario", "command"], sort=False):
        one, two, got = g[g["signals"] == 1], g[g["signals"] == 2], int((g["signals"] > 0).sum())
        codes = ", ".join(f"{c}: {n}" for c, n in g["rc"].value_counts().sort_index().items())
        line = (f"{name:16s} {command:5s} {len(g)} processes, {got} got a SIGINT (the others had finished); exit codes "
                f"{{{codes}}}; acknowledged {int(g['ack'].sum())}/{got}; after a 2nd SIGINT exit within max "
                f"{two['exit_after_s'].max() if len(two) else float('nan'):.2f} s ({len(two)}); after a single "
                f"SIGINT max {one['exit_after_s'].max() if len(one) else float('nan'):.2f} s")
        if command == "sweep":
            line += (f"; damaged parts {int(g['damaged'].sum())}; datasets equal to the uninterrupted one after the "
                     f"printed resume {int((g['resumed_equal'] == True).sum())}/"  # noqa: E712
                     f"{int(g['resumed_equal'].notna().sum())} (the others stopped before writing anything)")
        print(line)
    print(f"\n{len(failures)} failure(s)" + "".join(f"\n  {f}" for f in failures))
    return failures


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--signal", choices=("kill", "int"), required=True,
                    help="kill: kill -9 sweeps and tunes, then --resume; int: Ctrl-C sweeps and runs")
    ap.add_argument("--trials", type=int, help="processes that get the signal: with kill, in all (half sweeps, half "
                    "tunes; default 20); with int, per scenario and command (default 10)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the random signal times")
    ap.add_argument("--scenarios", nargs="+", choices=list(SCENARIOS),
                    help=f"with int: scenarios to interrupt (default: {' '.join(DEFAULT_SCENARIOS)})")
    args = ap.parse_args()
    if args.signal == "kill" and args.scenarios:
        ap.error("--scenarios applies to --signal int")
    args.trials = args.trials or (20 if args.signal == "kill" else 10)
    args.scenarios = args.scenarios or list(DEFAULT_SCENARIOS)
    rng = np.random.default_rng(args.seed)
    with tempfile.TemporaryDirectory(prefix=f"mcjax-{args.signal}-") as work:
        trials = kill_trials if args.signal == "kill" else int_trials
        return 1 if trials(args, rng, Path(work)) else 0


if __name__ == "__main__":
    sys.exit(main())
