"""Summary tables and plots of a sweep's output folder (``OUT/runs/*.parquet``).

Entry point: :func:`report` reads ``OUT`` with :mod:`mcjax.results`, finds the swept axes in
the metadata (:func:`swept_axes`), and returns a formatted summary table plus the PNG plots
written to ``OUT/report/``.  The pieces are usable on their own:

* :func:`summarize` -- one row per (swept axes..., filter) with run counts, mean RMSE and
  its 95 % confidence interval, mean RMSE of the non-divergent runs, the divergence count
  and rate with a 95 % Wilson interval, graph statistics (λ2, disconnected steps).
* :func:`format_table` -- the summary as ``"text"``, ``"csv"`` or ``"markdown"``.
* :func:`make_plots` -- PNG figures (see its docstring for the file names).
* :func:`mean_ci`, :func:`wilson_interval`, :func:`t_critical_95` -- the statistics.

Statistics (all at 95 %):

* Mean CI: Student-t interval ``mean ± t(0.975, n-1)·sd/√n`` (``sd`` with ``ddof=1``).
  scipy is not a runtime dependency, so the t quantile comes from a hand-written table for
  1–30 degrees of freedom (6 decimals) and, above 30, from the Cornish–Fisher expansion of
  the t quantile around the normal quantile 1.959964 (relative error < 2e-8).  With one
  run the interval is NaN.  Non-finite RMSE values (``nonfinite`` runs) are left out of
  ``rmse_mean`` (they would make it NaN/inf); they always count as diverged, and the
  ``nonfinite`` column says how many there were.
* Divergence rate: ``k/n`` with the Wilson score interval (no continuity correction), the
  same as ``scipy.stats.binomtest(k, n).proportion_ci(method="wilson")``.

Plots use matplotlib's object API (:class:`matplotlib.figure.Figure` with an explicit Agg
canvas), never :mod:`matplotlib.pyplot`: the global backend and pyplot's figure registry
are left untouched and nothing needs a display.  matplotlib is imported only inside
:func:`make_plots`.

This module imports neither JAX nor scipy nor tabulate.
"""

from __future__ import annotations

import itertools
import math
import os
import re
from pathlib import Path
from statistics import NormalDist
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
import pandas as pd

from mcjax import results

__all__ = [
    "FORMATS",
    "FILTER_ORDER",
    "AXIS_UNITS",
    "SUMMARY_COLUMNS",
    "t_critical_95",
    "mean_ci",
    "wilson_interval",
    "swept_axes",
    "summarize",
    "format_table",
    "make_plots",
    "report",
]

#: Output formats accepted by :func:`format_table` and :func:`report`.
FORMATS = ("text", "csv", "markdown")
#: Display order (and colour) of the known filters; other filters follow alphabetically.
FILTER_ORDER = ("cif", "icf", "modified_icf", "kcf", "local", "imm", "cv", "ct")
#: Units of swept parameters (mirrors the scenarios' ``PARAM_UNITS``,
#: copied so this module does not import JAX).  Unknown axes get no unit.
AXIS_UNITS = {
    "dt": "s",
    "comm_radius": "m",
    "sensing_radius": "m",
    "sigma_range": "m",
    "sigma_bearing": "rad",
    "sigma_accel": "m/s^2",
    "uav_speed": "m/s",
    "alpha_phi": "1/s",
    "turn_rate_max": "rad/s",
    "heading_cmd": "rad",
    "initial_positions": "m",
    "initial_headings": "rad",
    "target_x0": "m, m/s",
    "p0_diag": "m^2, (m/s)^2",
    "kcf_epsilon": "-",
    "alive": "0/1",
    "target_sigma_accel": "m/s^2",
    "alpha_I": "-",
    "alpha_C": "1/rad",
    "alpha_L": "1/m",
    "alpha_S": "-",
    "d_safe": "m",
    "d_lt": "m",
    "robustness_scale": "m",
    "plan_temperature": "m",
    "horizon": "steps",
    "replan_every": "steps",
    # uuv_imm (mcjax.scenarios.uuv_imm.PARAM_UNITS)
    "turn_rate": "rad/s",
    "model_turn_rate_error": "rad/s",
    "ct_start": "steps",
    "ct_stop": "steps",
}

#: Metric columns of :func:`summarize` (after the axis columns and ``filter``).
SUMMARY_COLUMNS = (
    "n",                        # runs in the group
    "rmse_mean",                # mean RMSE over runs with a finite RMSE
    "rmse_ci_low",              # 95 % t-interval of rmse_mean
    "rmse_ci_high",
    "n_ok",                     # non-divergent runs
    "rmse_ok_mean",             # mean RMSE over the non-divergent runs
    "rmse_ok_ci_low",           # 95 % t-interval of rmse_ok_mean
    "rmse_ok_ci_high",
    "diverged",                 # divergent runs (count)
    "nonfinite",                # runs with non-finite errors (count; all are divergent)
    "div_rate",                 # diverged / n
    "div_ci_low",               # 95 % Wilson interval of div_rate
    "div_ci_high",
    "lambda2_mean",             # mean over runs of the per-run mean λ2
    "lambda2_min",              # minimum over runs of the per-run minimum λ2
    "disconnected_steps_mean",  # mean over runs of the per-run disconnected steps
)

_Z975 = NormalDist().inv_cdf(0.975)  # 1.959963984540054
# t(0.975, dof) for dof = 1..30 (6 decimals).
_T975 = (
    12.706205, 4.302653, 3.182446, 2.776445, 2.570582, 2.446912, 2.364624, 2.306004,
    2.262157, 2.228139, 2.200985, 2.178813, 2.160369, 2.144787, 2.131450, 2.119905,
    2.109816, 2.100922, 2.093024, 2.085963, 2.079614, 2.073873, 2.068658, 2.063899,
    2.059539, 2.055529, 2.051831, 2.048407, 2.045230, 2.042272,
)
_FILTER_COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
                  "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf")
_REQUIRED = ("filter", "rmse", "diverged")


# --------------------------------------------------------------------------------------
# statistics
# --------------------------------------------------------------------------------------


def t_critical_95(dof: float) -> float:
    """Two-sided 95 % Student-t critical value ``t(0.975, dof)``; NaN for ``dof < 1``.

    Table for integer ``dof`` 1–30, Cornish–Fisher expansion (4 terms) otherwise; matches
    ``scipy.stats.t.ppf(0.975, dof)`` to a relative 1e-6 (table rounding) and better than
    2e-8 above 30.
    """
    dof = float(dof)
    if not dof >= 1:  # also NaN
        return math.nan
    if dof <= 30 and dof == int(dof):
        return _T975[int(dof) - 1]
    if math.isinf(dof):
        return _Z975
    z, v = _Z975, dof
    return (z
            + (z**3 + z) / (4 * v)
            + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * v**2)
            + (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / (384 * v**3)
            + (79 * z**9 + 776 * z**7 + 1482 * z**5 - 1920 * z**3 - 945 * z) / (92160 * v**4))


def mean_ci(values: Iterable[float]) -> tuple[float, float, float]:
    """``(mean, low, high)``: mean of the finite ``values`` and its 95 % t-interval.

    Non-finite values are ignored.  No finite value: all NaN; one: the interval is NaN.
    """
    x = np.asarray(list(values) if not isinstance(values, (np.ndarray, pd.Series)) else values,
                   dtype=float).ravel()
    x = x[np.isfinite(x)]
    n = x.size
    if n == 0:
        return math.nan, math.nan, math.nan
    mean = float(x.mean())
    if n == 1:
        return mean, math.nan, math.nan
    half = t_critical_95(n - 1) * float(x.std(ddof=1)) / math.sqrt(n)
    return mean, mean - half, mean + half


def wilson_interval(k: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval ``(low, high)`` of a binomial proportion ``k/n``.

    No continuity correction (as ``scipy.stats.binomtest(k, n).proportion_ci(
    method="wilson")``).  ``n == 0`` gives ``(nan, nan)``.
    """
    k, n = int(k), int(n)
    if n < 0 or k < 0 or k > n:
        raise ValueError(f"wilson_interval needs 0 <= k <= n, got k={k}, n={n}")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    if n == 0:
        return math.nan, math.nan
    z = NormalDist().inv_cdf(0.5 + confidence / 2)
    p = k / n
    z2n = z * z / n
    denom = 1 + z2n
    center = (p + z2n / 2) / denom
    half = z / denom * math.sqrt(p * (1 - p) / n + z2n / (4 * n))
    low = 0.0 if k == 0 else max(0.0, center - half)
    high = 1.0 if k == n else min(1.0, center + half)
    return low, high


# --------------------------------------------------------------------------------------
# summary table
# --------------------------------------------------------------------------------------


def swept_axes(metadata: Mapping[str, Any] | None, columns: Iterable[str]) -> list[str]:
    """Swept axes of a sweep: keys of ``metadata["spec"]["grid"]`` then of ``["zip"]``
    (a table, or a list of tables), in spec order, restricted to ``columns``."""
    spec = (metadata or {}).get("spec") or {}
    if not isinstance(spec, Mapping):
        return []
    names: list[str] = []
    tables: list[Any] = [spec.get("grid") or {}]
    zipped = spec.get("zip") or {}
    tables.extend(zipped if isinstance(zipped, list) else [zipped])
    for table in tables:
        if isinstance(table, Mapping):
            names.extend(k for k in table if k not in names)
    cols = set(columns)
    return [n for n in names if n in cols]


def _axes_list(axes: str | Sequence[str] | None) -> list[str]:
    if axes is None:
        return []
    if isinstance(axes, str):
        return [axes]
    out = list(axes)
    for a in out:
        if not isinstance(a, str):
            raise TypeError(f"axes must be column names (str), got {a!r}")
    if len(set(out)) != len(out):
        raise ValueError(f"axes contain duplicates: {out}")
    return out


def _check_columns(df: Any, needed: Sequence[str], where: str) -> None:
    if not isinstance(df, pd.DataFrame):
        raise TypeError(f"{where}: df must be a pandas DataFrame, got {type(df).__name__}")
    missing = [c for c in needed if c not in df.columns]
    if missing:
        raise ValueError(f"{where}: column(s) {missing} not in the table; it has {list(df.columns)}")


def _hashable(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        return tuple(_hashable(v) for v in value)
    return value


def _prepare(df: pd.DataFrame, axes: Sequence[str]) -> pd.DataFrame:
    """Make list/array-valued axis cells (per-agent parameters) hashable tuples."""
    data = df
    for a in axes:
        col = df[a]
        if col.dtype == object and col.map(lambda v: isinstance(v, (list, tuple, np.ndarray))).any():
            if data is df:
                data = df.copy()
            data[a] = col.map(_hashable)
    return data


def _filter_rank(name: Any) -> tuple[int, str]:
    name = str(name)
    return (FILTER_ORDER.index(name), "") if name in FILTER_ORDER else (len(FILTER_ORDER), name)


def _ordered_filters(values: Iterable[Any]) -> list[Any]:
    return sorted(pd.unique(pd.Series(list(values))), key=_filter_rank)


def _as_bool(s: pd.Series) -> np.ndarray:
    return pd.array(s, dtype="boolean").fillna(False).to_numpy(dtype=bool)


def _col(g: pd.DataFrame, name: str) -> np.ndarray:
    return g[name].to_numpy(dtype=float) if name in g.columns else np.full(len(g), np.nan)


def _nan_stat(fn, x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(fn(x)) if x.size else math.nan


def _group_stats(g: pd.DataFrame) -> dict[str, Any]:
    rmse = g["rmse"].to_numpy(dtype=float)
    div = _as_bool(g["diverged"])
    n = len(g)
    k = int(div.sum())
    nonfinite = (int(_as_bool(g["nonfinite"]).sum()) if "nonfinite" in g.columns
                 else int((~np.isfinite(rmse)).sum()))
    mean, lo, hi = mean_ci(rmse)
    ok_mean, ok_lo, ok_hi = mean_ci(rmse[~div])
    d_lo, d_hi = wilson_interval(k, n)
    return {
        "n": n,
        "rmse_mean": mean, "rmse_ci_low": lo, "rmse_ci_high": hi,
        "n_ok": n - k,
        "rmse_ok_mean": ok_mean, "rmse_ok_ci_low": ok_lo, "rmse_ok_ci_high": ok_hi,
        "diverged": k,
        "nonfinite": nonfinite,
        "div_rate": k / n if n else math.nan, "div_ci_low": d_lo, "div_ci_high": d_hi,
        "lambda2_mean": _nan_stat(np.mean, _col(g, "lambda2_mean")),
        "lambda2_min": _nan_stat(np.min, _col(g, "lambda2_min")),
        "disconnected_steps_mean": _nan_stat(np.mean, _col(g, "disconnected_steps")),
    }


def summarize(df: pd.DataFrame, axes: str | Sequence[str] | None = ()) -> pd.DataFrame:
    """Summary of a runs table: one row per combination of ``axes`` and ``filter``.

    Args:
        df: runs table (one row per run and filter) with at least ``filter``, ``rmse`` and
            ``diverged``; ``nonfinite``, ``lambda2_mean``, ``lambda2_min`` and
            ``disconnected_steps`` are used when present (NaN columns otherwise).
        axes: swept parameter columns to group by (``[]`` pools every run of a filter).
            List-valued cells (per-agent values) are grouped as tuples.  Runs of values of
            other, unlisted axes are pooled.

    Returns:
        DataFrame with columns ``[*axes, "filter", *SUMMARY_COLUMNS]`` (see
        :data:`SUMMARY_COLUMNS` and the module docstring for the statistics), sorted by the
        axes and then by filter (:data:`FILTER_ORDER` first), with a fresh index.
    """
    axes = _axes_list(axes)
    _check_columns(df, [*axes, *_REQUIRED], "summarize")
    keys = [*axes, "filter"]
    columns = [*keys, *SUMMARY_COLUMNS]
    if df.empty:
        return pd.DataFrame(columns=columns)
    data = _prepare(df, axes)
    rows = []
    for key, g in data.groupby(keys, sort=False, dropna=False):
        key = key if isinstance(key, tuple) else (key,)
        rows.append({**dict(zip(keys, key)), **_group_stats(g)})
    out = pd.DataFrame(rows, columns=columns)
    out["_rank"] = out["filter"].map(_filter_rank)
    out = out.sort_values([*axes, "_rank"], kind="stable").drop(columns="_rank")
    return out.reset_index(drop=True)


# --------------------------------------------------------------------------------------
# formatting
# --------------------------------------------------------------------------------------


def _check_fmt(fmt: Any) -> str:
    if not isinstance(fmt, str) or fmt not in FORMATS:
        raise ValueError(f"fmt={fmt!r} is not a supported format; allowed values: "
                         + ", ".join(repr(f) for f in FORMATS))
    return fmt


def _fmt_number(value: Any, digits: int) -> str:
    if value is None or value is pd.NA:
        return "nan"
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        v = float(value)
        if not math.isfinite(v):
            return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
        if v == 0:
            return "0"
        if 1e-4 <= abs(v) < 10.0 ** max(digits, 7):
            return np.format_float_positional(v, precision=digits, unique=False,
                                              fractional=False, trim="-")
        return f"{v:.{digits - 1}e}"
    if isinstance(value, (tuple, list, np.ndarray)):
        return "(" + ", ".join(_fmt_number(v, digits) for v in value) + ")"
    return str(value)


def _cells(summary: pd.DataFrame) -> tuple[list[str], list[list[str]], list[bool]]:
    headers = [str(c) for c in summary.columns]
    metric = set(SUMMARY_COLUMNS)
    rows = [[_fmt_number(v, 4 if c in metric else 6) for c, v in zip(summary.columns, row)]
            for row in summary.itertuples(index=False, name=None)]
    numeric = [pd.api.types.is_numeric_dtype(summary[c]) and not pd.api.types.is_bool_dtype(summary[c])
               for c in summary.columns]
    return headers, rows, numeric


def format_table(summary: pd.DataFrame, fmt: str = "text") -> str:
    """Render a :func:`summarize` table (any DataFrame works) as a string.

    ``fmt``:

    * ``"text"``: aligned plain-text columns (numbers right-aligned, 4 significant digits
      for metrics, 6 for axis values);
    * ``"csv"``: ``DataFrame.to_csv`` without index, full precision;
    * ``"markdown"``: a GitHub pipe table (hand-written; ``tabulate`` is not needed), same
      number formatting as ``"text"``.

    Raises:
        ValueError: ``fmt`` is not one of :data:`FORMATS` (the message names ``fmt`` and
        the allowed values).
        TypeError: ``summary`` is not a DataFrame.
    """
    _check_fmt(fmt)
    if not isinstance(summary, pd.DataFrame):
        raise TypeError(f"summary must be a pandas DataFrame, got {type(summary).__name__}")
    if fmt == "csv":
        return summary.to_csv(index=False)
    headers, rows, numeric = _cells(summary)
    if fmt == "markdown":
        def esc(s: str) -> str:
            return s.replace("|", "\\|")

        lines = ["| " + " | ".join(esc(h) for h in headers) + " |",
                 "|" + "|".join("---:" if num else ":---" for num in numeric) + "|"]
        lines += ["| " + " | ".join(esc(c) for c in row) + " |" for row in rows]
        return "\n".join(lines) + "\n"
    widths = [max([len(h), *(len(r[i]) for r in rows)]) for i, h in enumerate(headers)]

    def line(cells: list[str]) -> str:
        return "  ".join(c.rjust(w) if num else c.ljust(w)
                         for c, w, num in zip(cells, widths, numeric)).rstrip()

    return "\n".join([line(headers), *(line(r) for r in rows)]) + "\n"


# --------------------------------------------------------------------------------------
# plots
# --------------------------------------------------------------------------------------


def _axis_label(axis: str) -> str:
    unit = AXIS_UNITS.get(axis)
    if unit is None and axis.endswith("_radius"):
        unit = "m"
    return f"{axis} [{unit}]" if unit and unit != "-" else axis


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


def _filter_color(name: Any, ordered: Sequence[Any]) -> str:
    name = str(name)
    if name in FILTER_ORDER:
        return _FILTER_COLORS[FILTER_ORDER.index(name)]
    extra = [str(f) for f in ordered if str(f) not in FILTER_ORDER]
    return _FILTER_COLORS[(len(FILTER_ORDER) + extra.index(name)) % len(_FILTER_COLORS)]


def _is_numeric(col: pd.Series) -> bool:
    return pd.api.types.is_numeric_dtype(col) and not pd.api.types.is_bool_dtype(col)


def _spans_decades(values: Iterable[float], decades: float = 2.0) -> bool:
    v = np.asarray([x for x in values if x is not None], dtype=float)
    v = v[np.isfinite(v)]
    return bool(v.size and np.all(v > 0) and v.max() / v.min() > 10.0**decades)


class _XAxis:
    """x positions of an axis' values: the values themselves (numeric axis) or 0, 1, ...
    (categorical axis, e.g. per-agent tuples), with log scale when numeric and spanning
    more than two decades."""

    def __init__(self, name: str, values: Sequence[Any]):
        self.name = name
        self.values = list(values)
        self.numeric = all(isinstance(v, (int, float, np.integer, np.floating))
                           and not isinstance(v, (bool, np.bool_)) for v in self.values)
        self.log = self.numeric and _spans_decades(self.values)
        self.pos = {v: (float(v) if self.numeric else float(i)) for i, v in enumerate(self.values)}

    def x(self, values: Iterable[Any]) -> np.ndarray:
        return np.asarray([self.pos[v] for v in values], dtype=float)

    def dodge(self, x: np.ndarray, i: int, m: int) -> np.ndarray:
        """Shift series ``i`` of ``m`` sideways so error bars do not overlap."""
        if m <= 1:
            return x
        k = i - (m - 1) / 2
        if not self.numeric:
            return x + 0.06 * k
        v = np.asarray(list(self.pos.values()))
        if self.log:
            return x * 10.0 ** (0.006 * k * np.log10(v.max() / v.min()))
        span = float(v.max() - v.min()) or max(abs(float(v.max())), 1.0)
        return x + 0.006 * k * span

    def style(self, ax) -> None:
        ax.set_xlabel(_axis_label(self.name))
        if self.log:
            ax.set_xscale("log")
        if not self.numeric:
            ax.set_xticks(list(self.pos.values()))
            ax.set_xticklabels([_fmt_number(v, 4) for v in self.values], rotation=30, ha="right")


def _new_figure(figsize: tuple[float, float]):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=100, layout="constrained")
    FigureCanvasAgg(fig)  # explicit Agg canvas: no pyplot, no global backend switch
    return fig


def _save(fig, path: Path) -> Path:
    fig.savefig(path, format="png")
    fig.clear()
    return path


def _n_text(summary: pd.DataFrame, col: str = "n") -> str:
    n = summary[col].to_numpy()
    if n.size == 0:
        return ""
    lo, hi = int(n.min()), int(n.max())
    return f"n = {lo} runs per point and filter" if lo == hi else f"n = {lo}–{hi} runs per point and filter"


def _pooled_text(axis: str | Sequence[str], axes: Sequence[str]) -> str:
    own = {axis} if isinstance(axis, str) else set(axis)
    others = [a for a in axes if a not in own]
    return f"; pooled over {', '.join(others)}" if others else ""


def _maybe_log_y(ax, values: Iterable[float]) -> None:
    if _spans_decades(values):
        ax.set_yscale("log")


def _line_plot(summary: pd.DataFrame, xa: _XAxis, y: str, lo: str, hi: str, *, path: Path,
               title: str, subtitle: str, ylabel: str, errorbars: bool, rate: bool) -> Path:
    fig = _new_figure((7.0, 4.6))
    ax = fig.add_subplot()
    filters = _ordered_filters(summary["filter"])
    for i, f in enumerate(filters):
        s = summary[summary["filter"] == f]
        s = s.assign(_x=xa.x(s[xa.name])).sort_values("_x")
        x = s["_x"].to_numpy()
        yv, lv, hv = (s[c].to_numpy(dtype=float) for c in (y, lo, hi))
        color = _filter_color(f, filters)
        if errorbars:
            xd = xa.dodge(x, i, len(filters))
            yerr = np.vstack([np.where(np.isfinite(lv), yv - lv, 0), np.where(np.isfinite(hv), hv - yv, 0)])
            ax.errorbar(xd, yv, yerr=np.clip(yerr, 0, None), marker="o", ms=4, capsize=3,
                        color=color, label=str(f))
        else:
            ax.plot(x, yv, marker="o", ms=4, color=color, label=str(f))
            ax.fill_between(x, lv, hv, color=color, alpha=0.18, linewidth=0)
    xa.style(ax)
    ax.set_ylabel(ylabel)
    if rate:
        top = np.nanmax(np.r_[summary[hi].to_numpy(dtype=float), summary[y].to_numpy(dtype=float), 0.0])
        top = min(1.05, max(0.05, 1.12 * top))
        ax.set_ylim(-0.02 * top, top)
    else:
        _maybe_log_y(ax, summary[y])
    ax.grid(True, alpha=0.3, which="both")
    ax.legend(title="filter", fontsize="small")
    ax.set_title(f"{title}\n{subtitle}", fontsize="medium")
    return _save(fig, path)


def _lambda2_plot(df: pd.DataFrame, xa: _XAxis, axes: Sequence[str], path: Path) -> Path:
    """λ2 and disconnected steps vs one axis, from one row per run (filter-independent)."""
    if {"point_id", "seed_index"} <= set(df.columns):
        runs = df.drop_duplicates(subset=["point_id", "seed_index"])
    elif "seed_index" in df.columns:
        runs = df.drop_duplicates(subset=["seed_index", *axes])
    else:
        runs = df[df["filter"] == _ordered_filters(df["filter"])[0]]
    rows = []
    for value, g in runs.groupby(xa.name, sort=False):
        m, lo, hi = mean_ci(_col(g, "lambda2_mean"))
        rows.append({"v": value, "x": xa.pos[value], "mean": m, "lo": lo, "hi": hi,
                     "min": _nan_stat(np.min, _col(g, "lambda2_min")),
                     "disc": _nan_stat(np.mean, _col(g, "disconnected_steps")), "n": len(g)})
    s = pd.DataFrame(rows).sort_values("x")
    fig = _new_figure((7.0, 5.6))
    ax1, ax2 = fig.subplots(2, 1, sharex=True, height_ratios=[2, 1])
    ax1.plot(s["x"], s["mean"], marker="o", ms=4, color="#1f77b4", label=r"mean over runs of mean $\lambda_2$")
    ax1.fill_between(s["x"], s["lo"], s["hi"], color="#1f77b4", alpha=0.2, linewidth=0,
                     label="95 % t-interval")
    ax1.plot(s["x"], s["min"], marker="v", ms=4, ls="--", color="#d62728", label=r"min over runs of min $\lambda_2$")
    ax1.axhline(0.0, color="0.4", lw=0.8)
    ax1.set_ylabel(r"$\lambda_2$ (algebraic connectivity)")
    ax1.grid(True, alpha=0.3, which="both")
    ax1.legend(fontsize="small")
    ax2.plot(s["x"], s["disc"], marker="o", ms=4, color="#7f7f7f")
    ax2.set_ylabel("mean disconnected\nsteps per run")
    ax2.grid(True, alpha=0.3, which="both")
    xa.style(ax2)
    if xa.log:
        ax1.set_xscale("log")
    n = s["n"].to_numpy()
    ntxt = f"n = {n.min()} runs per point" if n.min() == n.max() else f"n = {n.min()}–{n.max()} runs per point"
    ax1.set_title(f"Communication graph connectivity vs {xa.name}\n{ntxt}{_pooled_text(xa.name, axes)}",
                  fontsize="medium")
    return _save(fig, path)


def _heatmap(summary: pd.DataFrame, a: _XAxis, b: _XAxis, metric: str, *, path: Path,
             title: str, cbar_label: str, rate: bool, axes: Sequence[str]) -> Path:
    from matplotlib import colormaps
    from matplotlib.colors import LogNorm, Normalize

    filters = _ordered_filters(summary["filter"])
    m = len(filters)
    ncols = min(3, m)
    nrows = math.ceil(m / ncols)
    fig = _new_figure((3.6 * ncols + 1.2, 3.2 * nrows + 0.9))
    grid = np.atleast_1d(fig.subplots(nrows, ncols, squeeze=False)).ravel()
    ia = {v: i for i, v in enumerate(a.values)}
    ib = {v: i for i, v in enumerate(b.values)}
    vals = summary[metric].to_numpy(dtype=float)
    finite = vals[np.isfinite(vals)]
    if rate:
        norm = Normalize(0.0, 1.0)
        cmap = colormaps["Reds"].with_extremes(bad="0.85")
    else:
        lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
        norm = LogNorm(lo, hi) if _spans_decades(finite) else Normalize(lo, hi if hi > lo else lo + 1.0)
        cmap = colormaps["viridis"].with_extremes(bad="0.85")
    annotate = len(a.values) * len(b.values) <= 100
    image = None
    for ax, f in zip(grid, filters):
        mat = np.full((len(b.values), len(a.values)), np.nan)
        sf = summary[summary["filter"] == f]
        for va, vb, v in zip(sf[a.name], sf[b.name], sf[metric]):
            mat[ib[vb], ia[va]] = v
        image = ax.imshow(np.ma.masked_invalid(mat), origin="lower", aspect="auto", cmap=cmap,
                          norm=norm, interpolation="nearest")
        ax.set_xticks(range(len(a.values)))
        ax.set_xticklabels([_fmt_number(v, 4) for v in a.values], rotation=30, ha="right",
                           fontsize="small")
        ax.set_yticks(range(len(b.values)))
        ax.set_yticklabels([_fmt_number(v, 4) for v in b.values], fontsize="small")
        ax.set_xlabel(_axis_label(a.name), fontsize="small")
        ax.set_ylabel(_axis_label(b.name), fontsize="small")
        ax.set_title(str(f), fontsize="medium")
        if annotate:
            for (j, i), v in np.ndenumerate(mat):
                if np.isfinite(v):
                    shade = norm(v)
                    dark = (shade > 0.55) if rate else (shade < 0.5)
                    ax.text(i, j, _fmt_number(v, 2 if rate else 3), ha="center", va="center",
                            fontsize="x-small", color="white" if dark else "black")
                else:
                    ax.text(i, j, "–", ha="center", va="center", fontsize="x-small")
    for ax in grid[m:]:
        ax.set_visible(False)
    if image is not None:
        fig.colorbar(image, ax=list(grid[:m]), label=cbar_label, shrink=0.9)
    fig.suptitle(f"{title}\n{_n_text(summary)}{_pooled_text([a.name, b.name], axes)}",
                 fontsize="medium")
    return _save(fig, path)


def _bar_plot(summary: pd.DataFrame, path: Path) -> Path:
    from matplotlib.patches import Patch

    filters = _ordered_filters(summary["filter"])
    s = summary.set_index("filter").loc[filters]
    x = np.arange(len(filters))
    colors = [_filter_color(f, filters) for f in filters]
    fig = _new_figure((max(7.0, 1.6 * len(filters) + 3), 4.4))
    ax1, ax2 = fig.subplots(1, 2)

    def err(mean, lo, hi):
        mean, lo, hi = (np.asarray(v, dtype=float) for v in (mean, lo, hi))
        return np.clip(np.vstack([np.nan_to_num(mean - lo), np.nan_to_num(hi - mean)]), 0, None)

    w = 0.38
    ax1.bar(x - w / 2, s["rmse_mean"], w, yerr=err(s["rmse_mean"], s["rmse_ci_low"], s["rmse_ci_high"]),
            color=colors, capsize=3, label="all runs")
    ax1.bar(x + w / 2, s["rmse_ok_mean"], w,
            yerr=err(s["rmse_ok_mean"], s["rmse_ok_ci_low"], s["rmse_ok_ci_high"]),
            color=colors, alpha=0.5, hatch="//", edgecolor="0.3", capsize=3, label="non-divergent runs")
    _maybe_log_y(ax1, np.r_[s["rmse_mean"].to_numpy(dtype=float), s["rmse_ok_mean"].to_numpy(dtype=float)])
    ax1.set_xticks(x)
    ax1.set_xticklabels([str(f) for f in filters], rotation=20)
    ax1.set_ylabel("mean RMSE [m]")
    ax1.set_title("Mean RMSE (95 % t-interval)", fontsize="medium")
    ax1.legend(handles=[Patch(facecolor="0.45", label="all runs"),
                        Patch(facecolor="0.45", alpha=0.5, hatch="//", edgecolor="0.3",
                              label="non-divergent runs")], fontsize="small")
    ax1.grid(True, axis="y", alpha=0.3, which="both")
    ax2.bar(x, s["div_rate"], 0.6, yerr=err(s["div_rate"], s["div_ci_low"], s["div_ci_high"]),
            color=colors, capsize=3)
    top = min(1.05, max(0.05, 1.12 * float(np.nanmax(np.r_[s["div_ci_high"].to_numpy(dtype=float), 0.0]))))
    ax2.set_ylim(0, top)
    ax2.set_xticks(x)
    ax2.set_xticklabels([str(f) for f in filters], rotation=20)
    ax2.set_ylabel("divergence rate (fraction of runs)")
    ax2.set_title("Divergence rate (95 % Wilson interval)", fontsize="medium")
    ax2.grid(True, axis="y", alpha=0.3)
    fig.suptitle(f"Single sweep point: RMSE and divergence per filter\n{_n_text(summary)}",
                 fontsize="medium")
    return _save(fig, path)


def make_plots(df: pd.DataFrame, axes: str | Sequence[str] | None,
               out_dir: str | os.PathLike) -> list[Path]:
    """Write PNG plots of a runs table to ``out_dir/report/``; return their paths.

    Only axes with more than one distinct value are plotted ("plot axes").  For each plot
    axis ``A`` (numeric axes on a value scale, log scale when the values span more than
    two decades; list-valued axes as categories), one line per filter:

    * ``rmse_vs_<A>.png``: mean RMSE (runs with finite RMSE), shaded 95 % t-interval;
    * ``rmse_nondiverged_vs_<A>.png``: mean RMSE of the non-divergent runs, shaded 95 %
      t-interval;
    * ``divergence_vs_<A>.png``: divergence rate with 95 % Wilson interval error bars
      (series slightly dodged sideways so equal rates stay readable);
    * ``lambda2_vs_<A>.png`` (when ``lambda2_mean``/``lambda2_min`` exist): mean over runs
      of the per-run mean λ2 (95 % t-interval), minimum λ2 over runs, and the mean number
      of disconnected steps; computed once per run (the graph does not depend on the
      filter).

    When there are other plot axes, the runs at each value of ``A`` are **pooled** over
    them (every run counts once; the interval then also includes the spread between the
    pooled points); the heatmaps show the full grid.  For every pair ``(A, B)`` of plot
    axes (a two-axis grid gives one pair; more axes pool the rest), small multiples with
    one panel per filter and a shared colour scale:

    * ``heatmap_divergence_<A>__<B>.png``: divergence rate;
    * ``heatmap_rmse_<A>__<B>.png``: mean RMSE (log colour scale above two decades);
    * ``heatmap_rmse_nondiverged_<A>__<B>.png``: mean RMSE of the non-divergent runs.

    With no plot axis (a single point): ``summary_bars.png``, bars per filter of mean RMSE
    (all and non-divergent runs, 95 % t-intervals) and divergence rate (Wilson interval).

    Figures are :class:`matplotlib.figure.Figure` objects drawn on an Agg canvas created
    here; pyplot is never used, so no global state (backend, open figures) changes.
    """
    axes = _axes_list(axes)
    _check_columns(df, [*axes, *_REQUIRED], "make_plots")
    if df.empty:
        raise ValueError("make_plots: the runs table is empty")
    try:
        import matplotlib  # noqa: F401
    except ImportError as exc:  # pragma: no cover - matplotlib is optional
        raise ImportError("make_plots needs matplotlib (pip install matplotlib)") from exc
    report_dir = Path(out_dir) / "report"
    report_dir.mkdir(parents=True, exist_ok=True)
    data = _prepare(df, axes)
    xaxes: dict[str, _XAxis] = {}
    for a in axes:
        values = list(pd.unique(data[a]))
        if len(values) > 1:
            try:
                values = sorted(values)
            except TypeError:
                pass
            xaxes[a] = _XAxis(a, values)
    paths: list[Path] = []
    if not xaxes:
        paths.append(_bar_plot(summarize(data, []), report_dir / "summary_bars.png"))
        return paths
    for name, xa in xaxes.items():
        s = summarize(data, [name])
        tag = _safe(name)
        sub = f"{_n_text(s)}{_pooled_text(name, list(xaxes))}"
        paths.append(_line_plot(
            s, xa, "rmse_mean", "rmse_ci_low", "rmse_ci_high", path=report_dir / f"rmse_vs_{tag}.png",
            title=f"Mean RMSE vs {name} (shaded: 95 % t-interval)", subtitle=sub,
            ylabel="mean RMSE [m]", errorbars=False, rate=False))
        paths.append(_line_plot(
            s, xa, "rmse_ok_mean", "rmse_ok_ci_low", "rmse_ok_ci_high",
            path=report_dir / f"rmse_nondiverged_vs_{tag}.png",
            title=f"Mean RMSE of non-divergent runs vs {name} (shaded: 95 % t-interval)",
            subtitle=sub, ylabel="mean RMSE, non-divergent runs [m]", errorbars=False, rate=False))
        paths.append(_line_plot(
            s, xa, "div_rate", "div_ci_low", "div_ci_high", path=report_dir / f"divergence_vs_{tag}.png",
            title=f"Divergence rate vs {name} (bars: 95 % Wilson interval)", subtitle=sub,
            ylabel="divergence rate (fraction of runs)", errorbars=True, rate=True))
        if "lambda2_mean" in data.columns or "lambda2_min" in data.columns:
            paths.append(_lambda2_plot(data, xa, list(xaxes), report_dir / f"lambda2_vs_{tag}.png"))
    for (na, a), (nb, b) in itertools.combinations(xaxes.items(), 2):
        s = summarize(data, [na, nb])
        tag = f"{_safe(na)}__{_safe(nb)}"
        paths.append(_heatmap(s, a, b, "div_rate", path=report_dir / f"heatmap_divergence_{tag}.png",
                              title=f"Divergence rate over {na} × {nb}", cbar_label="divergence rate",
                              rate=True, axes=list(xaxes)))
        paths.append(_heatmap(s, a, b, "rmse_mean", path=report_dir / f"heatmap_rmse_{tag}.png",
                              title=f"Mean RMSE over {na} × {nb}", cbar_label="mean RMSE [m]",
                              rate=False, axes=list(xaxes)))
        paths.append(_heatmap(s, a, b, "rmse_ok_mean",
                              path=report_dir / f"heatmap_rmse_nondiverged_{tag}.png",
                              title=f"Mean RMSE of non-divergent runs over {na} × {nb}",
                              cbar_label="mean RMSE, non-divergent runs [m]", rate=False,
                              axes=list(xaxes)))
    return paths


# --------------------------------------------------------------------------------------
# entry point
# --------------------------------------------------------------------------------------


def report(out_dir: str | os.PathLike, fmt: str = "text", *,
           plots: bool = True) -> tuple[str, list[Path]]:
    """Summarise a sweep's output folder: ``(formatted table, plot paths)``.

    Reads ``OUT/runs`` (:func:`mcjax.results.read_table`), takes the swept axes from the
    metadata (:func:`swept_axes`), summarises (:func:`summarize`), formats
    (:func:`format_table` with ``fmt``) and, unless ``plots=False``, writes the plots of
    :func:`make_plots` to ``OUT/report/``.

    Raises:
        ValueError: ``fmt`` is not one of :data:`FORMATS`, or ``out_dir`` holds no runs
        (the message names the folder).
    """
    _check_fmt(fmt)
    if not isinstance(out_dir, (str, os.PathLike)) or str(out_dir) == "":
        raise TypeError(f"out_dir must be a non-empty str or os.PathLike, got {out_dir!r}")
    out = Path(out_dir)
    df = results.read_table(out)
    if df.empty:
        raise ValueError(f"no runs found in {str(out)!r}: expected Parquet part files in "
                         f"{str(out / 'runs')!r} (is this the output folder of `mcjax sweep`?)")
    axes = swept_axes(results.read_metadata(out), df.columns)
    table = format_table(summarize(df, axes), fmt)
    paths = make_plots(df, axes, out) if plots else []
    return table, paths
