"""The forest plot of a check's verdicts (``mcjax report`` of a check folder): one row per claim,
each on its own axis in its output's unit, the estimate with two intervals — the interval at the
claim's family-wise level, the one its verdict (``family_verdict``) is read from, drawn thick in the
colour of that verdict, and its own 95 % interval (``verdict``, per claim) thin beside it in the
colour of that one — against what the claim compares it with: the claimed value (dashed, the
claimed side shaded), the claimed band (shaded), the other statistics of a comparison or an order
(a row each), and the paper's number (a star) where the paper gives one.

Why both intervals: the verdict the table leads with is the family's, so its interval is the one
that shows why a claim holds, fails or is undecided; the 95 % interval beside it is the claim alone,
which a reader of one claim expects, and the gap between the two is what judging 16 claims at once
costs. For a claim on one statistic both come from ``claims.parquet``'s numbers (``low``, ``high``;
``family_low``, ``family_high``); for one on several, the 95 % ones from its ``estimates`` and the
family's from ``family_ours`` (three significant digits: the table keeps them as text only).

* :func:`claim_marks` -- what is drawn for each claim (:class:`Marks`), from the verdict table and
  the claims as the file gave them (:func:`mcjax.claims.folder.claim_tables`).
* :func:`forest_figure` -- the figure and its caption; each interval is a line whose ``gid`` is
  ``family:<id>:<side>`` or ``claim:<id>:<side>`` (the estimate: ``estimate:<id>:<side>``).
* :func:`write_forest` -- the PNG, ``OUT/report/forest.png``.

This module does not import JAX.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any, Mapping, NamedTuple, Sequence

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from mcjax.report.plots.common import DPI, PlotFile, new_figure, number_ticks

__all__ = ["FOREST_FILE", "VERDICT_COLORS", "Side", "Marks", "claim_marks", "forest_figure", "write_forest"]

#: The figure's file name in ``OUT/report/``.
FOREST_FILE = "forest.png"
#: The colour of each verdict.
VERDICT_COLORS = {"holds": "#2ca02c", "fails": "#d62728", "undecided": "#8c8c8c"}
_PAPER = "#7b3294"
#: An estimate as ``fmt_estimate`` writes it: ``value [low, high]`` (``–``: none).
_NUMBER = r"(?:-?(?:\d+\.?\d*|\.\d+)(?:e[+-]?\d+)?|–|nan|-?inf)"
_ESTIMATE = re.compile(rf"({_NUMBER}) \[({_NUMBER}), ({_NUMBER})\]")


class Side(NamedTuple):
    """One statistic of a claim: its label (empty for a claim on one), estimate, 95 % interval
    and interval at the claim's family level."""

    label: str
    value: float
    low: float
    high: float
    family_low: float
    family_high: float


class Marks(NamedTuple):
    """What the forest plot draws for one claim: its verdict at the family's level and alone, the
    runs to decide each (-1: decided), its statistics, what it is compared with (a ``value``, a
    ``band``, or none: its other statistics), the paper's number, its unit and the family level's
    confidence."""

    id: str
    verdict: str
    runs_to_decide: int
    per_claim: str
    per_claim_runs: int
    sides: tuple[Side, ...]
    value: float | None
    band: tuple[float, float] | None
    paper: float | None
    relation: str
    unit: str
    confidence: float


def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:  # "–": no interval
        return math.nan


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    return float(value) if math.isfinite(float(value)) else None


def _at(value: Any) -> str:
    if isinstance(value, Mapping):
        return ", ".join(f"{k} = {json.dumps(v)}" for k, v in value.items())
    return str(value)


def _label(keys: Any) -> str:
    """A side's keys in words: ``filter NAME; AXIS = 2500.0``."""
    if not isinstance(keys, Mapping):
        return ""
    words = [f"{k} {keys[k]}" for k in ("sweep", "output", "filter", "statistic") if isinstance(keys.get(k), str)]
    return "; ".join(words + ([_at(keys["at"])] if isinstance(keys.get("at"), Mapping) and keys["at"] else []))


def _labels(row: Mapping[str, Any], raw: Mapping[str, Any], k: int) -> list[str]:
    relation = str(raw.get("relation", ""))
    if relation == "ordered" and isinstance(raw.get("order"), list) and len(raw["order"]) == k:
        return [_label(o) or f"statistic {i + 1}" for i, o in enumerate(raw["order"])]
    if relation in ("below", "above") and k == 2:  # each side by the keys the other side changes
        than = raw.get("than") if isinstance(raw.get("than"), Mapping) else {}
        own = _label({k: raw[k] for k in than if k in raw}) or "the claim's"
        return [own, f"than: {_label(than) or 'the other side'}"]
    if relation == "monotone":
        parts = re.split(r"\s+[<>]\s+", str(row.get("ours", "")))
        if len(parts) == k:
            return [p.split(": ")[0] for p in parts]
    return [f"statistic {i + 1}" for i in range(k)]


def claim_marks(table: pd.DataFrame, raws: Mapping[str, Mapping[str, Any]],
                units: Mapping[str, str] | None = None) -> list[Marks]:
    """Each claim's :class:`Marks`, in the table's order. ``raws``: each claim's table as the claims
    file gave it, by id (its value, band or tolerance, paper's number; :func:`mcjax.claims.folder.claim_tables`);
    ``units``: each claim's unit, by id."""
    units = units or {}
    family = "family_verdict" in table
    out = []
    for row in table.to_dict("records"):
        cid, raw = str(row["id"]), raws.get(str(row["id"]), {})
        ests = json.loads(row["estimates"]) if isinstance(row.get("estimates"), str) else []
        if len(ests) <= 1:  # one statistic: claims.parquet's own numbers
            fam = (row["family_low"], row["family_high"]) if family else (row["low"], row["high"])
            sides = (Side("", float(row["value"]), float(row["low"]), float(row["high"]), float(fam[0]),
                          float(fam[1])),)
        else:
            found = _ESTIMATE.findall(str(row.get("family_ours", ""))) if family else []
            fam = ([(_float(lo), _float(hi)) for _, lo, hi in found] if len(found) == len(ests)
                   else [(e["low"], e["high"]) for e in ests])
            labels = _labels(row, raw, len(ests))
            sides = tuple(Side(lab, float(e["value"]), float(e["low"]), float(e["high"]), float(f[0]), float(f[1]))
                          for lab, e, f in zip(labels, ests, fam))
        relation = str(raw.get("relation", ""))
        value = _number(raw.get("value")) if relation in ("below", "above") and "than" not in raw else None
        band = None
        if relation == "within" and isinstance(raw.get("band"), list) and len(raw["band"]) == 2:
            band = (float(raw["band"][0]), float(raw["band"][1]))
        elif relation == "equal" and None not in (_number(raw.get("value")), _number(raw.get("tolerance"))):
            band = (float(raw["value"]) - float(raw["tolerance"]), float(raw["value"]) + float(raw["tolerance"]))
        verdict = str(row["family_verdict"] if family else row["verdict"])
        runs = int(row["family_runs_to_decide"] if family else row["runs_to_decide"])
        out.append(Marks(cid, verdict, runs, str(row["verdict"]), int(row["runs_to_decide"]), sides, value, band,
                         _number(raw.get("paper")), relation, str(units.get(cid, "")),
                         float(row["family_confidence"]) if family else 0.95))
    return out


def _said(verdict: str, runs: int) -> str:
    return f"{verdict} (~{runs:,} runs)" if verdict == "undecided" and runs >= 0 else verdict


def _limits(m: Marks) -> tuple[float, float]:
    xs = [x for s in m.sides for x in s[1:]]
    xs += [m.value] if m.value is not None else []
    xs += list(m.band) if m.band else []
    xs += [m.paper] if m.paper is not None else []
    xs = np.asarray([x for x in xs if x is not None and math.isfinite(x)], dtype=float)
    if not xs.size:
        return -1.0, 1.0
    lo, hi = float(xs.min()), float(xs.max())
    pad = 0.06 * (hi - lo) if hi > lo else max(abs(hi) * 0.1, 1e-9)
    return lo - pad, hi + pad


def _finite(*xs: float) -> bool:
    return all(math.isfinite(x) for x in xs)


def _panel(ax, m: Marks) -> None:
    k = len(m.sides)
    left, right = _limits(m)
    own, fam = VERDICT_COLORS.get(m.per_claim, "0.4"), VERDICT_COLORS.get(m.verdict, "0.4")
    if m.value is not None:  # the claimed side, shaded, and the value
        ax.axvspan(*((left, m.value) if m.relation == "below" else (m.value, right)), color=VERDICT_COLORS["holds"],
                   alpha=0.07, lw=0)
        ax.axvline(m.value, color="0.15", ls="--", lw=1.0, gid=f"value:{m.id}")
    if m.band is not None:
        ax.axvspan(*m.band, color=VERDICT_COLORS["holds"], alpha=0.14, lw=0, gid=f"band:{m.id}")
    for i, s in enumerate(m.sides):
        y = k - 1 - i
        if _finite(s.family_low, s.family_high):
            ax.plot([s.family_low, s.family_high], [y + 0.14] * 2, color=fam, lw=5, alpha=0.6,
                    solid_capstyle="butt", gid=f"family:{m.id}:{i}")
        if _finite(s.low, s.high):
            ax.plot([s.low, s.high], [y - 0.14] * 2, color=own, lw=1.6, marker="|", ms=7, mew=1.6,
                    gid=f"claim:{m.id}:{i}")
        if math.isfinite(s.value):
            ax.plot([s.value, s.value], [y + 0.14, y - 0.14], ls="none", marker="o", ms=3.5, color="black",
                    gid=f"estimate:{m.id}:{i}")
    if m.paper is not None:
        if m.relation == "consistent":  # the paper's number is what the claim is compared with
            ax.axvline(m.paper, color=_PAPER, ls=":", lw=1.2)
        ax.plot([m.paper], [(k - 1) / 2], ls="none", marker="*", ms=9, color=_PAPER, gid=f"paper:{m.id}")
    ax.set_xlim(left, right)
    ax.set_ylim(-0.55, k - 0.45)
    ax.set_yticks(range(k - 1, -1, -1) if k > 1 else [])
    if k > 1:
        ax.set_yticklabels([s.label for s in m.sides], fontsize=6.5)
    number_ticks(ax.xaxis)
    ax.tick_params(axis="x", labelsize=7, pad=1)
    ax.grid(True, axis="x", alpha=0.25)
    ax.set_title(f"{m.id}: {_said(m.verdict, m.runs_to_decide)}", loc="left", fontsize=8, color=fam,
                 fontweight="bold")
    ax.set_title(f"per claim: {_said(m.per_claim, m.per_claim_runs)}" + (f"   [{m.unit}]" if m.unit else ""),
                 loc="right", fontsize=7.5, color=own)


def forest_figure(marks: Sequence[Marks]) -> tuple[Figure, str]:
    """The forest plot of ``marks`` (module docstring) and its caption."""
    heights = [0.5 + 0.3 * len(m.sides) for m in marks] or [0.8]
    fig = new_figure((8.0, 0.9 + sum(heights) + 0.25 * len(heights)))
    axes = np.atleast_1d(fig.subplots(len(heights), 1, gridspec_kw={"height_ratios": heights}))
    for ax, m in zip(axes, marks):
        _panel(ax, m)
    handles = [Line2D([], [], color="0.45", lw=5, alpha=0.6, label="interval at the family's level (the verdict's)"),
               Line2D([], [], color="0.45", lw=1.6, marker="|", ms=7, label="95 % interval, the claim alone"),
               Line2D([], [], ls="none", marker="o", ms=3.5, color="black", label="estimate"),
               Line2D([], [], color="0.15", ls="--", lw=1.0, label="claimed value (claimed side shaded)"),
               Patch(color=VERDICT_COLORS["holds"], alpha=0.14, lw=0, label="claimed band"),
               Line2D([], [], ls="none", marker="*", ms=9, color=_PAPER, label="the paper's number"),
               *(Patch(color=c, label=v) for v, c in VERDICT_COLORS.items())]
    fig.legend(handles=handles, loc="outside upper center", ncol=3, fontsize=7, frameon=False)
    levels = sorted({round(100 * m.confidence, 2) for m in marks})
    level = (f"{levels[0]:g} %" if len(levels) == 1 else f"{levels[0]:g}–{levels[-1]:g} %") if levels else "95 %"
    caption = (f"Each claim on its own axis, in its output's unit: the estimate (dot) with its interval at the "
               f"family-wise level ({level} confidence; thick, in the colour of the verdict the table leads "
               f"with, which is read from it) and its own 95 % interval (thin, in the colour of its verdict alone), "
               f"against what the claim compares it with: the claimed value (dashed, the claimed side shaded), "
               f"the claimed band (shaded), the other statistics of a comparison or an order (a row each), and "
               f"the paper's number (star) where the paper gives one. Green: holds; red: fails; grey: undecided "
               f"(~N runs: the runs per point that would decide it). A claim on one statistic is drawn from "
               f"claims.parquet's low / high and family_low / family_high; one on several from its estimates, "
               f"its family-level intervals from family_ours (three significant digits).")
    return fig, caption


def write_forest(marks: Sequence[Marks], out_dir: str | Path) -> PlotFile:
    """Draw :func:`forest_figure` to ``OUT/report/forest.png`` at :data:`~mcjax.report.plots.common.DPI`."""
    fig, caption = forest_figure(marks)
    path = Path(out_dir) / "report" / FOREST_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png", dpi=DPI)
    fig.clear()
    return PlotFile(path, caption)
