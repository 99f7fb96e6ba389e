"""A tune's optimisation with its atomic per-step state (:func:`optimise`, resumable), the
trace's figure, and the held-out evaluation of the initial and final Params as a two-point
sweep (:func:`evaluation_spec`) whose rows say their ``role``, initial or tuned
(:class:`RoleExecutor`, :func:`summary_text`)."""

from __future__ import annotations

import contextlib
import json
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from mcjax.base.files import atomic_write
from mcjax.study import ChunkError, LocalExecutor, Study, build_spec, run_sweep, store
from mcjax.tune.loss import Evaluator
from mcjax.tune.spec import TuneSpec, from_unconstrained, to_unconstrained

# ------------------------------------------------------------------ optimisation with resume

STATE_FILE = "tune_state.npz"
TRACE_FILE = "trace.parquet"


def make_optimizer(spec: TuneSpec):
    """The spec's optax optimiser, ``optax.OPTIMIZER(learning_rate)``."""
    import optax

    return getattr(optax, spec.optimizer)(spec.learning_rate)


def trace_columns(spec: TuneSpec) -> list[str]:
    """The columns of the trace, one row per optimisation step."""
    return ["step", "loss", "soft_rmse", "soft_divergence", *spec.names, *[f"z_{n}" for n in spec.names],
            "grad_norm", *[f"grad_{n}" for n in spec.names], "dropped_runs", "wall_s"]


def save_state(out_dir: Path, step: int, z, opt_state, trace: pd.DataFrame) -> None:
    """The optimiser's state after ``step`` completed steps, atomically (temporary file, then
    rename): ``z``, every leaf of the optax state, and the trace so far (also as Parquet)."""
    import jax

    leaves = [np.asarray(a) for a in jax.tree.leaves(opt_state)]
    arrays = {"step": np.asarray(step), "z": np.asarray(z, np.float64),
              **{f"leaf_{i}": a for i, a in enumerate(leaves)}}

    def npz(tmp):
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)

    atomic_write(out_dir / TRACE_FILE, lambda tmp: trace.to_parquet(tmp, index=False))
    atomic_write(out_dir / STATE_FILE, npz)


def load_state(out_dir: Path, spec: TuneSpec):
    """``(step, z, opt_state, trace)`` saved by :func:`save_state`, or None if there is none."""
    import jax

    path = out_dir / STATE_FILE
    if not path.is_file():
        return None
    opt = make_optimizer(spec)
    z0 = to_unconstrained(spec.bounds, spec.initial())
    template = opt.init(jax.numpy.asarray(z0))
    with np.load(path) as data:
        step = int(data["step"])
        z = np.array(data["z"])
        leaves = [jax.numpy.asarray(data[f"leaf_{i}"]) for i in range(len(jax.tree.leaves(template)))]
    trace = pd.read_parquet(out_dir / TRACE_FILE) if (out_dir / TRACE_FILE).is_file() else pd.DataFrame()
    trace = trace[trace["step"] < step] if len(trace) else trace
    return step, z, jax.tree.unflatten(jax.tree.structure(template), leaves), trace


def optimise(spec: TuneSpec, out_dir: Path, *, evaluator: Evaluator | None = None,
             progress: Callable[[dict], None] | None = None,
             should_stop: Callable[[], bool] | None = None) -> pd.DataFrame:
    """Run the optimisation from the saved state in ``out_dir`` (or from the initial Params),
    saving the state after every completed step; return the trace. Row ``k`` of the trace is
    the loss and gradient at the Params *before* update ``k`` (row 0: the initial Params); a
    last row ``step = steps`` holds the final Params (their loss evaluated too).
    ``should_stop()`` is asked after each step."""
    import jax

    opt = make_optimizer(spec)
    saved = load_state(out_dir, spec)
    if saved is None:
        z = to_unconstrained(spec.bounds, spec.initial())
        opt_state = opt.init(jax.numpy.asarray(z))
        step, rows = 0, []
    else:
        step, z, opt_state, trace = saved
        rows = trace.to_dict("records")
    evaluator = evaluator or Evaluator(spec)
    update = jax.jit(lambda g, s, z: _apply(opt, g, s, z))
    while step <= spec.steps:
        t0 = time.perf_counter()
        ev = evaluator(z)
        x = np.asarray(from_unconstrained(spec.bounds, jax.numpy.asarray(z)))
        row = {"step": step, "loss": ev.loss, "soft_rmse": ev.soft_rmse, "soft_divergence": ev.soft_divergence,
               **{n: float(v) for n, v in zip(spec.names, x)}, **{f"z_{n}": float(v) for n, v in zip(spec.names, z)},
               "grad_norm": float(np.linalg.norm(ev.grad)),
               **{f"grad_{n}": float(g) for n, g in zip(spec.names, ev.grad)},
               "dropped_runs": ev.dropped}
        if step < spec.steps:
            g = np.where(np.isfinite(ev.grad), ev.grad, 0.0)
            z_new, opt_state = update(jax.numpy.asarray(g), opt_state, jax.numpy.asarray(z))
            z = np.asarray(z_new)
        row["wall_s"] = time.perf_counter() - t0
        rows.append(row)
        step += 1
        trace = pd.DataFrame(rows, columns=trace_columns(spec))
        save_state(out_dir, step, z, opt_state, trace)
        if progress is not None:
            progress(row)
        if should_stop is not None and should_stop() and step <= spec.steps:
            break
    return pd.DataFrame(rows, columns=trace_columns(spec))


def _apply(opt, g, state, z):
    import optax

    updates, state = opt.update(g, state, z)
    return optax.apply_updates(z, updates), state


def finished(spec: TuneSpec, trace: pd.DataFrame) -> bool:
    """Whether the trace holds the last step (the final Params' loss)."""
    return len(trace) > 0 and int(trace["step"].max()) >= spec.steps


# ------------------------------------------------------------------ evaluation and figure


def final_values(spec: TuneSpec, trace: pd.DataFrame) -> np.ndarray:
    """The tuned Params' values after the last step."""
    row = trace[trace["step"] == spec.steps].iloc[0]
    return np.array([row[n] for n in spec.names])


def evaluation_spec(spec: TuneSpec, final) -> Study:
    """The held-out evaluation as a sweep: the tuned Params zipped over two points (point 0 =
    the initial values, point 1 = the final ones) on ``heldout_seeds`` seeds of
    ``heldout_base_seed``, exact simulation. Params whose value did not change are left at it
    (not an axis); if none changed, one point."""
    data = {k: v for k, v in spec.source.items() if k != "tune"}
    data["params"] = dict(data.get("params", {}))
    zipped = {}
    for b, v in zip(spec.bounds, np.asarray(final, np.float64)):
        data["params"].pop(b.name, None)
        if float(v) != b.initial:
            zipped[b.name] = [b.initial, float(v)]
        else:
            data["params"][b.name] = b.initial
    if zipped:
        data["zip"] = zipped
    data["seeds"] = spec.heldout_seeds
    data["base_seed"] = spec.heldout_base_seed
    data["description"] = (data.get("description", "") + " — held-out evaluation of mcjax tune: point 0 = "
                           "initial, point 1 = tuned Params").strip(" —")
    return build_spec(data, Path(spec.base_dir))


#: The evaluation dataset's column saying which Params a row ran: point 0 the initial values,
#: point 1 the tuned ones (a one-point evaluation, where no Param moved, is all "initial").
ROLE_COLUMN, ROLES = "role", ("initial", "tuned")


def with_role(rows: pd.DataFrame) -> pd.DataFrame:
    """``rows`` of the held-out evaluation with the column ``role`` ("initial" for point 0,
    "tuned" for point 1) just before ``filter``."""
    out = rows.copy()
    where = out.columns.get_loc("filter") if "filter" in out.columns else len(out.columns)
    out.insert(where, ROLE_COLUMN, np.where(out["point_id"].to_numpy() == 0, *ROLES))
    return out


class RoleExecutor:
    """The held-out evaluation's executor: ``inner`` (default: this process,
    :class:`mcjax.study.LocalExecutor`) computes the chunks; every row leaves with its ``role``
    (:func:`with_role`), so the dataset says which row is initial and which tuned."""

    def __init__(self, inner=None):
        self.inner = inner if inner is not None else LocalExecutor()

    def map_chunks(self, study: Study, chunks: list[int], should_stop: Callable[[], bool]):
        for rows in self.inner.map_chunks(study, chunks, should_stop):
            series = rows.timeseries
            yield rows._replace(runs=with_role(rows.runs), timeseries=None if series is None else with_role(series))


def run_evaluation(ev: Study, out_dir: Path, **options) -> None:
    """Run the held-out evaluation into ``out_dir`` (:func:`mcjax.study.run_sweep` with
    ``options``: ``chunks``, ``progress``, ``should_stop``), each row with its ``role``
    (:class:`RoleExecutor`); no rows kept in memory."""
    run_sweep(ev, out_dir, executor=RoleExecutor(), keep=False, **options)


def summary_text(runs: pd.DataFrame, ev: Study) -> str:
    """The held-out evaluation's summary as ``mcjax report`` prints a sweep's (legend, then one
    row per role and filter), the initial row first and a column ``role`` saying which is which."""
    from mcjax.analysis import tables

    runs = runs if ROLE_COLUMN in runs.columns else with_role(runs)  # an evaluation written before the column
    metadata = {**ev.scenario.metadata(ev.config), "spec": ev.source}
    axes = tables.swept_axes(metadata, runs.columns)
    summary = tables.summarize(runs, metadata, [ROLE_COLUMN, *axes])  # "initial" sorts before "tuned"
    legend = tables.legend_lines(metadata, axes)
    legend.insert(len(legend) - 1, f"{ROLE_COLUMN}: initial = the Params the tune started from (point 0), tuned = "
                                   f"where it ended (point 1)")
    return tables.format_table(summary, "text", legend)


def paired_differences(runs: pd.DataFrame, columns: list[str]) -> pd.DataFrame:
    """The held-out comparison, paired: per filter and column, the mean over seeds of tuned
    (point 1) − initial (point 0) with its 95 % Student-t interval (a flag's difference is
    one of rates). Empty if the evaluation has one point (nothing changed)."""
    from mcjax.analysis.statistics import paired_by_seed

    if runs["point_id"].nunique() < 2:
        return pd.DataFrame([])
    return pd.DataFrame(paired_by_seed(runs, columns, 0, 1, list(dict.fromkeys(runs["filter"]))))


def plot_trace(spec: TuneSpec, trace: pd.DataFrame, path: Path) -> Path:
    """The optimisation trace as a PNG: the loss (and its two parts) per step, and each tuned
    Param per step (log axis for a log-scaled one)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(spec.bounds)
    fig, axes = plt.subplots(1, n + 1, figsize=(4.2 * (n + 1), 3.4))
    ax = axes[0]
    ax.plot(trace["step"], trace["loss"], "o-", label="loss")
    ax.plot(trace["step"], trace["soft_rmse"] / spec.loss.error_scale, ".--", label="soft RMSE / c")
    ax.plot(trace["step"], spec.loss.divergence_weight * trace["soft_divergence"], ".:", label="w x soft divergence")
    ax.set_xlabel("optimisation step")
    ax.set_title(f"training loss ({spec.train_seeds} runs)")
    ax.legend(fontsize=7)
    for ax, b in zip(axes[1:], spec.bounds):
        ax.plot(trace["step"], trace[b.name], "o-")
        ax.axhline(b.low, color="grey", lw=0.5)
        ax.axhline(b.high, color="grey", lw=0.5)
        if b.scale == "log":
            ax.set_yscale("log")
        ax.set_xlabel("optimisation step")
        ax.set_title(b.name)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# ------------------------------------------------------------------ output folder


def identity(spec: TuneSpec) -> dict:
    """What makes two tunes the same for ``--resume``: the spec as written."""
    return json.loads(json.dumps({"spec": spec.source}, default=str))


def prepare_tune_output(spec: TuneSpec, out_dir: str | Path, *, resume: bool = False, force: bool = False,
                        spec_file: str | Path | None = None, keep: list = ()) -> None:
    """Make ``out_dir`` ready for the tune ``spec`` (:func:`mcjax.study.store.prepare_tune_output`,
    with the tune's :func:`identity`)."""
    store.prepare_tune_output(identity(spec), out_dir, resume=resume, force=force, spec_file=spec_file, keep=keep)


@contextlib.contextmanager
def write_failures_end_the_command(out_dir: Path):
    """A tune that cannot write (a full disk, a lost mount: any OSError while saving its trace or
    state, or a part of its held-out evaluation) ends with one line on stderr and exit code 1:
    what failed and how to finish. Nothing partial is left visible (every file is written
    atomically), so ``--resume`` completes the tune once there is room."""
    try:
        yield
    except ChunkError as exc:  # a part of the evaluation: the message says what was written
        message = str(exc)
    except OSError as exc:
        where = f" ({exc.filename})" if exc.filename else ""
        message = (f"writing the tune's files in {out_dir} failed: {exc.strerror or exc}{where}; nothing partial "
                   f"is left; once there is room, finish with --resume")
    else:
        return
    print("error: " + " ".join(message.split()), file=sys.stderr)
    raise SystemExit(1)
