"""``mcjax check`` without the CLI: a claims file's sweeps run through the study pipeline into one
output folder, and every claim's verdict written beside them.

The folder holds ``check.json`` (which claims file, as read, and the seeds: what ``--resume``
compares), one sweep folder per sweep the file names (``OUT/<sweep>/``, each what ``mcjax sweep``
writes: its lock, ``sweep.json``, Parquet parts — so resuming, locks, Dask and the program store
work as for a sweep, and claims that share a sweep share its runs) and, once every sweep is whole,
``claims.parquet``: the verdict table (:data:`mcjax.claims.evaluate.COLUMNS`), written atomically.
A check stopped and resumed computes the chunks still missing and gives the same table.

``base_seed`` runs every sweep of the file from that base seed (as a copy of the file with
``base_seed = N`` written into each sweep would); ``replicate = K`` runs the file K times on
disjoint seed ranges — range r with every sweep's base seed plus ``r ×`` :data:`SEEDS_PER_RANGE`,
range 0 the file's own (or ``base_seed``'s) — each a check folder of its own (``OUT/range_<r>/``,
resumed as a check is), and ``OUT/claims.parquet`` is range 0's table with each range's verdicts
and whether they agree (:func:`mcjax.claims.evaluate.replication`). Two ranges share no run: a
run's key is ``fold_in(PRNGKey(base_seed), seed_index)`` (:mod:`mcjax.engine.keys`), and two base
seeds are two Threefry keys. Both are part of the folder's identity: ``--resume`` refuses another
base seed or range count.

Reports through callbacks (``message``, ``warn``, ``progress``, ``should_stop``) and raises the
pipeline's exceptions (:class:`~mcjax.claims.spec.ClaimsError` before anything runs,
:class:`~mcjax.study.store.OutputError`, :class:`~mcjax.study.execute.ChunkError`)::

    from mcjax.claims.runner import run_check
    result = run_check("benchmarks/claims/ren2017.toml", seeds=50, out_dir="results/check_ren2017")
    result.table[["id", "ours", "verdict"]]
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Callable, NamedTuple

import pandas as pd

from mcjax.base import provenance
from mcjax.base.validation import show
from mcjax.analysis.statistics import FAMILY_ERROR
from mcjax.claims.evaluate import needed_columns, replication, verdict_table
from mcjax.claims.folder import CHECK_FILE, TABLE_FILE, write_table
from mcjax.claims.spec import FAMILIES, ClaimsError, ClaimsFile, load_claims
from mcjax.study.execute import Executor
from mcjax.study.runner import NamedSweep, SweepProgress, run_named_sweeps
from mcjax.study.spec import MAX_BASE_SEED
from mcjax.study.store import RESULTS_DIR, OutputError, hold_run_folder

#: How far apart the base seeds of two seed ranges of a replication are (range r: + r x this).
SEEDS_PER_RANGE = 1_000_000
#: What ``--resume`` compares in ``check.json``.
COMPARED = ("claims", "seeds", "base_seed", "shift", "replicate")


class CheckResult(NamedTuple):
    """What :func:`run_check` did: the checked ``claims`` file, its ``out_dir``, the verdict
    ``table`` (None when stopped), whether ``should_stop()`` stopped it, and the table's
    metadata (``meta``: what ``claims.parquet`` holds beside it)."""

    claims: ClaimsFile
    out_dir: Path
    table: pd.DataFrame | None
    stopped: bool
    meta: dict | None = None


def default_out_dir(claims_file: str | Path) -> Path:
    """``results/check_<name>`` (as ``mcjax sweep``'s ``results/<name>``), the name from the claims
    file's stem."""
    name = re.sub(r"[^A-Za-z0-9._-]+", "_", Path(claims_file).stem).strip("._-") or "claims"
    return RESULTS_DIR / f"check_{name}"


def _identity(claims: ClaimsFile, replicate: int | None = None) -> dict:
    return json.loads(json.dumps({"claims": claims.source,
                                  "seeds": {k: s.seeds for k, s in claims.sweeps.items()},
                                  "base_seed": claims.base_seed, "shift": claims.shift or None, "replicate": replicate,
                                  "base_seeds": {k: s.base_seed for k, s in claims.sweeps.items()}}, default=str))


def family_method(claims: ClaimsFile, family: str | None = None) -> str:
    """The method that holds ``claims`` to a family-wise error: ``family`` (``--family``), the
    file's own, else Holm's. :class:`ClaimsError` (one line) for an unknown one, or one the file
    does not allow: a file that names its method fixed it before the runs."""
    if family is not None and family not in FAMILIES:
        raise ClaimsError(f"--family: must be one of {', '.join(FAMILIES)}; got {show(family)}")
    if family is not None and claims.family is not None and family != claims.family:
        raise ClaimsError(f"--family {family}: {claims.path.name} fixes family = {claims.family!r} (chosen before "
                          f"the runs); leave --family out, or change the file")
    return family or claims.family or "holm"


def _refuse_other_seeds(out: Path, ident: dict) -> None:
    """On resume: another --base-seed or --replicate than the folder's, in one line."""
    try:
        saved = json.loads((out / CHECK_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return  # hold_run_folder says what is wrong
    for key, option in (("base_seed", "--base-seed"), ("replicate", "--replicate")):
        if isinstance(saved, dict) and saved.get(key) != ident[key]:
            was = "none" if saved.get(key) is None else saved.get(key)
            raise OutputError(f"{out} holds a check with {option} {was}; --resume needs the same {option} "
                              f"(or start again with --force)")


def _meta(claims: ClaimsFile, table: pd.DataFrame, **more) -> dict:
    return {"paper": claims.paper, "title": claims.title, "claims_file": str(claims.path.resolve()),
            "seeds": {k: s.seeds for k, s in claims.sweeps.items()},
            "base_seeds": {k: s.base_seed for k, s in claims.sweeps.items()}, "base_seed": claims.base_seed,
            "family": {"method": str(table["family"].iloc[0]), "error": FAMILY_ERROR, "claims": len(table),
                       "tests": int(table["family_tests"].iloc[0])}, **more}


def _keep(claims: ClaimsFile) -> list[Path]:
    files = [claims.path.resolve(), *(f for f in claims.spec_files.values() if f is not None)]
    return files


def run_check(claims_file: str | Path | ClaimsFile, *, out_dir: str | Path | None = None, seeds: int | None = None,
              base_seed: int | None = None, replicate: int | None = None, family: str | None = None,
              resume: bool = False, force: bool = False, executor: Executor | None = None,
              message: Callable[[str], None] | None = None, warn: Callable[[str], None] | None = None,
              progress: Callable[[str, SweepProgress], None] | None = None,
              should_stop: Callable[[], bool] | None = None) -> CheckResult:
    """Check ``claims_file`` (module docstring): read and check it whole
    (:func:`mcjax.claims.spec.load_claims`, ``seeds`` runs per point, every sweep from ``base_seed``;
    or a :class:`ClaimsFile` already read that way, ``seeds`` and ``base_seed`` then ignored), make
    ``out_dir`` ready (default ``results/check_<name>``; a fresh check needs it empty or missing,
    ``force`` replaces a previous check, ``resume`` needs the same claims file, seeds, base seed
    and ``replicate``), run every sweep (``progress(sweep, SweepProgress)`` as ``mcjax sweep``
    reports it), then judge every claim — alone and in the file's family (``family``:
    :func:`family_method`) — and write ``claims.parquet``. ``replicate = K``: the whole check on K
    seed ranges (module docstring), ``progress`` told ``range_<r>/<sweep>``."""
    say, stop = message or (lambda _: None), should_stop or (lambda: False)
    claims = (claims_file if isinstance(claims_file, ClaimsFile)
              else load_claims(claims_file, seeds=seeds, base_seed=base_seed))
    method = family_method(claims, family)
    out = Path(default_out_dir(claims.path) if out_dir is None else out_dir)
    if replicate is not None:
        return _replicated(claims, replicate, method, out, resume=resume, force=force, executor=executor, say=say,
                           warn=warn, progress=progress, stop=stop)
    ident = {**_identity(claims), "claims_file": str(claims.path.resolve())}
    if resume:
        _refuse_other_seeds(out, ident)
    with hold_run_folder(out, ident, identity_file=CHECK_FILE, kind="check", compare=COMPARED,
                         other="the check of another claims file", resume=resume, force=force, keep=_keep(claims),
                         warn=warn):
        say(f"{claims.paper}: {len(claims.claims)} claim(s) on {len(claims.sweeps)} sweep(s) "
            f"({', '.join(f'{k}: {s.n_points} point(s) x {s.seeds} seed(s)' for k, s in claims.sweeps.items())})")
        columns = needed_columns(claims)
        ran = run_named_sweeps([NamedSweep(name, out / name, study, claims.spec_files[name], columns[name],
                                           label=f"sweep {name}") for name, study in claims.sweeps.items()],
                               resume=resume, executor=executor, message=say, warn=warn, progress=progress,
                               should_stop=stop)
        if ran is None:
            return CheckResult(claims, out, None, True)
        table = verdict_table(claims, ran, method)
        meta = _meta(claims, table)
        write_table(out / TABLE_FILE, table, {**meta, **provenance.environment_metadata()})
    return CheckResult(claims, out, table, False, meta)


def _replicated(claims: ClaimsFile, replicate, method: str, out: Path, *, resume: bool, force: bool,
                executor: Executor | None, say: Callable, warn: Callable | None, progress: Callable | None,
                stop: Callable[[], bool]) -> CheckResult:
    """The check on ``replicate`` seed ranges, each in ``out/range_<r>/`` (module docstring)."""
    if isinstance(replicate, bool) or not isinstance(replicate, int) or replicate < 2:
        raise ClaimsError(f"--replicate: must be an integer >= 2 (the number of seed ranges); got {show(replicate)}")
    name, top = max(((k, s.base_seed) for k, s in claims.sweeps.items()), key=lambda kv: kv[1])
    if top + (replicate - 1) * SEEDS_PER_RANGE > MAX_BASE_SEED:
        raise ClaimsError(f"--replicate {replicate}: range {replicate - 1} would run sweep {name} from base seed "
                          f"{top + (replicate - 1) * SEEDS_PER_RANGE:,}, past the largest, {MAX_BASE_SEED:,} (ranges "
                          f"are {SEEDS_PER_RANGE:,} base seeds apart); ask fewer ranges or a smaller --base-seed")
    ranges = [claims] + [load_claims(claims.path, seeds=claims.seeds, base_seed=claims.base_seed,
                                     shift=r * SEEDS_PER_RANGE) for r in range(1, replicate)]
    bases = [{k: s.base_seed for k, s in c.sweeps.items()} for c in ranges]
    ident = {**_identity(claims, replicate), "claims_file": str(claims.path.resolve()), "ranges": bases}
    if resume:
        _refuse_other_seeds(out, ident)
    tables = []
    with hold_run_folder(out, ident, identity_file=CHECK_FILE, kind="check", compare=COMPARED,
                         other="the check of another claims file", resume=resume, force=force, keep=_keep(claims),
                         warn=warn):
        for r, c in enumerate(ranges):
            sub = out / f"range_{r}"
            say(f"range {r} of {replicate} (base seed {', '.join(sorted(set(map(str, bases[r].values()))))}):")
            result = run_check(c, out_dir=sub, family=method, resume=resume and (sub / CHECK_FILE).is_file(),
                               executor=executor, message=say, warn=warn, should_stop=stop,
                               progress=(lambda at_sweep, at, r=r: progress(f"range_{r}/{at_sweep}", at))
                               if progress else None)
            if result.stopped:
                return CheckResult(claims, out, None, True)
            tables.append(result.table)
        table = replication(tables)
        meta = _meta(claims, table, replicate=replicate, ranges=bases, seeds_per_range=SEEDS_PER_RANGE)
        write_table(out / TABLE_FILE, table, {**meta, **provenance.environment_metadata()})
    return CheckResult(claims, out, table, False, meta)
