"""The verdict of every claim of a claims file from its sweeps' runs: each side's statistic with
its 95 % interval (:mod:`mcjax.claims.verdicts`) and the claim's relation judged on them, as one row per
claim (:data:`COLUMNS`) — the table ``claims.parquet`` holds.

A side's runs are its sweep's rows at its point and filter, ordered by seed. A ``rate`` counts a
flag output's non-zero values, or ``output > over`` (a non-finite value counts: it is above any
bound) or ``output < under``; ``mean``, ``median`` and ``quantile`` take the finite values (the
runs they leave out show in ``runs``). A difference (``minus``) is matched seed by seed
(:func:`mcjax.claims.verdicts.paired`, which refuses sides whose seeds differ). Nothing pools points:
every estimate is of one design point, or of one pairing.

Pure functions of tables; no JAX.
"""

from __future__ import annotations

import json
import math
from typing import Mapping

import numpy as np
import pandas as pd

from mcjax.claims import verdicts
from mcjax.claims.spec import Claim, ClaimsFile, Side
from mcjax.claims.verdicts import Estimate, Verdict

#: The columns of the verdict table, in order.
COLUMNS = ("id", "claim", "where", "paper", "ours", "verdict", "runs_to_decide", "statistic", "relation",
           "value", "low", "high", "runs", "sweeps", "estimates")


def side_values(side: Side, rows: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """The side's per-run values (flags as 0/1 for a rate) and their seeds, ordered by seed."""
    sel = rows[(rows["point_id"] == side.point_id) & (rows["filter"] == side.filter)].sort_values("seed_index")
    x = sel[side.output].to_numpy(dtype=np.float64)
    if side.statistic == "rate":
        if side.over is not None:
            x = np.where(np.isfinite(x), x > side.over, True)
        elif side.under is not None:
            x = np.isfinite(x) & (x < side.under)
        else:
            x = np.nan_to_num(x, nan=1.0) != 0
        x = x.astype(np.float64)
    return x, sel["seed_index"].to_numpy()


def side_estimate(side: Side, rows: Mapping[str, pd.DataFrame]) -> Estimate:
    """The side's statistic with its interval; a difference paired by seed when it has ``minus``."""
    x, seeds = side_values(side, rows[side.sweep])
    if side.minus is not None:
        y, seeds_b = side_values(side.minus, rows[side.minus.sweep])
        return verdicts.paired(x, y, seeds, seeds_b)
    return verdicts.estimate(x, side.statistic, q=side.q)


def _at(at: dict) -> str:
    return ", ".join(f"{k} = {json.dumps(v)}" for k, v in at.items())


def describe_side(side: Side) -> str:
    """The side in words: ``rate of diverged > 1000 (my_filter; alpha_I = 0)``."""
    what = f"{side.q:g}-quantile" if side.statistic == "quantile" else side.statistic
    bound = f" > {side.over:g}" if side.over is not None else f" < {side.under:g}" if side.under is not None else ""
    where = "; ".join(x for x in (side.filter, _at(side.at)) if x)
    text = f"{what} of {side.output}{bound}" + (f" ({where})" if where else "")
    if side.minus is not None:
        other = "; ".join(x for x in (f"sweep {side.minus.sweep}" if side.minus.sweep != side.sweep else "",
                                      side.minus.output if side.minus.output != side.output else "",
                                      side.minus.filter if side.minus.filter != side.filter else "",
                                      _at(side.minus.at) if side.minus.at != side.at else "") if x)
        text += f" minus the same ({other or 'same point'}), paired by seed"
    return text


def _fmt(v: float) -> str:
    if not math.isfinite(v):
        return "–"
    return f"{v:.3g}" if abs(v) >= 1e-3 or v == 0 else f"{v:.2e}"


def fmt_estimate(est: Estimate) -> str:
    """``value [low, high]`` (3 significant digits)."""
    return f"{_fmt(est.value)} [{_fmt(est.low)}, {_fmt(est.high)}]"


def _relation_text(claim: Claim) -> str:
    r = claim.relation
    if r in ("below", "above"):
        return f"{r} {_fmt(claim.value)}" if not claim.others else f"{r} {describe_side(claim.others[0])}"
    if r == "within":
        return f"within [{_fmt(claim.band[0])}, {_fmt(claim.band[1])}]"
    if r == "equal":
        return f"equal to {_fmt(claim.value)} ± {_fmt(claim.band[1] - claim.value)}"
    if r == "ordered":
        return f"{claim.direction} in the order " + " ; ".join(describe_side(s) for s in claim.others)
    if r == "monotone":
        return f"{claim.direction} along {claim.along}"
    return f"consistent with the paper's {_fmt(float(claim.paper))} from {claim.paper_runs} runs"


def judge(claim: Claim, rows: Mapping[str, pd.DataFrame]) -> tuple[Verdict, list[Estimate]]:
    """The claim's verdict and the estimates it was judged on (the claim's own side first)."""
    r = claim.relation
    if r in ("ordered", "monotone"):
        ests = [side_estimate(s, rows) for s in claim.others]
        return verdicts.ordered(ests, decreasing=claim.direction == "decreasing"), ests
    est = side_estimate(claim.side, rows)
    if r in ("below", "above") and claim.others:
        other = side_estimate(claim.others[0], rows)
        return verdicts.ordered([est, other], decreasing=r == "above"), [est, other]
    if r in ("below", "above"):
        return verdicts.compare(est, r, claim.value), [est]
    if r in ("within", "equal"):
        return verdicts.compare(est, "within", band=claim.band), [est]
    return verdicts.consistent(est, float(claim.paper), claim.paper_runs), [est]


def claim_row(claim: Claim, rows: Mapping[str, pd.DataFrame]) -> dict:
    """One row of the verdict table (:data:`COLUMNS`)."""
    verdict, ests = judge(claim, rows)
    own = ests[0]
    if claim.relation in ("ordered", "monotone"):
        sign = "  <  " if claim.direction == "increasing" else "  >  "
        if claim.relation == "monotone":
            ours = sign.join(f"{claim.along} = {json.dumps(s.at[claim.along])}: {fmt_estimate(e)}"
                             for s, e in zip(claim.others, ests))
        else:
            ours = sign.join(fmt_estimate(e) for e in ests)
        statistic = describe_side(claim.others[0])
    else:
        ours = fmt_estimate(own) if len(ests) == 1 else f"{fmt_estimate(own)} vs {fmt_estimate(ests[1])}"
        statistic = describe_side(claim.side)
    single = len(ests) == 1
    sweeps = sorted({claim.side.sweep, *(s.sweep for s in claim.others)}
                    | ({claim.side.minus.sweep} if claim.side.minus else set()))
    return {
        "id": claim.id, "claim": claim.text, "where": claim.where,
        "paper": "" if claim.paper is None else (claim.paper if isinstance(claim.paper, str) else _fmt(claim.paper)),
        "ours": ours, "verdict": verdict.verdict,
        "runs_to_decide": -1 if verdict.runs_to_decide is None else int(verdict.runs_to_decide),
        "statistic": statistic, "relation": _relation_text(claim),
        "value": own.value if single else math.nan, "low": own.low if single else math.nan,
        "high": own.high if single else math.nan, "runs": int(min(e.n for e in ests)),
        "sweeps": ", ".join(sweeps),
        "estimates": json.dumps([e._asdict() for e in ests], default=float),
    }


def verdict_table(claims: ClaimsFile, rows: Mapping[str, pd.DataFrame]) -> pd.DataFrame:
    """Every claim's row (:data:`COLUMNS`), in the file's order."""
    return pd.DataFrame([claim_row(c, rows) for c in claims.claims], columns=list(COLUMNS))


def needed_columns(claims: ClaimsFile) -> dict[str, list[str]]:
    """Per sweep, the columns its claims read (keys, axes and outputs)."""
    need: dict[str, set] = {}
    for c in claims.claims:
        sides = [c.side, *c.others] + ([c.side.minus] if c.side.minus else [])
        for s in sides:
            need.setdefault(s.sweep, set()).add(s.output)
    return {name: ["point_id", "seed_index", "filter", *study.axes, *sorted(need.get(name, ()))]
            for name, study in claims.sweeps.items()}
