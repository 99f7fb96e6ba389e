"""The report's words beside its findings: a glossary of a dataset's terms (the filters, the error
metric, the divergence flag, the graph statistics, the swept axes, the intervals) and the base
Params table, both from the dataset's declarations — nothing here names a scenario, a filter or
a unit. No JAX, no matplotlib."""

from __future__ import annotations

from typing import Any, Mapping, Sequence

from mcjax.analysis import tables
from mcjax.analysis.findings import PCT

__all__ = ["ROLE_WORDS", "declared_words", "glossary", "params_table"]


#: What each role means, in words that hold for any scenario (the roles of mcjax.contract).
ROLE_WORDS = {
    "error": "the metric the report leads with; the mean over runs comes with its {pct} Student-t interval",
    "divergence": "a run counts as diverged when this flag is set; the divergence rate is the percentage of runs "
                  "flagged, with its {pct} Wilson interval",
    "nonfinite": "a run whose estimate went NaN or infinite (it counts as diverged)",
    "connectivity_mean": "λ2, the algebraic connectivity: the second-smallest eigenvalue of the comm graph's "
                         "Laplacian; 0 when the graph has fallen apart, larger when it is better connected",
    "connectivity_min": "the same λ2 at the run's worst step: 0 means the graph was disconnected at least once",
    "disconnected_steps": "how many of the run's steps the comm graph was in pieces (λ2 = 0): agents in "
                          "different pieces cannot share estimates",
    "nees": "the normalised estimation error squared: the squared error weighed by the filter's own covariance. "
            "A filter honest about its error averages the state's dimension; above the {pct} band of that many "
            "runs it is over-confident (its errors are larger than it claims), below it under-confident",
    "nis": "the normalised innovation squared: each agent's measurement surprise weighed by the spread the filter "
           "predicted for it; the same rule as the NEES, with the measurement's dimension",
    "floor": "the error floor: the posterior Cramér–Rao bound, the smallest RMS error any filter of the same "
             "measurements can have (averaged over the runs); each filter's error is given as a multiple of it",
}


def declared_words(name: str, sch: tables.Schema) -> str:
    """The declared description of an output or Param column ("" without one)."""
    decl = sch.outputs.get(name) if name in sch.outputs else sch.params.get(name)
    return str((decl or {}).get("description") or "").strip() if isinstance(decl, Mapping) else ""


def glossary(metadata: Mapping[str, Any], axes: Sequence[str] = (), *, tuned: bool = False) -> list[tuple[str, str]]:
    """``(term, words)`` for the words of the page: each filter (its declared words from the
    metadata's ``filter_descriptions`` where the scenario gives them, else the scenario's own
    title), the error metric, the divergence flag (with the config's threshold), the graph
    statistics, each swept axis (``tuned``: each tuned Param of a tune's evaluation), the base
    Params and the two kinds of interval."""
    sch = tables.schema(metadata)
    pct = PCT
    out: list[tuple[str, str]] = []
    described = metadata.get("filter_descriptions") if isinstance(metadata, Mapping) else None
    described = described if isinstance(described, Mapping) else {}
    missing = [f for f in sch.filters if not described.get(f)]
    named = metadata.get("filter_names") if isinstance(metadata, Mapping) else None
    named = named if isinstance(named, Mapping) else {}
    for f in sch.filters:
        if described.get(f):  # the sentences' name for it, and the code name the tables use
            out.append((f"{named[f]} ({f})" if named.get(f) and named[f] != f else f, str(described[f])))
    if missing:
        out.append((", ".join(missing), "the estimators compared, run side by side on the same measurements in "
                    "every run (one row per run and filter)" + (f"; the scenario's own words: {sch.title}"
                                                                if sch.title else "")))
    config = metadata.get("config") if isinstance(metadata.get("config"), Mapping) else {}
    for role in ("error", "divergence", "nonfinite", "connectivity_mean", "connectivity_min", "disconnected_steps",
                 "nees", "nis", "floor"):
        name = getattr(sch, role)
        if not name:
            continue
        u = tables.unit(name, sch)
        words = declared_words(name, sch)
        text = (words + " — " if words else "") + ROLE_WORDS[role].format(pct=pct)
        if role == "divergence" and "divergence_threshold" in config:
            text += f" (in this config divergence_threshold = {tables.format_number(config['divergence_threshold'])})"
        out.append((f"{name} [{u}]" if u else name, text))
    for a in axes:
        shown = tables.display(a, sch)[0]
        label = (sch.params.get(a) or {}).get("label") if isinstance(sch.params.get(a), Mapping) else None
        term = f"{label} ({a})" if label else a
        out.append((f"{term} [{shown}]" if shown else term, (declared_words(a, sch) or "a Param")
                    + (" — tuned by gradient through the closed loop" if tuned else " — swept")))
    out.append(("Params", "the scenario's parameters a sweep may vary without recompiling (radii, noise levels, "
                          "weights)" + ("" if tuned else "; their values in this dataset are in the table "
                                                         "'Base Params'")))
    out.append((f"{pct} interval", "a mean's Student-t interval, a rate's Wilson score interval: where two "
                                   "intervals do not overlap, the report calls one value lower"))
    return out


def params_table(metadata: Mapping[str, Any], axes: Sequence[str] = ()) -> tuple[list[list[str]], str]:
    """The base Params as rows ``[name, value, unit, description]`` and a note on where the
    values come from: the metadata's ``base_params`` (the Params every point starts from,
    written by the sweep) when the dataset has them; else ``base_params_file`` (the base config
    file's ``[params]`` as :func:`mcjax.report.base_params_from_files` read them); else only the
    spec's ``[params]`` table. The note says which."""
    sch = tables.schema(metadata)
    values = metadata.get("base_params")
    files = metadata.get("base_params_file")
    if isinstance(values, Mapping) and values:
        note = "The Params every point starts from (the base config with the spec's [params] and --set applied)."
    elif isinstance(files, Mapping) and isinstance(files.get("values"), Mapping):
        values = files["values"]
        note = (f"The dataset does not record its base Params (written by an older mcjax): these are the [params] "
                f"of its base config file {files.get('path')} as that file is now, with the spec's [params] over "
                f"them; if the file changed since the sweep ran, they may differ from what ran.")
    else:
        spec = metadata.get("spec") if isinstance(metadata.get("spec"), Mapping) else {}
        values = spec.get("params") if isinstance(spec.get("params"), Mapping) else {}
        base = spec.get("base")
        note = ("This dataset does not record its base Params (written by an older mcjax): only the spec's "
                "[params] are shown" + (f"; the rest are those of its base config, {base}" if base else "") + ".")
    rows = []
    for name in list(sch.params) + [k for k in values if k not in sch.params]:
        if name not in values and name not in axes:
            continue
        value = f"swept ({name} is an axis)" if name in axes else tables.format_number(
            _plain(values[name]), tables.KEY_DIGITS)
        rows.append([name, value, tables.unit(name, sch), declared_words(name, sch)])
    return rows, note


def _plain(value: Any) -> Any:
    if isinstance(value, list):
        return tuple(_plain(v) for v in value)
    return value
