"""A study's output folder: its identity file, the part files on disk, ``--resume`` and
``--force`` (for sweeps, tunes and a tune's held-out evaluation alike, and for the folders of
``mcjax check`` and ``mcjax league`` that hold several sweeps: :func:`hold_run_folder`). Every
file is written atomically (:func:`mcjax.base.files.atomic_write`); the Parquet parts themselves
are written by :func:`mcjax.base.parquet.write_part`. One command writes a folder at a time
(:func:`hold_output`, the lock of :mod:`mcjax.study.lock`). No JAX.
"""

from __future__ import annotations

import contextlib
import json
import re
import shutil
from pathlib import Path
from typing import Callable, Iterator

from mcjax.base import parquet
from mcjax.base.files import atomic_write, read_json_object
from mcjax.base.validation import is_int, one_line
from mcjax.study import lock
from mcjax.study.plan import Study
from mcjax.study.rows import chunk_parts

IDENTITY_FILE = "sweep.json"
#: The keys of sweep.json that make two sweeps the same for ``--resume``.
IDENTITY_KEYS = ("spec", "seeds", "base_seed", "chunk_size", "n_runs")
#: Where ``mcjax sweep`` writes when no ``--out`` is given: ``results/<spec name>``.
RESULTS_DIR = Path("results")


class OutputError(ValueError):
    """The output folder cannot be used as asked (not empty, nothing to resume, another sweep)."""


@contextlib.contextmanager
def hold_output(out_dir: str | Path, warn: Callable[[str], None] | None = None) -> Iterator[None]:
    """Hold ``out_dir``'s lock (:func:`mcjax.study.lock.hold`: one writer per output folder) for
    the ``with`` block; :class:`OutputError` in one line naming the holder when another command
    holds it. ``warn`` is told when a lock left by a process that is gone is taken over."""
    try:
        with lock.hold(out_dir, warn):
            yield
    except lock.LockError as exc:
        raise OutputError(str(exc)) from None


def _contents(folder: Path) -> list[Path]:
    """What a folder holds, but for its lock."""
    return [p for p in folder.iterdir() if p.name != lock.LOCK_FILE]


def default_out_dir(spec_path: str | Path) -> Path:
    """``results/<name>``, the name being the spec file's stem with anything but letters,
    digits, ``.``, ``_`` and ``-`` replaced and no leading dots (``...toml`` gives
    ``results/sweep``): always a folder inside ``results/``, never ``results/`` itself."""
    name = re.sub(r"[^A-Za-z0-9._-]+", "_", Path(spec_path).stem).lstrip("._-")
    return RESULTS_DIR / (name if name.strip(".") else "sweep")


def identity(study: Study) -> dict:
    """What makes two sweeps the same for ``--resume``: spec, seeds, base seed, chunking."""
    return json.loads(json.dumps({"spec": study.source, "seeds": study.seeds, "base_seed": study.base_seed,
                                  "chunk_size": study.chunk_runs, "n_runs": study.n_runs}, default=str))


def read_identity(out_dir: str | Path) -> dict:
    """The ``sweep.json`` of an output folder; OutputError in one line, saying what to do,
    when it is missing or damaged."""
    state = Path(out_dir) / IDENTITY_FILE
    if not state.is_file():
        raise OutputError(f"nothing to resume in {out_dir}: no {IDENTITY_FILE} (start the sweep without --resume)")
    try:
        saved = json.loads(state.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise OutputError(f"{state} is damaged ({one_line(exc)}); it records which sweep the folder holds, so the "
                          f"folder cannot be resumed: start again with --force") from None
    ok = isinstance(saved, dict) and all(k in saved for k in IDENTITY_KEYS)
    ok = ok and isinstance(saved["spec"], dict) and all(is_int(saved[k]) for k in IDENTITY_KEYS[1:])
    ok = ok and isinstance(saved.get("set", {}), dict)
    if not ok:
        raise OutputError(f"{state} is damaged (it lacks {', '.join(IDENTITY_KEYS)}); the folder cannot be resumed: "
                          f"start again with --force")
    return saved


def _inside(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def check_replaceable(out_dir: Path, keep: list[Path], identity_file: str = IDENTITY_FILE,
                      kind: str = "sweep") -> None:
    """``--force`` replaces only a folder that is empty or holds a previous ``kind`` of run
    (its ``identity_file``, ``sweep.json`` for a sweep) and never one that is or holds the
    current folder, a file of ``keep`` (the spec, its base), your home folder or ``results/``
    itself."""
    if out_dir.is_symlink():
        raise OutputError(f"--force: {out_dir} is a symbolic link; give the folder itself as --out")
    out = out_dir.resolve()
    guarded = [Path.cwd().resolve(), RESULTS_DIR.resolve(), Path.home().resolve()]
    guarded += [Path(p).resolve() for p in keep]
    for g in guarded:
        if _inside(g, out):
            what = ("the current folder" if g == guarded[0] else "results/ itself" if g == guarded[1]
                    else "your home folder" if g == guarded[2] else str(g))
            raise OutputError(f"--force: {out_dir} is or holds {what}; it replaces only a {kind}'s own output folder "
                              f"(choose another --out)")
    if _contents(out) and not (out / identity_file).is_file():
        raise OutputError(f"--force: {out_dir} is not empty and holds no {identity_file}, so it is no {kind}'s output "
                          f"folder; --force replaces only those (choose another --out)")


def write_identity(out_dir: Path, identity_file: str, saved: dict) -> None:
    """The identity file of an output folder (``sweep.json``, ``tune.json``), atomically."""
    atomic_write(Path(out_dir) / identity_file, json.dumps(saved, indent=1))


def _wrote_nothing(folder: Path, identity_file: str) -> bool:
    """The folder holds a run's identity file and nothing written after it: no file but empty
    folders (a sweep, check or tune that failed before its first part, e.g. a bug in a user's
    scenario)."""
    items = _contents(folder)
    if not any(p.name == identity_file and p.is_file() for p in items):
        return False
    return all(p.name == identity_file or (p.is_dir() and not p.is_symlink() and not any(
        q.is_file() or q.is_symlink() for q in p.rglob("*"))) for p in items)


def start_fresh(out_dir: str | Path, *, force: bool, keep: list[Path] = (), identity_file: str = IDENTITY_FILE,
                kind: str = "sweep", note: Callable[[str], None] | None = None) -> Path:
    """Make ``out_dir`` an empty folder for a new ``kind`` of run: a missing or empty folder,
    one that holds only the identity file of a run that wrote nothing (reused; ``note`` is told),
    or — with ``force`` — one holding a previous run of that kind (:func:`check_replaceable`),
    which is deleted. :class:`OutputError` in one line otherwise."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise OutputError(f"output folder {out_dir} is a file; choose another --out")
    if out_dir.exists() and _contents(out_dir) and not force and _wrote_nothing(out_dir, identity_file):
        for item in _contents(out_dir):  # a run that failed before its first part: nothing to lose
            shutil.rmtree(item) if item.is_dir() and not item.is_symlink() else item.unlink()
        (note or (lambda _: None))(f"{out_dir} held only the identity file of a {kind} that wrote nothing; "
                                   f"reusing it")
    if out_dir.exists() and _contents(out_dir):
        if not force:
            raise OutputError(f"output folder {out_dir} is not empty; pass --resume to finish it, --force to "
                              f"replace it, or choose another --out")
        check_replaceable(out_dir, list(keep), identity_file, kind)
        for item in _contents(out_dir):  # the lock stays: this command holds it
            shutil.rmtree(item) if item.is_dir() and not item.is_symlink() else item.unlink()
    out_dir.mkdir(parents=True, exist_ok=True)
    return out_dir


@contextlib.contextmanager
def hold_run_folder(out_dir: Path, ident: dict, *, identity_file: str, kind: str, compare: tuple, other: str,
                    resume: bool = False, force: bool = False, keep: list[Path] = (),
                    warn: Callable[[str], None] | None = None) -> Iterator[None]:
    """Hold ``out_dir``'s lock (:func:`hold_output`) for the ``with`` block of a run that holds
    several sweeps (a ``kind`` of run: ``mcjax check``, ``mcjax league``), the folder made ready
    first: ``resume`` needs its ``identity_file`` readable and the same values of ``ident`` under
    ``compare`` (else :class:`OutputError`: the folder holds ``other`` — "another league file" —
    or seed count); a fresh run needs it empty or missing (a folder that holds this very run is told so,
    with ``--resume`` to finish it, or to print it again when it is complete: when its table, the
    one Parquet file at its top, ``claims.parquet`` or ``league.parquet``, is written), ``force``
    replaces a previous run of that kind (:func:`start_fresh`, ``keep``: files it must not hold), and writes ``ident`` as its
    identity file. ``--resume`` with ``--force``: :class:`OutputError`, before the lock is taken."""
    if resume and force:
        raise OutputError("--resume and --force exclude each other")
    with hold_output(out_dir, warn):
        if resume:
            try:
                saved = json.loads((out_dir / identity_file).read_text(encoding="utf-8"))
            except (OSError, ValueError):
                raise OutputError(f"nothing to resume in {out_dir}: no readable {identity_file} (start the {kind} "
                                  f"without --resume)") from None
            if {k: saved.get(k) for k in compare} != {k: ident[k] for k in compare}:
                raise OutputError(f"{out_dir} holds {other} or seed count; --resume needs the same file and --seeds "
                                  f"(or start again with --force)")
        else:
            if not force and out_dir.is_dir() and _contents(out_dir) and not _wrote_nothing(out_dir, identity_file):
                saved = read_json_object(out_dir / identity_file)
                if {k: saved.get(k) for k in compare} == {k: ident[k] for k in compare}:
                    tables = sorted(p.name for p in out_dir.glob("*.parquet"))  # written once every sweep is whole
                    state = (f"to print its table again (it is complete: {tables[0]} is written)" if tables else
                             "to finish it (it is not complete: its table is not written yet)")
                    raise OutputError(f"{out_dir} already holds this {kind} (the same file and --seeds): pass --resume "
                                      f"{state}; --force to run it again, or choose another --out")
            try:
                start_fresh(out_dir, force=force, keep=keep, identity_file=identity_file, kind=kind)
            except OSError as exc:
                raise OutputError(f"output folder {out_dir}: {exc.strerror or exc}") from None
            write_identity(out_dir, identity_file, ident)
        yield


def _spec_file(spec_file) -> str | None:
    return None if spec_file is None else str(Path(spec_file).resolve())


def prepare_output(study: Study, out_dir: str | Path, *, resume: bool = False, force: bool = False,
                   keep: list[Path] = (), spec_file: str | Path | None = None,
                   note: Callable[[str], None] | None = None,
                   hold: contextlib.ExitStack | None = None) -> list[int] | None:
    """Make ``out_dir`` ready for ``study``; return the chunks still to run (None: all).

    A fresh sweep needs an empty or missing folder (``force`` replaces one that holds a
    previous sweep, see :func:`check_replaceable`; ``keep``: files it must not hold) and
    writes the identity file (with ``spec_file`` and the ``--set`` values, for resuming).
    ``resume`` needs the same identity, removes half-written staging files and returns the
    chunks whose parts are missing or damaged (:func:`check_parts`; ``note`` is told about
    each problem, and about a folder reused because it held only a run that wrote nothing). With ``hold``, first takes the folder's lock (:func:`hold_output`) and
    keeps it until ``hold`` closes. Raises :class:`OutputError` otherwise."""
    out_dir = Path(out_dir)
    ident = identity(study)
    if resume and force:
        raise OutputError("--resume and --force exclude each other")
    try:
        if hold is not None:
            hold.enter_context(hold_output(out_dir))
        if resume:
            saved = read_identity(out_dir)
            if {k: saved[k] for k in IDENTITY_KEYS} != ident:
                diff = sorted(k for k in IDENTITY_KEYS if saved.get(k) != ident.get(k))
                raise OutputError(f"{out_dir} holds a different sweep ({', '.join(diff)} differ); --resume needs the "
                                  f"same spec, seeds, chunk size and --set values (leave them out to take the saved "
                                  f"ones)")
            parquet.clean_staging(out_dir)
            todo, problems = check_parts(study, out_dir)
            for line in problems:
                (note or (lambda _: None))(f"resume: {line}")
            return todo
        if not force:
            _refuse_a_sweep_in(study, out_dir, ident)
        start_fresh(out_dir, force=force, keep=keep, note=note)
        write_identity(out_dir, IDENTITY_FILE, {**ident, "set": study.overrides, "spec_file": _spec_file(spec_file)})
    except OSError as exc:
        raise OutputError(f"output folder {out_dir}: {exc.strerror or exc}") from None
    return None


def _refuse_a_sweep_in(study: Study, out_dir: Path, ident: dict) -> None:
    """A fresh sweep into a folder that holds a sweep (a readable ``sweep.json`` and parts) is refused with what
    the folder holds and what to do: this sweep complete (report it, or run it again with --force), this sweep
    unfinished (--resume), or another sweep (--force). Any other folder is :func:`start_fresh`'s to judge."""
    if not (out_dir / IDENTITY_FILE).is_file() or _wrote_nothing(out_dir, IDENTITY_FILE):
        return
    try:
        saved = read_identity(out_dir)
    except OutputError:
        return
    if not parquet.existing_parts(out_dir, "runs"):
        return
    if {k: saved[k] for k in IDENTITY_KEYS} != ident:
        differ = ", ".join(sorted(k for k in IDENTITY_KEYS if saved.get(k) != ident.get(k)))
        raise OutputError(f"output folder {out_dir} is not empty: it holds another sweep ({differ} differ); pass "
                          f"--force to replace it, or choose another --out")
    missing, chunks = len(missing_chunks(study, out_dir)), len(study.plan)
    if missing:
        raise OutputError(f"output folder {out_dir} is not empty: it holds this sweep, {chunks - missing} of {chunks} "
                          f"chunk(s) written; pass --resume to finish it, --force to start again, or choose another "
                          f"--out")
    raise OutputError(f"output folder {out_dir} already holds this sweep, complete ({chunks} of {chunks} chunk(s) "
                      f"written): `mcjax report {out_dir}` reads it; pass --force to run it again, or choose another "
                      f"--out")


def check_parts(study: Study, out_dir: str | Path) -> tuple[list[int], list[str]]:
    """Chunks to run (again) and one line per problem found: a chunk whose part (of ``runs/``,
    or ``timeseries/`` when the spec asks for it) is missing, or damaged — unreadable, or
    not holding exactly the rows and runs it should. Damaged parts and parts that belong to
    no chunk of the plan are removed (a re-run chunk rewrites its parts under the same names)."""
    out_dir = Path(out_dir)
    tables = ["runs"] + (["timeseries"] if study.timeseries else [])
    rows_per_run = {"runs": len(study.config.filters), "timeseries": len(study.config.filters) * study.config.n_steps}
    have = {t: set(parquet.existing_parts(out_dir, t)) for t in tables}
    todo, problems, planned = [], [], {t: set() for t in tables}
    for i, (a, b) in enumerate(study.plan):
        bad = []
        for t in tables:
            for part in chunk_parts(study, i, a, b):
                planned[t].add(part)
                point = int(part.split("/")[0].split("=")[1])
                lo, hi = max(a, point * study.seeds) - point * study.seeds, min(b, (point + 1) * study.seeds) - point * study.seeds
                if part not in have[t]:
                    bad.append(f"{t}/{part}.parquet is missing")
                    continue
                why = parquet.part_problem(out_dir, t, part, range(lo, hi), rows_per_run[t])
                if why:
                    bad.append(f"{t}/{part}.parquet is damaged ({why})")
                    parquet.remove_part(out_dir, t, part)
        if bad:
            todo.append(i)
            problems += [f"chunk {i}: {line}; re-running it" for line in bad]
    for t in tables:
        for part in sorted(have[t] - planned[t]):
            problems.append(f"{t}/{part}.parquet belongs to no chunk of this sweep; removed")
            parquet.remove_part(out_dir, t, part)
    return todo, problems


def missing_chunks(study: Study, out_dir: str | Path) -> list[int]:
    """Chunks not completely on disk: some part (of ``runs/``, or ``timeseries/`` when the spec
    asks for it) is missing. Re-running one rewrites its parts under the same names."""
    tables = ["runs"] + (["timeseries"] if study.timeseries else [])
    have = {t: set(parquet.existing_parts(out_dir, t)) for t in tables}
    return [i for i, (a, b) in enumerate(study.plan)
            if not all(set(chunk_parts(study, i, a, b)) <= have[t] for t in tables)]


# ------------------------------------------------------------------ a tune's folder

#: The identity file of a tune's output folder.
TUNE_IDENTITY_FILE = "tune.json"


def prepare_tune_output(ident: dict, out_dir: str | Path, *, resume: bool = False, force: bool = False,
                        spec_file: str | Path | None = None, keep: list = ()) -> None:
    """Make ``out_dir`` ready for a tune whose identity (its spec as written) is ``ident``: a
    fresh tune needs a missing or empty folder (``force`` replaces one holding a previous tune,
    ``tune.json``; one holding this very tune is told so, with ``--resume``); ``resume`` needs the same spec in ``tune.json`` and removes half-written
    temporary files. Writes ``tune.json``. :class:`OutputError` otherwise, before anything is
    written."""
    out_dir = Path(out_dir)
    state = out_dir / TUNE_IDENTITY_FILE
    if resume and force:
        raise OutputError("--resume and --force exclude each other")
    try:
        if resume:
            if not state.is_file():
                raise OutputError(f"nothing to resume in {out_dir}: no {TUNE_IDENTITY_FILE} (start the tune without "
                                  f"--resume)")
            try:
                saved = json.loads(state.read_text(encoding="utf-8"))
            except (UnicodeDecodeError, ValueError) as exc:
                raise OutputError(f"{state} is damaged ({exc}); start again with --force") from None
            if not isinstance(saved, dict) or saved.get("spec") != ident["spec"]:
                raise OutputError(f"{out_dir} holds a different tune (its spec differs); --resume needs the same spec")
            for tmp in out_dir.glob(".*.tmp"):
                tmp.unlink()
            return
        if not force and state.is_file() and not _wrote_nothing(out_dir, TUNE_IDENTITY_FILE):
            if read_json_object(state).get("spec") == ident["spec"]:
                raise OutputError(f"{out_dir} already holds this tune (the same spec): pass --resume to finish it, or "
                                  f"to print its result again if it is complete; --force to run it again, or choose "
                                  f"another --out")
        start_fresh(out_dir, force=force, keep=keep, identity_file=TUNE_IDENTITY_FILE, kind="tune")
        write_identity(out_dir, TUNE_IDENTITY_FILE, {**ident, "spec_file": _spec_file(spec_file)})
    except OSError as exc:
        raise OutputError(f"output folder {out_dir}: {exc.strerror or exc}") from None


def prepare_evaluation(ev: Study, out_dir: str | Path, *, spec_file: str | Path | None = None):
    """Ready ``out_dir`` for a tune's held-out evaluation sweep ``ev``: write its ``sweep.json``
    (as ``mcjax sweep`` does, so ``mcjax report`` reads the folder), or, when one for the same
    evaluation is there, return the chunks still missing (a resumed evaluation). None: all."""
    out_dir = Path(out_dir)
    ident = identity(ev)
    path = out_dir / IDENTITY_FILE
    if path.is_file():
        try:
            saved = json.loads(path.read_text(encoding="utf-8"))
        except (UnicodeDecodeError, ValueError):
            saved = None
        if isinstance(saved, dict) and {k: saved.get(k) for k in ident} == ident:
            parquet.clean_staging(out_dir)
            return check_parts(ev, out_dir)[0]
    for folder in ("runs", parquet.STAGING_DIR):
        if (out_dir / folder).exists():
            shutil.rmtree(out_dir / folder)
    write_identity(out_dir, IDENTITY_FILE, {**ident, "set": {}, "spec_file": _spec_file(spec_file), "tune": True})
    return None
