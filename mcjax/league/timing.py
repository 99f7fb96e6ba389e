"""The timing pass of a league: the cost per run of each filter alone, measured on this machine.

For each scenario of the league and each filter it runs, the scenario's sweep at the league's
first point is built with that filter alone (or, when the scenario refuses it alone, with the
first of its other filters it needs beside it — said in the note), run once to compile and warm
up, then run again on ``timing_runs`` runs in this process, timed: seconds per run, compilation
excluded. The result is stated with :func:`machine`, the machine it was measured on.

The timing pass runs here whatever the sweeps' executor (the cost is of this machine).
"""

from __future__ import annotations

import os
import platform
import time
from typing import Callable

from mcjax.base.validation import SpecError
from mcjax.league.spec import League, cell_spec


def machine() -> str:
    """This machine in one line: CPU model, cores, JAX's backend and devices."""
    model = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            model = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), model)
    except OSError:
        pass
    import jax

    devices = jax.devices()
    return (f"{model}, {os.cpu_count()} cores, {platform.system()}; jax {jax.__version__} on "
            f"{len(devices)} {devices[0].platform} device(s)")


def _study(league: League, key: str, names: list[str]):
    from mcjax.study.spec import build_spec

    source = league.source
    point = source["points"][next(iter(league.points))]
    data = {k: v for k, v in source.items() if k == "base_seed"}
    spec = cell_spec(source["scenarios"][key], point, [league.config_names[n] for n in names], data)
    return build_spec(spec, league.path.parent, seeds=league.timing_runs, chunk_size=league.timing_runs)


def time_filter(league: League, key: str, filt: str) -> tuple[float, str]:
    """``(seconds per run, note)`` of scenario ``key`` running ``filt`` alone (module docstring)."""
    from mcjax.study.execute import chunk_rows

    entry = league.scenarios[key]
    study, note = None, "alone"
    for companion in [None, *(g for g in entry.filters if g != filt)]:
        try:
            study = _study(league, key, [filt] if companion is None else [companion, filt])
            note = "alone" if companion is None else f"with {companion} (the scenario needs it)"
            break
        except SpecError:
            continue
    if study is None:
        return float("nan"), "not timed: the scenario runs it only with other filters"
    for _ in chunk_rows(study):  # compile and warm up
        pass
    t0 = time.perf_counter()
    for _ in chunk_rows(study):
        pass
    return (time.perf_counter() - t0) / study.n_runs, note


def timing_pass(league: League, saved: dict, *, save: Callable[[dict], None] | None = None,
                message: Callable[[str], None] | None = None,
                should_stop: Callable[[], bool] | None = None) -> tuple[dict, bool]:
    """``(timing, stopped)``: ``saved`` completed with every scenario × filter not timed yet
    (``{"machine": …, "costs": {scenario: {filter: [seconds, note]}}}``); ``save(timing)`` after each
    filter, so a stopped league keeps what it measured; ``should_stop()`` asked between filters."""
    say, stop = message or (lambda _: None), should_stop or (lambda: False)
    timing = {"machine": saved.get("machine") or machine(), "runs": league.timing_runs,
              "costs": {k: dict(v) for k, v in (saved.get("costs") or {}).items()}}
    for key, entry in league.scenarios.items():
        done = timing["costs"].setdefault(key, {})
        for filt in entry.filters:
            if filt in done:
                continue
            if stop():
                return timing, True
            seconds, note = time_filter(league, key, filt)
            done[filt] = [seconds, note]
            say(f"timing {key} / {filt}: {seconds * 1e3:.3g} ms per run ({note})")
            if save is not None:
                save(timing)
    return timing, False
