"""``OUT/report/index.html``: one self-contained page per sweep dataset.

The page leads with what the data show: "What this shows", a few sentences written from the runs
with their intervals and, folded under them, the order of the filters at each design point and the
consistency and error-floor table (:func:`mcjax.analysis.findings.box`). Then every plot with its caption, the summary
tables (the wide one scrolls inside its box), a glossary from the scenario's declarations and
the base Params; below them the spec (as TOML), the config and the provenance (package
versions, git revision, dates, runs present and planned). Images are embedded as base64
``data:`` URIs and the style sheet is inline: the page loads nothing from a network or
another file, so it can be mailed or archived alone. No scripts.

* :func:`page` -- the HTML text; :func:`write_page` -- writes it to ``OUT/report/index.html``.
* :func:`spec_toml` -- a spec (the dict of a TOML file) written back as TOML.
* :func:`head`, :data:`FOOT`, :func:`html_table`, :func:`image` -- the pieces other pages
  share (:mod:`mcjax.report.tune_page`).

Numbers are formatted by :mod:`mcjax.analysis.tables` (:func:`~mcjax.analysis.tables.format_cells`,
:func:`~mcjax.analysis.tables.format_number`), as in the printed tables.  This module does not
import JAX or matplotlib.
"""

from __future__ import annotations

import base64
import html
import math
import os
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping, Sequence

import pandas as pd
import tomli_w

from mcjax.analysis import findings, tables
from mcjax.analysis.statistics import CONFIDENCE
from mcjax.analysis.summary import Summary, summary_for
from mcjax.base.files import atomic_write
from mcjax.report import glossary

__all__ = ["PAGE_NAME", "page", "write_page", "spec_toml", "glance", "head", "FOOT", "html_table", "image"]

#: The page's file name inside ``OUT/report/``.
PAGE_NAME = "index.html"

#: Provenance keys of the dataset's metadata, in the order shown, with their labels.
PROVENANCE = (
    ("created_utc", "dataset written (UTC)"),
    ("git_revision", "git revision of mcjax"),
    ("git_dirty", "uncommitted changes in the mcjax checkout"),
    ("mcjax", "mcjax"),
    ("python", "Python"),
    ("jax", "jax"),
    ("jaxlib", "jaxlib"),
    ("numpy", "numpy"),
    ("pandas", "pandas"),
    ("pyarrow", "pyarrow"),
    ("optax", "optax"),
    ("seeds", "seeds per point"),
    ("base_seed", "base seed"),
    ("chunk_size", "runs per chunk"),
    ("n_points", "points"),
)

_STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; margin: 0; color: #1b1b1b;
       background: #fafafa; line-height: 1.45; }
main { max-width: 1100px; margin: 0 auto; padding: 1.5rem 1.5rem 4rem; background: #fff; }
h1 { font-size: 1.6rem; margin-bottom: 0.2rem; }
h2 { border-bottom: 1px solid #ddd; padding-bottom: 0.2rem; margin-top: 2.2rem; }
.subtitle { color: #555; margin-top: 0; }
.warning { background: #fde8e8; border-left: 4px solid #b00000; padding: 0.6rem 0.8rem; }
nav ul { list-style: none; padding: 0; display: flex; gap: 1.2rem; flex-wrap: wrap; }
pre { background: #f4f4f4; padding: 0.8rem; overflow-x: auto; font-size: 0.85rem; }
.scroll { overflow-x: auto; max-width: 100%; }
.findings { background: #f1f6fc; border-left: 4px solid #1f77b4; padding: 0.2rem 1rem 0.6rem; }
.findings li { margin: 0.35rem 0; }
.note { color: #555; font-size: 0.85rem; }
dt { font-weight: 600; margin-top: 0.4rem; }
dd { margin-left: 1.2rem; }
table { border-collapse: collapse; font-size: 0.82rem; margin: 0.6rem 0; }
th, td { border: 1px solid #ddd; padding: 0.2rem 0.45rem; }
th { background: #f0f0f0; text-align: left; }
table.numbers td { text-align: right; font-variant-numeric: tabular-nums; }
figure { margin: 1.4rem 0; }
figure img { max-width: 100%; height: auto; border: 1px solid #eee; }
figcaption { color: #333; font-size: 0.9rem; max-width: 900px; }
.legend li { font-size: 0.88rem; }
details { margin: 0.5rem 0; }
summary { cursor: pointer; font-weight: 600; }
"""


def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


# ------------------------------------------------------------------------------ spec as TOML


def spec_toml(spec: Mapping[str, Any]) -> str:
    """A sweep spec (as read from TOML, with its ``--set`` values applied) as TOML text
    (:func:`tomli_w.dumps`: the top-level values, then one ``[table]`` per table)."""
    return tomli_w.dumps(dict(spec))


# ------------------------------------------------------------------------------ tables


def html_table(headers: Sequence[str], rows: Sequence[Sequence[str]], numbers: bool = False) -> str:
    """A table of texts (escaped) by :meth:`pandas.DataFrame.to_html`; ``numbers``: its cells
    right-aligned in tabular figures."""
    frame = pd.DataFrame([list(r) for r in rows], columns=list(headers), dtype=object)
    table = frame.to_html(index=False, escape=True, border=0, justify="left",
                          classes="numbers" if numbers else None)
    return f'<div class="scroll">{table}</div>'


def glance(summary: pd.DataFrame, sch: tables.Schema, axes: Sequence[str]) -> pd.DataFrame:
    """The summary's headline columns as text: per point (its axes in their display units)
    and filter, the runs, the mean error
    ``mean [low, high]`` (``mean (every run)`` when every run gave it) and, with a divergence flag, the mean over non-divergent runs and
    the divergence rate in percent ("2.0 % [0.6, 7.0]"), with their intervals (numbers by :func:`mcjax.analysis.tables.format_number`)."""
    e = sch.error

    def interval(row, mean, low, high) -> str:
        m = tables.format_number(row[mean], tables.STAT_DIGITS)
        lo, hi = row[low], row[high]
        if isinstance(lo, float) and math.isnan(lo):
            return m
        if lo == hi:  # an interval of zero width: every run gave the same number
            return f"{m} (every run)"
        return (f"{m} [{tables.format_number(lo, tables.STAT_DIGITS)}, "
                f"{tables.format_number(hi, tables.STAT_DIGITS)}]")

    u = tables.unit(e, sch)
    out = pd.DataFrame(index=summary.index)
    for a in axes:  # in the unit the plots use
        shown, factor = tables.display(a, sch)
        out[f"{a} [{shown}]" if shown else a] = summary[a].map(lambda v, f=factor: tables.scaled(v, f))
    out["filter"] = summary["filter"]
    out["runs"] = summary["n"]
    out[f"mean {e}" + (f" [{u}]" if u else "")] = [interval(r, f"{e}_mean", f"{e}_ci_low", f"{e}_ci_high")
                                                    for _, r in summary.iterrows()]
    if sch.divergence:
        out["non-divergent runs"] = summary["n_ok"]
        out[f"mean {e}, non-divergent" + (f" [{u}]" if u else "")] = [
            interval(r, f"{e}_ok_mean", f"{e}_ok_ci_low", f"{e}_ok_ci_high") for _, r in summary.iterrows()]
        out["divergence rate"] = [findings.percent(r["div_rate"], r["div_ci_low"], r["div_ci_high"])
                                  for _, r in summary.iterrows()]
    return out


# ------------------------------------------------------------------------------ the page


def image(path: Path) -> str:
    """A PNG file as a ``data:`` URI (embedded: the page loads no other file)."""
    return "data:image/png;base64," + base64.b64encode(Path(path).read_bytes()).decode("ascii")


def _png_size(path: Path) -> tuple[int, int] | None:
    head = Path(path).read_bytes()[:24]
    if head[:8] != b"\x89PNG\r\n\x1a\n":
        return None
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


def _figures(plots: Sequence[Any]) -> list[str]:
    """Each plot as a figure: the PNG embedded at half its pixel size (drawn at twice the
    figure's layout resolution: sharp on high-density screens), its alt text the caption's
    first sentence (what the plot shows), the caption under it."""
    out = []
    for p in plots:
        path = Path(p.path)
        size = _png_size(path)
        dims = f' width="{(size[0] + 1) // 2}" height="{(size[1] + 1) // 2}"' if size else ""
        alt = str(p.caption).split(". ")[0].rstrip(".") + "."
        out.append(f'<figure id="{_e(path.stem)}"><img src="{image(path)}" alt="{_e(alt)}"{dims}>'
                   f"<figcaption><strong>{_e(path.name)}</strong> — {_e(p.caption)}</figcaption></figure>")
    return out


def _axis_cells(frame: pd.DataFrame, sch: tables.Schema, axes: Sequence[str]) -> tuple[list[str], list[list[str]]]:
    """A table whose first columns are ``axes`` (values as in the runs) as headers and cells of text: the
    axes in the plots' units (their unit in the header, as :func:`glance` shows them), the rest as it is."""
    shown = {a: tables.display(a, sch) for a in axes}
    headers = [f"{a} [{shown[a][0]}]" if shown[a][0] else a for a in axes] + [str(c) for c in frame.columns
                                                                              if c not in axes]
    rows = [[tables.format_number(tables.scaled(r[a], shown[a][1]), tables.KEY_DIGITS) for a in axes]
            + [str(r[c]) for c in frame.columns if c not in axes] for _, r in frame.iterrows()]
    return headers, rows


def _findings_section(df: pd.DataFrame, metadata: Mapping[str, Any], summary: Summary,
                      warning: str | None, facts: str) -> str:
    """The box: its sentences, then (folded, under them) the order of the filters at each design
    point and the consistency and error-floor table with its one legend."""
    box = findings.box(df, metadata, summary.axes, summary=summary)
    sch, axes = summary.schema, list(summary.plot_axes)
    parts = ['<section id="findings" class="findings"><h2>What this shows</h2>']
    if warning:
        parts.append(f'<p class="warning">WARNING: {_e(warning)}</p>')
    parts.append(f"<p>{_e(facts)}</p>")
    if box.sentences:
        parts.append("<ul>" + "".join(f"<li>{_e(f.text)}</li>" for f in box.sentences) + "</ul>")
    else:
        parts.append("<p>(No sentence: the dataset has fewer than two filters to compare.)</p>")
    parts.append(f'<p class="note">Written from the runs below; an order is stated only where the '
                 f'{_e(findings.PCT)} intervals do not overlap (<a href="#glossary">glossary</a>).</p>')
    if box.orders is not None:
        parts.append(f'<details id="orders"><summary>The order of the filters at each of the {len(box.orders)} '
                     f"design points</summary>")
        parts.append(f"<p>The mean {_e(sch.error)} with its {_e(findings.PCT)} interval, lowest first; '&lt;' "
                     f"stands where every filter before it lies below every filter after it (the intervals apart), "
                     f"'≈' between filters the intervals do not order.</p>")
        parts.append(html_table(*_axis_cells(box.orders, sch, axes)))
        parts.append("</details>")
    if box.quality is not None:
        parts.append('<details id="quality"><summary>Consistency and the error floor, per filter and design point'
                     "</summary>")
        parts.append('<ul class="legend">' + "".join(f"<li>{_e(line)}</li>" for line in box.legend) + "</ul>")
        parts.append(html_table(*_axis_cells(box.quality, sch, axes)))
        parts.append("</details>")
    parts.append("</section>")
    return "\n".join(parts)


def _computed(df: pd.DataFrame, sch: tables.Schema, config: Mapping[str, Any]) -> str:
    """Under the config table: the outputs every run computed (the dataset's declared columns), so that
    a setting that reads off is not taken to have switched off what the page shows."""
    names = [k for k in sch.outputs if k in df.columns]
    off = [str(k) for k, v in config.items() if isinstance(v, str) and v.lower() == "off"]
    return (f"Computed in every run of this dataset: {', '.join(names)}."
            + (f" A setting above that reads off ({', '.join(off)}) left out only outputs not in this list."
               if off else ""))


def _check_sweep_opening(out: Path) -> str | None:
    """What a sweep of ``mcjax check`` is for, where its spec gives no description: the check's paper
    and claims file and the claims that read it (:func:`mcjax.claims.folder.served_claims`)."""
    from mcjax.claims.folder import served_claims

    served = served_claims(out)
    if served is None:
        return None
    saved, ids = served
    claims = saved.get("claims") if isinstance(saved.get("claims"), Mapping) else {}
    paper = claims.get("paper") if isinstance(claims.get("paper"), str) else None
    file = Path(saved["claims_file"]).name if isinstance(saved.get("claims_file"), str) else None
    whose = (f"{paper}'s claims" if paper else "a claims file") + (f" ({file})" if file else "")
    serves = (f": claim {ids[0]} reads it" if len(ids) == 1 else
              f": claims {', '.join(ids[:-1])} and {ids[-1]} read it" if ids else "")
    return f"Sweep {out.name} of mcjax check on {whose}{serves}."


def page(out_dir: str | os.PathLike, df: pd.DataFrame, metadata: Mapping[str, Any], plots: Sequence[Any],
         skipped: Sequence[Any] = (), warning: str | None = None, now: datetime | None = None, *,
         summary: Summary | None = None) -> str:
    """The HTML text of the report on the dataset in ``out_dir``: what it shows first
    (:mod:`mcjax.analysis.findings`), then the plots, the summary tables, the glossary and the base
    Params, and below them the spec, config and provenance.

    Args:
        out_dir: the sweep's output folder (named on the page).
        df: its runs table; metadata: its metadata (:func:`mcjax.base.parquet.read_metadata`).
        plots: written figures, each with ``.path`` (a PNG file) and ``.caption``
            (:class:`mcjax.report.plots.PlotFile`); embedded in this order.
        skipped: plots left out on purpose, each with ``.name`` and ``.reason``.
        warning: a line shown at the top (e.g. the dataset is incomplete).
        now: the time the report is written (default: now, UTC).
        summary: the :class:`mcjax.analysis.summary.Summary` of ``df`` the page's tables, findings
            and figures read (built here when not given).
    """
    one = summary_for(df, metadata, tables.swept_axes(metadata, df.columns), summary)
    sch, axes, summary = one.schema, list(one.axes), one.table
    spec = metadata.get("spec") if isinstance(metadata.get("spec"), Mapping) else {}
    out = Path(out_dir)
    now = now or datetime.now(timezone.utc)
    title = f"{sch.scenario}: {out.name}" if sch.scenario else out.name
    description = spec.get("description") if isinstance(spec.get("description"), str) else None

    parts = [head(f"mcjax report — {title}")]
    parts.append(f"<h1>mcjax report — {_e(title)}</h1>")
    if sch.title:
        parts.append(f'<p class="subtitle">{_e(sch.title)}</p>')
    opening = description or _check_sweep_opening(out)
    if opening:  # no sentence at all where nothing says what the sweep is for
        parts.append(f"<p>{_e(opening)}</p>")
    runs = (len(df[["point_id", "seed_index"]].drop_duplicates()) if {"point_id", "seed_index"} <= set(df.columns)
            else None)
    planned = metadata.get("n_runs")
    filters = ", ".join(tables.ordered_filters(df["filter"], sch.filters)) if "filter" in df.columns else ""
    axes_text = ", ".join(f"{a} (plotted in {tables.display(a, sch)[0] or 'no unit'})" for a in axes)
    runs_text = (f"{runs if runs is not None else '?'} runs present of {planned if planned is not None else '?'} "
                 f"planned")
    parts.append(_findings_section(df, metadata, one, warning,
                                   f"{runs_text}; filters {filters}; swept: {axes_text or 'nothing (one point)'}."))
    parts.append('<nav><ul><li><a href="#plots">Plots</a></li><li><a href="#summary">Summary</a></li>'
                 '<li><a href="#glossary">Glossary</a></li><li><a href="#params">Base Params</a></li>'
                 '<li><a href="#spec">Spec</a></li><li><a href="#provenance">Provenance</a></li></ul></nav>')

    # plots
    parts.append('<section id="plots"><h2>Plots</h2>')
    if not plots:
        parts.append("<p>(No plots.)</p>")
    parts.extend(_figures(plots))
    if skipped:
        parts.append("<h3>Not plotted</h3><ul>" + "".join(f"<li><code>{_e(s.name)}</code>: {_e(s.reason)}.</li>"
                                                         for s in skipped) + "</ul>")
    parts.append("</section>")

    # summary
    pct = f"{100 * CONFIDENCE:g} %"
    parts.append('<section id="summary"><h2>Summary</h2>')
    parts.append(f"<p>Per point (in the plots' units) and filter: the runs, the mean {_e(sch.error)} with its "
                 f"{pct} Student-t "
                 f"interval" + (f", the same over the non-divergent runs and the divergence rate in percent with "
                                f"its {pct} Wilson interval" if sch.divergence else "") + ".</p>")
    g = glance(summary, sch, axes)
    parts.append(html_table(*tables.format_cells(g)[:2], numbers=True))
    parts.append("<h3>Every statistic</h3><p>As <code>mcjax report</code> prints it (the units of its legend: "
                 "an angle in degrees; rates as fractions); the table scrolls sideways inside its box.</p>")
    parts.append('<ul class="legend">' + "".join(f"<li>{_e(line)}</li>" for line
                                                in tables.legend_lines(sch, axes, table_units=True)) + "</ul>")
    parts.append(html_table(*tables.format_cells(tables.in_table_units(summary, sch, axes))[:2], numbers=True))
    parts.append("</section>")

    # glossary and base Params
    parts.append('<section id="glossary"><h2>Glossary</h2><dl>' + "".join(
        f"<dt>{_e(term)}</dt><dd>{_e(words)}</dd>" for term, words in glossary.glossary(metadata, axes))
        + "</dl></section>")
    rows, note = glossary.params_table(metadata, axes)
    parts.append(f'<section id="params"><h2>Base Params</h2><p>{_e(note)}</p>')
    parts.append(html_table(["Param", "value", "unit", "what it is"], rows) if rows else "<p>(None recorded.)</p>")
    parts.append("</section>")

    # spec and config
    parts.append('<section id="spec"><h2>Spec</h2>')
    parts.append("<ul>" + "".join(f"<li>{f}</li>" for f in (
        f"Dataset: <code>{_e(out)}</code>", f"Filters: {_e(filters)}",
        f"Swept: {_e(axes_text) if axes else 'nothing (a single point)'}",
        f"Runs: {_e(runs_text)} ({len(df)} rows, one per run and filter)")) + "</ul>")
    parts.append(f"<pre>{_e(spec_toml(spec))}</pre>" if spec else "<p>(No spec in the dataset's metadata.)</p>")
    config = metadata.get("config")
    if isinstance(config, Mapping) and config:
        parts.append("<h3>Config (as run)</h3>")
        rows = [[str(k), tables.format_number(v, tables.KEY_DIGITS) if not isinstance(v, str) else v]
                for k, v in config.items()]
        parts.append(html_table(["field", "value"], rows))
        parts.append(f'<p class="note">{_e(_computed(df, sch, config))}</p>')
    parts.append("</section>")

    # provenance
    parts.append('<section id="provenance"><h2>Provenance</h2>')
    rows = [["runs present / planned", f"{runs if runs is not None else '?'} / "
                                        f"{planned if planned is not None else '?'}"]]
    for key, name in PROVENANCE:
        if key in metadata:
            value = metadata[key]
            rows.append([name, str(value).lower() if isinstance(value, bool) else str(value)])
    rows.append(["report written (UTC)", now.astimezone(timezone.utc).isoformat(timespec="seconds")])
    parts.append(html_table(["what", "value"], rows))
    parts.append("</section>")
    parts.append(FOOT)
    return "\n".join(parts)


def head(title: str) -> str:
    """The page's head with the inline style sheet, and the opening of its body."""
    return (f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">\n'
            f"<title>{_e(title)}</title>\n<style>{_STYLE}</style>\n</head>\n<body>\n<main>")


#: The page's end.
FOOT = "</main>\n</body>\n</html>\n"


def provenance_section(rows: Sequence[Sequence[str]], meta: Mapping[str, Any], labels: Sequence[tuple[str, str]],
                       now: datetime | None = None) -> str:
    """A page's provenance section: ``rows`` (what, value) first, then each ``(key, label)`` of ``labels`` that
    ``meta`` holds (a flag as ``true``/``false``), then when the report was written (``now``, UTC)."""
    now = now or datetime.now(timezone.utc)
    shown = [*rows, *([name, str(meta[key]).lower() if isinstance(meta[key], bool) else str(meta[key])]
                      for key, name in labels if key in meta)]
    shown.append(["report written (UTC)", now.astimezone(timezone.utc).isoformat(timespec="seconds")])
    return '<section id="provenance"><h2>Provenance</h2>' + html_table(["what", "value"], shown) + "</section>"


def write_page(out_dir: str | os.PathLike, df: pd.DataFrame, metadata: Mapping[str, Any], plots: Sequence[Any],
               skipped: Sequence[Any] = (), warning: str | None = None, *, summary: Summary | None = None) -> Path:
    """Write :func:`page` (of the page's ``summary``, when given) to ``OUT/report/index.html``
    (atomically: :func:`mcjax.base.files.atomic_write`) and return its path."""
    return atomic_write(Path(out_dir) / "report" / PAGE_NAME,
                        page(out_dir, df, metadata, plots, skipped, warning, summary=summary))
