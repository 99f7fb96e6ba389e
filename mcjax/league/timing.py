"""The timing pass of a league: the cost per run of each filter alone, measured on this machine.

"Alone" means the scenario built with that filter as its only filter, so the program times no other
filter's work. For each scenario of the league and each filter it runs, the scenario's sweep at the
league's first point is built that way (or, when the scenario refuses a filter alone, with the first
of its other filters it needs beside it — Sun et al. 2011's planner needs the modified ICF; said in
the note, and the cost is then of both), on :func:`repeat_runs` runs. It is run once untimed (that
compiles the program and warms it up), then :data:`REPEATS` times, each repeat timed: per repeat,
seconds per run with compilation excluded. The cost is the median of the repeats, and their range
(lowest, highest) is the measurement's spread. The runs scale with the league's: ``timing_runs``
(the file's) or the runs per cell (``--seeds``), whichever is smaller, split into the repeats — so a
quick look times few runs.

Each filter alone is a program of its own to compile: most of the pass's time. :class:`Warmup` runs
the untimed repeats (the compilations) in a thread of its own while the league's sweeps run — a
sweep of at most 100 runs keeps one core busy, so the other compiles — and in two once they are
done; the timing pass waits for every one to finish before it times anything, so no compilation
runs beside a timed repeat.

The pass runs here whatever the sweeps' executor (the cost is of this machine, :func:`machine`),
says where it is after each repeat (``progress``), and is stopped within a fraction of a second by
``should_stop()``: the repeat in flight (a compilation too) is left to finish in the background and
its time is not kept. What it measured is saved after each filter, so a resumed league keeps it.
"""

from __future__ import annotations

import os
import platform
import statistics
import threading
import time
from typing import Callable

from mcjax.base.validation import SpecError
from mcjax.league.spec import League, cell_spec
from mcjax.study.runner import SweepProgress

#: Timed repeats of each filter (after one untimed repeat that compiles).
REPEATS = 3
#: How often a running repeat looks at ``should_stop()`` (seconds).
POLL_S = 0.1


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


def load_average() -> float | None:
    """The machine's load average over the last minute (None where the system gives none)."""
    try:
        return round(os.getloadavg()[0], 2)
    except (AttributeError, OSError):
        return None


def repeat_runs(league: League) -> int:
    """Runs of each timed repeat: ``timing_runs`` or the runs per cell, whichever is smaller, split into
    :data:`REPEATS` (rounded up); 0 when the league has no timing pass."""
    runs = min(league.timing_runs, league.seeds)
    return -(-runs // REPEATS) if runs else 0


def stages(league: League) -> dict[str, int]:
    """``{"timing <scenario>": steps}`` of the progress the pass reports: one step per repeat of each filter
    (the untimed one included); empty without a timing pass."""
    if not league.timing_runs:
        return {}
    return {f"timing {key}": len(entry.filters) * (1 + REPEATS) for key, entry in league.scenarios.items()}


def _study(league: League, key: str, names: list[str], runs: int):
    from mcjax.study.spec import build_spec

    source = league.source
    point = source["points"][next(iter(league.points))]
    data = {k: v for k, v in source.items() if k == "base_seed"}
    spec = cell_spec(source["scenarios"][key], point, [league.config_names[n] for n in names], data)
    return build_spec(spec, league.path.parent, seeds=runs, chunk_size=runs)


def timed_study(league: League, key: str, filt: str, runs: int):
    """``(study, note)``: scenario ``key`` with ``filt`` alone on ``runs`` runs, or with the first other
    filter of the scenario it needs (the note says which); ``(None, why)`` when neither builds."""
    entry = league.scenarios[key]
    for companion in [None, *(g for g in entry.filters if g != filt)]:
        try:
            study = _study(league, key, [filt] if companion is None else [companion, filt], runs)
        except SpecError:
            continue
        return study, "alone" if companion is None else f"with {companion} (the scenario needs it)"
    return None, "not timed: the scenario runs it only with other filters"


def run_unless_stopped(work: Callable[[], None], stop: Callable[[], bool]) -> bool:
    """Run ``work()`` in a thread of its own, looking at ``stop()`` every :data:`POLL_S`: True when it
    finished, False when ``stop()`` turned True first (the work is left to finish in the background).
    An exception of ``work`` is raised here."""
    failed: list[BaseException] = []

    def run() -> None:
        try:
            work()
        except BaseException as exc:  # noqa: BLE001 - raised again in the caller's thread
            failed.append(exc)

    thread = threading.Thread(target=run, name="mcjax-league-timing", daemon=True)
    thread.start()
    while thread.is_alive():
        thread.join(POLL_S)
        if thread.is_alive() and stop():
            return False
    if failed:
        raise failed[0]
    return True


def _kept(saved: dict, runs: int) -> dict:
    """``{scenario: {filter: cost}}`` of a saved timing pass that can be kept (the same repeats)."""
    if saved.get("repeat_runs") != runs or saved.get("repeats") != REPEATS:
        return {}
    return {k: {f: c for f, c in v.items() if isinstance(c, dict)} for k, v in (saved.get("costs") or {}).items()}


class Warmup:
    """The untimed first repeat of every filter of ``league`` still to time (none in ``saved``, the
    folder's ``timing.json``), taken in turn from one queue by daemon threads: one started here (beside
    the sweeps, which keep one core busy), one more per :meth:`wait` (the sweeps done, every core
    compiles); ``stop()`` looked at between filters. :meth:`ready` hands the timing pass the study each
    warmed."""

    def __init__(self, league: League, saved: dict, should_stop: Callable[[], bool] | None = None) -> None:
        runs, kept = repeat_runs(league), _kept(saved, repeat_runs(league))
        self._todo = [(key, f) for key, entry in league.scenarios.items() for f in entry.filters
                      if f not in kept.get(key, {})] if runs else []
        self._queue = list(self._todo)
        self._league, self._runs, self._stop = league, runs, should_stop or (lambda: False)
        self._done: dict = {}
        self._lock = threading.Lock()
        self._threads: list[threading.Thread] = []
        self._start()

    def _start(self) -> None:
        thread = threading.Thread(target=self._run, name="mcjax-league-warmup", daemon=True)
        self._threads.append(thread)
        thread.start()

    def _run(self) -> None:
        from mcjax.study.execute import chunk_rows

        while not self._stop():
            with self._lock:
                if not self._queue:
                    return
                key, filt = self._queue.pop(0)
            try:
                study, note = timed_study(self._league, key, filt, self._runs)
                if study is not None:
                    for _ in chunk_rows(study):
                        pass
            except Exception:  # noqa: BLE001 - the timing pass warms this filter itself, and meets the error
                continue
            self._done[key, filt] = (study, note)

    def wait(self, should_stop: Callable[[], bool]) -> bool:
        """Wait until every warm-up is done (True), or ``should_stop()`` (False); a second thread
        takes from the queue meanwhile."""
        with self._lock:
            if self._queue:
                self._start()
        for thread in list(self._threads):
            while thread.is_alive():
                thread.join(POLL_S)
                if thread.is_alive() and should_stop():
                    return False
        return True

    def pending(self) -> int:
        """How many filters are still to warm up."""
        alive = any(t.is_alive() for t in self._threads)
        return len([k for k in self._todo if k not in self._done]) if alive else 0

    def ready(self, key: str, filt: str):
        """``(study, note)`` of the filter warmed up here, or None."""
        return self._done.get((key, filt))


def time_filter(league: League, key: str, filt: str, *, runs: int | None = None,
                tick: Callable[[], None] | None = None, should_stop: Callable[[], bool] | None = None,
                warm: tuple | None = None) -> tuple[list[float], str] | None:
    """``([seconds per run of each timed repeat], note)`` of scenario ``key`` running ``filt`` alone
    (module docstring) on ``runs`` runs a repeat (default :func:`repeat_runs`); ``tick()`` after each
    repeat; None when ``should_stop()`` stopped it. ``warm``: ``(study, note)`` whose untimed repeat
    ran already (:class:`Warmup`)."""
    from mcjax.study.execute import chunk_rows

    stop = should_stop or (lambda: False)
    study, note = warm or timed_study(league, key, filt, runs or repeat_runs(league))
    if study is None:
        return [], note
    seconds = []
    for i in range(1 + REPEATS):  # the first compiles and warms up, untimed
        if i == 0 and warm is not None:
            if tick is not None:
                tick()
            continue
        t0 = time.perf_counter()
        if stop() or not run_unless_stopped(lambda: [None for _ in chunk_rows(study)], stop):
            return None
        if i:
            seconds.append((time.perf_counter() - t0) / study.n_runs)
        if tick is not None:
            tick()
    return seconds, note


def summary(seconds: list[float]) -> tuple[float, float, float]:
    """``(median, lowest, highest)`` of the repeats' seconds per run (NaN for none)."""
    if not seconds:
        return float("nan"), float("nan"), float("nan")
    return statistics.median(seconds), min(seconds), max(seconds)


def timing_pass(league: League, saved: dict, *, save: Callable[[dict], None] | None = None,
                message: Callable[[str], None] | None = None,
                progress: Callable[[str, SweepProgress], None] | None = None,
                should_stop: Callable[[], bool] | None = None, warmup: Warmup | None = None) -> tuple[dict, bool]:
    """``(timing, stopped)``: ``saved`` (``timing.json``) completed with every scenario × filter not timed
    yet — ``{"machine", "load", "repeat_runs", "repeats", "costs": {scenario: {filter: {"seconds":
    [per repeat], "note"}}}}``; what was saved with other repeats is timed again. ``save(timing)`` after
    each filter, so a stopped league keeps what it measured; ``progress("timing <scenario>",
    SweepProgress)`` after each repeat (chunks: repeats, runs: their runs); ``should_stop()`` looked at
    while each repeat runs. ``warmup``: the untimed repeats run beside the sweeps, waited for first."""
    say, stop = message or (lambda _: None), should_stop or (lambda: False)
    tell = progress or (lambda *_: None)
    runs = repeat_runs(league)
    if warmup is not None:
        if warmup.pending():
            say(f"timing: waiting for the compilation of {warmup.pending()} filter(s) alone")
        if not warmup.wait(stop):
            return {}, True
    same = saved.get("repeat_runs") == runs and saved.get("repeats") == REPEATS
    timing = {"machine": (same and saved.get("machine")) or machine(),
              "load": saved.get("load") if same and "load" in saved else load_average(),
              "repeat_runs": runs, "repeats": REPEATS, "costs": _kept(saved, runs)}
    steps = stages(league)
    for key, entry in league.scenarios.items():
        done = timing["costs"].setdefault(key, {})
        todo = [f for f in entry.filters if f not in done]
        stage, total = f"timing {key}", steps[f"timing {key}"]
        at = [total - len(todo) * (1 + REPEATS)]

        def tick(stage=stage, total=total, at=at) -> None:
            tell(stage, SweepProgress(at[0], total, at[0] * runs, total * runs))

        if todo:
            tick()
        for filt in todo:
            if stop():
                return timing, True

            def step(tick=tick, at=at) -> None:
                at[0] += 1
                tick()

            got = time_filter(league, key, filt, runs=runs, tick=step, should_stop=stop,
                              warm=None if warmup is None else warmup.ready(key, filt))
            if got is None:
                return timing, True
            seconds, note = got
            done[filt] = {"seconds": seconds, "note": note}
            med, low, high = summary(seconds)
            say(f"timing {key} / {filt}: {note}" if not seconds else
                f"timing {key} / {filt}: {med * 1e3:.3g} ms per run (repeats {low * 1e3:.3g} to "
                f"{high * 1e3:.3g}; {note})")
            if save is not None:
                save(timing)
    return timing, False


def costs(timing: dict, key: str) -> dict[str, tuple[float, float, float, str]]:
    """``{filter: (seconds per run, lowest, highest, note)}`` of scenario ``key`` from a timing pass."""
    out = {}
    for filt, c in ((timing.get("costs") or {}).get(key) or {}).items():
        if isinstance(c, dict):
            out[filt] = (*summary(list(c.get("seconds") or [])), str(c.get("note", "")))
    return out
