"""``mcjax check`` without the CLI: a claims file's sweeps run through the study pipeline into one
output folder, and every claim's verdict written beside them.

The folder holds ``check.json`` (which claims file, as read, and the seeds: what ``--resume``
compares), one sweep folder per sweep the file names (``OUT/<sweep>/``, each what ``mcjax sweep``
writes: its lock, ``sweep.json``, Parquet parts — so resuming, locks, Dask and the program store
work as for a sweep, and claims that share a sweep share its runs) and, once every sweep is whole,
``claims.parquet``: the verdict table (:data:`mcjax.claims.evaluate.COLUMNS`), written atomically.
A check stopped and resumed computes the chunks still missing and gives the same table.

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
from mcjax.claims.evaluate import needed_columns, verdict_table
from mcjax.claims.folder import CHECK_FILE, TABLE_FILE, write_table
from mcjax.claims.spec import ClaimsFile, load_claims
from mcjax.study.execute import Executor
from mcjax.study.runner import SweepProgress, run_sweep_folder
from mcjax.study.store import IDENTITY_FILE, RESULTS_DIR, hold_run_folder



class CheckResult(NamedTuple):
    """What :func:`run_check` did: the checked ``claims`` file, its ``out_dir``, the verdict
    ``table`` (None when stopped) and whether ``should_stop()`` stopped it."""

    claims: ClaimsFile
    out_dir: Path
    table: pd.DataFrame | None
    stopped: bool


def default_out_dir(claims_file: str | Path) -> Path:
    """``results/check_<name>`` (as ``mcjax sweep``'s ``results/<name>``), the name from the claims
    file's stem."""
    name = re.sub(r"[^A-Za-z0-9._-]+", "_", Path(claims_file).stem).strip("._-") or "claims"
    return RESULTS_DIR / f"check_{name}"


def _identity(claims: ClaimsFile) -> dict:
    return json.loads(json.dumps({"claims": claims.source,
                                  "seeds": {k: s.seeds for k, s in claims.sweeps.items()}}, default=str))


def _keep(claims: ClaimsFile) -> list[Path]:
    files = [claims.path.resolve(), *(f for f in claims.spec_files.values() if f is not None)]
    return files


def run_check(claims_file: str | Path | ClaimsFile, *, out_dir: str | Path | None = None, seeds: int | None = None,
              resume: bool = False, force: bool = False, executor: Executor | None = None,
              message: Callable[[str], None] | None = None, warn: Callable[[str], None] | None = None,
              progress: Callable[[str, SweepProgress], None] | None = None,
              should_stop: Callable[[], bool] | None = None) -> CheckResult:
    """Check ``claims_file`` (module docstring): read and check it whole
    (:func:`mcjax.claims.spec.load_claims`, ``seeds`` runs per point; or a :class:`ClaimsFile` already
    read that way, ``seeds`` then ignored), make ``out_dir`` ready
    (default ``results/check_<name>``; a fresh check needs it empty or missing, ``force``
    replaces a previous check, ``resume`` needs the same claims file and seeds), run every sweep
    (``progress(sweep, SweepProgress)`` as ``mcjax sweep`` reports it), then judge every claim and
    write ``claims.parquet``."""
    say, stop = message or (lambda _: None), should_stop or (lambda: False)
    claims = claims_file if isinstance(claims_file, ClaimsFile) else load_claims(claims_file, seeds=seeds)
    out = Path(default_out_dir(claims.path) if out_dir is None else out_dir)
    ident = {**_identity(claims), "claims_file": str(claims.path.resolve())}
    rows: dict[str, pd.DataFrame] = {}
    with hold_run_folder(out, ident, identity_file=CHECK_FILE, kind="check", compare=("claims", "seeds"),
                         other="the check of another claims file", resume=resume, force=force, keep=_keep(claims),
                         warn=warn):
        say(f"{claims.paper}: {len(claims.claims)} claim(s) on {len(claims.sweeps)} sweep(s) "
            f"({', '.join(f'{k}: {s.n_points} point(s) x {s.seeds} seed(s)' for k, s in claims.sweeps.items())})")
        columns = needed_columns(claims)
        for name, study in claims.sweeps.items():
            folder = out / name
            again = resume and (folder / IDENTITY_FILE).is_file()
            say(f"sweep {name}:")
            result = run_sweep_folder(study, spec_file=claims.spec_files[name], out_dir=folder, resume=again,
                                      executor=executor, columns=columns[name], message=say, warn=warn,
                                      progress=(lambda at, name=name: progress(name, at)) if progress else None,
                                      should_stop=stop)
            if result.stopped:
                return CheckResult(claims, out, None, True)
            if result.runs_run:
                say(f"sweep {name}: {result.runs_run} runs in {result.seconds:.1f} s (compilation included)")
            rows[name] = result.rows
        table = verdict_table(claims, rows)
        write_table(out / TABLE_FILE, table, {"paper": claims.paper, "title": claims.title,
                                              "claims_file": str(claims.path.resolve()),
                                              "seeds": ident["seeds"], **provenance.environment_metadata()})
    return CheckResult(claims, out, table, False)
