"""``mcjax report`` on the output folder of ``mcjax tune``: one page with the trace, the initial
and tuned values and the held-out comparison paired by seed -- and no sweep plots (the held-out
evaluation is a two-point zip: a line plot of two points says nothing a table does not).

* :func:`is_tune_folder` -- whether a folder holds a tune (its ``tune.json`` or ``trace.parquet``).
* :func:`roles` -- which evaluation point ran the initial and which the tuned Params, and how
  that is known: the dataset's ``role`` column; for a tune written before that column, the
  trace's first and last values matched to the points' values, else the evaluation's own
  description ("point 0 = initial, point 1 = tuned"); nothing else (never the row order alone).
* :func:`summary_table` -- the summary table with a ``role`` column first, as ``mcjax tune`` prints it.
* :func:`paired` -- per filter and output, tuned − initial paired by seed with its 95 %
  Student-t interval (what ``mcjax tune`` prints, :func:`mcjax.tune.paired_differences`).
* :func:`page`, :func:`write_page` -- the HTML page (``OUT/report/index.html``).

This module does not import JAX.
"""

from __future__ import annotations

import html
import json
import math
import os
import re
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import pandas as pd

from mcjax.analysis import findings, tables
from mcjax.analysis.statistics import mean_ci, paired_by_seed, wilson_interval
from mcjax.base.files import atomic_write
from mcjax.report import glossary, html_page

__all__ = ["TUNE_FILE", "TRACE_FILE", "TRACE_FIGURE", "ROLE_COLUMN", "is_tune_folder", "roles", "summary_table",
           "paired", "page", "write_page"]

def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


#: Files of a tune's folder (written by ``mcjax tune``): its identity, the trace and its figure.
TUNE_FILE, TRACE_FILE, TRACE_FIGURE = "tune.json", "trace.parquet", "trace.png"
#: The evaluation dataset's column saying which Params a row ran ("initial" or "tuned").
ROLE_COLUMN = "role"
_DESCRIBED = re.compile(r"point 0 = initial, point 1 = tuned")


def is_tune_folder(out: str | os.PathLike) -> bool:
    """Whether ``out`` holds a tune (``tune.json`` or ``trace.parquet``), not a plain sweep."""
    return (Path(out) / TUNE_FILE).is_file() or (Path(out) / TRACE_FILE).is_file()


def _trace(out: Path) -> pd.DataFrame | None:
    path = out / TRACE_FILE
    if not path.is_file():
        return None
    try:
        trace = pd.read_parquet(path)
    except (OSError, ValueError):
        return None
    return trace.sort_values("step") if len(trace) and "step" in trace.columns else None


def _tune_spec(out: Path) -> dict:
    try:
        saved = json.loads((out / TUNE_FILE).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return {}
    spec = saved.get("spec") if isinstance(saved, dict) else None
    return spec if isinstance(spec, dict) else {}


def _zipped(metadata: Mapping[str, Any]) -> list[str]:
    spec = metadata.get("spec") if isinstance(metadata.get("spec"), Mapping) else {}
    z = spec.get("zip") if isinstance(spec.get("zip"), Mapping) else {}
    return list(z)


def roles(out: str | os.PathLike, df: pd.DataFrame, metadata: Mapping[str, Any]) -> tuple[dict[int, str], str]:
    """``({point_id: "initial" | "tuned"}, how it is known)`` for a tune's evaluation dataset.

    Raises:
        ValueError: the folder does not say which point is which (no ``role`` column, no
            trace whose values match the points, no description saying it), or says it
            inconsistently.
    """
    out = Path(out)
    points = sorted(int(p) for p in pd.unique(df["point_id"]))
    if ROLE_COLUMN in df.columns:
        pairs = df[["point_id", ROLE_COLUMN]].drop_duplicates()
        if pairs["point_id"].duplicated().any() or not set(pairs[ROLE_COLUMN]) <= {"initial", "tuned"}:
            raise ValueError(f"the runs in {str(out)!r} give a point two roles or an unknown role: "
                             f"{sorted(map(tuple, pairs.to_numpy().tolist()))}")
        return {int(p): str(r) for p, r in pairs.to_numpy().tolist()}, "the dataset's role column"
    if len(points) == 1:
        return {points[0]: "initial"}, "one point: no tuned Param moved from its initial value"
    names = _zipped(metadata)
    trace = _trace(out)
    if trace is not None and names and all(n in trace.columns and n in df.columns for n in names):
        first, last = trace.iloc[0], trace.iloc[-1]
        found: dict[int, str] = {}
        for p in points:
            row = df[df["point_id"] == p].iloc[0]
            for role, ref in (("initial", first), ("tuned", last)):
                if all(math.isclose(float(row[n]), float(ref[n]), rel_tol=1e-12, abs_tol=0.0) for n in names):
                    found[p] = role
        if len(found) == len(points) and sorted(found.values()) == ["initial", "tuned"]:
            return found, "each point's values matched to the trace's first (initial) and last (tuned) values"
    spec = metadata.get("spec") if isinstance(metadata.get("spec"), Mapping) else {}
    if points == [0, 1] and _DESCRIBED.search(str(spec.get("description") or "")):
        return {0: "initial", 1: "tuned"}, "the evaluation's description (point 0 = initial, point 1 = tuned)"
    raise ValueError(f"cannot tell which point of the tune in {str(out)!r} ran the initial and which the tuned "
                     f"Params: its runs have no {ROLE_COLUMN!r} column, its {TRACE_FILE} does not match the points' "
                     f"values and its description does not say; run the tune again with --force")


def summary_table(out_dir: str | os.PathLike, df: pd.DataFrame, metadata: Mapping[str, Any], fmt: str = "text",
                  warning: str | None = None) -> str:
    """The summary table of a tune's evaluation with a ``role`` column first (initial, tuned),
    as ``mcjax tune`` prints it, in ``fmt`` (:data:`mcjax.analysis.tables.FORMATS`); without a way to
    tell the roles (:func:`roles`), the sweep's table grouped by the zipped Params."""
    sch = tables.schema(metadata, df.columns)
    axes = tables.swept_axes(metadata, df.columns)
    try:
        role_of = roles(out_dir, df, metadata)[0]
    except ValueError:
        role_of = None
    if role_of is not None:
        df = df.assign(**{ROLE_COLUMN: df["point_id"].map(lambda p: role_of[int(p)])})
        axes = [ROLE_COLUMN, *[a for a in axes if a != ROLE_COLUMN]]
    header = ([f"WARNING: {warning}"] if warning else []) + tables.legend_lines(sch, [a for a in axes if a != ROLE_COLUMN])
    if role_of is not None:
        header.append(f"{ROLE_COLUMN}: which Params ran — initial (before the tune) or tuned (after it)")
    return tables.format_table(tables.summarize(df, sch, axes), fmt, header)


def paired(df: pd.DataFrame, role_of: Mapping[int, str], columns: list[str],
           metadata_filters: tuple[str, ...] = ()) -> pd.DataFrame:
    """Per filter and output column, the mean over the seeds both points ran of tuned − initial
    with its 95 % Student-t interval (a flag's difference is one of rates), beside each role's
    mean: the comparison :func:`mcjax.tune.paired_differences` prints; filters in the order
    ``metadata_filters`` (the dataset's ``filters``) gives."""
    point = {r: p for p, r in role_of.items()}
    if set(point) != {"initial", "tuned"}:
        return pd.DataFrame([])
    return pd.DataFrame(paired_by_seed(df, columns, point["initial"], point["tuned"],
                                       tables.ordered_filters(df["filter"], metadata_filters)))


def _stat(values: pd.Series, flag: bool, unit: str) -> str:
    x = values.astype(float).to_numpy()
    if flag:
        k, n = int(np.nansum(x)), int(np.isfinite(x).sum())
        ci = wilson_interval(k, n)
        return findings.percent(k / n if n else math.nan, ci.low, ci.high)
    m = mean_ci(x)
    return findings.quote(m.mean, m.low, m.high, unit)


def _difference(r: Mapping[str, Any], flag: bool, unit: str) -> str:
    if flag:
        lo, hi = r["ci_low"], r["ci_high"]
        inner = f" [{100 * lo:+.1f}, {100 * hi:+.1f}]" if math.isfinite(lo) and math.isfinite(hi) else ""
        return f"{100 * r['paired_difference']:+.1f} percentage points{inner}"
    return findings.quote(r["paired_difference"], r["ci_low"], r["ci_high"], unit, every="every seed")


def _sentences(pairs: pd.DataFrame, sch: tables.Schema, n: int) -> list[str]:
    """One sentence per filter and output: lower / higher only where the paired interval
    excludes 0."""
    out = []
    for _, r in pairs.iterrows():
        flag = r["output"] == sch.divergence
        u = tables.unit(str(r["output"]), sch)
        what = "divergence rate" if flag else f"mean {r['output']}"
        d = _difference(r, flag, u)
        lo, hi = r["ci_low"], r["ci_high"]
        if math.isfinite(lo) and hi < 0:
            verdict = f"the tuned Params lower {r['filter']}'s {what}"
        elif math.isfinite(lo) and lo > 0:
            verdict = f"the tuned Params raise {r['filter']}'s {what}"
        else:
            verdict = f"no change of {r['filter']}'s {what} beyond the {findings.PCT} interval"
        out.append(f"On {int(r['n'])} held-out seeds {verdict}: tuned − initial, paired by seed, {d}.")
    return out


def page(out_dir: str | os.PathLike, df: pd.DataFrame, metadata: Mapping[str, Any], warning: str | None = None,
         now: datetime | None = None) -> str:
    """The HTML page of a tune's folder: what the held-out comparison shows, the initial and
    tuned values, the trace (its figure embedded), the comparison table (each role's mean or
    rate with its interval, tuned − initial paired by seed), the summary per role, the
    glossary, then the tune's spec and the evaluation's provenance. No sweep plots."""
    out = Path(out_dir)
    sch = tables.schema(metadata, df.columns)
    role_of, how = roles(out, df, metadata)
    data = df.assign(**{ROLE_COLUMN: df["point_id"].map(lambda p: role_of[int(p)])})
    names = _zipped(metadata)
    trace = _trace(out)
    tune_spec = _tune_spec(out)
    now = now or datetime.now(timezone.utc)
    e = sch.error
    columns = [c for c in (e, sch.divergence) if c]
    pairs = paired(data, role_of, columns, sch.filters)
    n_seeds = int(data["seed_index"].nunique()) if "seed_index" in data.columns else 0
    parts = [html_page.head(f"mcjax report — tune: {out.name}"),
             f"<h1>mcjax report — tune: {_e(out.name)}</h1>"]
    if sch.title:
        parts.append(f'<p class="subtitle">{_e(sch.title)}</p>')
    parts.append('<section id="findings" class="findings"><h2>What this shows</h2>')
    if warning:
        parts.append(f'<p class="warning">WARNING: {_e(warning)}</p>')
    moved = ", ".join(names) if names else "none"
    parts.append(f"<p>A tune of {_e(moved)} on the scenario's smooth system, then the initial and the tuned values "
                 f"run on {n_seeds} held-out seeds with the exact simulation (which point is which: {_e(how)}).</p>")
    said = _sentences(pairs, sch, n_seeds)
    parts.append("<ul>" + "".join(f"<li>{_e(s)}</li>" for s in said) + "</ul>" if said else
                 "<p>(No comparison: no tuned Param moved, so the evaluation ran one point.)</p>")
    parts.append("</section>")

    # initial and tuned values
    parts.append('<section id="values"><h2>Initial and tuned values</h2>')
    value_rows = []
    tuned_names = [n for n in (tune_spec.get("tune", {}).get("params", {}) if isinstance(tune_spec.get("tune"), dict)
                               else {})] or names
    for n in tuned_names:
        if trace is not None and n in trace.columns:
            a, b = float(trace[n].iloc[0]), float(trace[n].iloc[-1])
        elif n in data.columns:
            a = float(data.loc[data[ROLE_COLUMN] == "initial", n].iloc[0])
            b = float(data.loc[data[ROLE_COLUMN] == "tuned", n].iloc[0]) if "tuned" in role_of.values() else a
        else:
            continue
        value_rows.append([n, tables.format_number(a, 6), tables.format_number(b, 6), tables.unit(n, sch),
                           glossary.declared_words(n, sch)])
    parts.append(html_page.html_table(["Param", "initial", "tuned", "unit", "what it is"], value_rows)
                 if value_rows else "<p>(The folder records no tuned values.)</p>")
    parts.append("</section>")

    # trace
    parts.append('<section id="trace"><h2>Optimisation trace</h2>')
    figure = out / TRACE_FIGURE
    if trace is not None:
        first, last = trace.iloc[0], trace.iloc[-1]
        parts.append(f"<p>{len(trace) - 1} optimisation step(s); training loss {_e(tables.format_number(first['loss']))}"
                     f" → {_e(tables.format_number(last['loss']))} (row k: the loss at the values before update k; "
                     f"the last row: the tuned values).</p>")
    if figure.is_file():
        parts.append(f'<figure id="trace-figure"><img src="{html_page.image(figure)}" alt="The training loss and '
                     f'each tuned Param against the optimisation step." style="max-width:100%;height:auto">'
                     f"<figcaption><strong>{TRACE_FIGURE}</strong> — the training loss (and its two parts) per "
                     f"optimisation step, and each tuned Param per step between its bounds.</figcaption></figure>")
    elif trace is None:
        parts.append("<p>(No trace in this folder.)</p>")
    parts.append("</section>")

    # comparison
    parts.append('<section id="comparison"><h2>Held-out comparison</h2>')
    parts.append(f"<p>Per filter: each role's mean (a rate: in percent, Wilson interval) with its "
                 f"{_e(findings.PCT)} interval, and tuned − initial paired by seed (the same seeds ran both) "
                 f"with its {_e(findings.PCT)} Student-t interval.</p>")
    rows = []
    for _, r in pairs.iterrows():
        flag = r["output"] == sch.divergence
        u = tables.unit(str(r["output"]), sch)
        g = data[data["filter"] == r["filter"]]
        rows.append([str(r["filter"]), str(r["output"]),
                     _stat(g.loc[g[ROLE_COLUMN] == "initial", r["output"]], flag, u),
                     _stat(g.loc[g[ROLE_COLUMN] == "tuned", r["output"]], flag, u),
                     _difference(r, flag, u), str(int(r["n"]))])
    parts.append(html_page.html_table(["filter", "output", "initial", "tuned", "tuned − initial (paired)",
                                         "seeds"], rows, numbers=True) if rows else "<p>(Nothing to compare.)</p>")
    summary = tables.summarize(data, sch, [ROLE_COLUMN])
    parts.append("<h3>Every statistic, per role</h3>")
    parts.append(html_page.html_table(*tables.format_cells(summary)[:2], numbers=True))
    parts.append("</section>")

    parts.append('<section id="glossary"><h2>Glossary</h2><dl>' + "".join(
        f"<dt>{_e(t)}</dt><dd>{_e(w)}</dd>" for t, w in glossary.glossary(metadata, names, tuned=True))
        + "</dl></section>")
    parts.append('<section id="spec"><h2>Spec</h2>')
    if tune_spec:
        parts.append(f"<h3>The tune ({TUNE_FILE})</h3><pre>{_e(html_page.spec_toml(tune_spec))}</pre>")
    spec = metadata.get("spec") if isinstance(metadata.get("spec"), Mapping) else {}
    parts.append(f"<h3>The held-out evaluation</h3><pre>{_e(html_page.spec_toml(spec))}</pre>")
    parts.append("</section>")
    prov = [[name, str(metadata[key])] for key, name in html_page.PROVENANCE if key in metadata]
    prov.append(["report written (UTC)", now.astimezone(timezone.utc).isoformat(timespec="seconds")])
    parts.append('<section id="provenance"><h2>Provenance</h2>' + html_page.html_table(["what", "value"], prov)
                 + "</section>")
    parts.append(html_page.FOOT)
    return "\n".join(parts)


def write_page(out_dir: str | os.PathLike, df: pd.DataFrame, metadata: Mapping[str, Any],
               warning: str | None = None) -> Path:
    """Write :func:`page` to ``OUT/report/index.html`` (atomically) and return its path."""
    return atomic_write(Path(out_dir) / "report" / html_page.PAGE_NAME, page(out_dir, df, metadata, warning))
