"""The verdict of every claim of a claims file from its sweeps' runs: each side's statistic with
its 95 % interval (:mod:`mcjax.claims.verdicts`) and the claim's relation judged on them, as one row per
claim (:data:`COLUMNS`) — the table ``claims.parquet`` holds.

The file's claims are one family, and each row also holds the claim's verdict at a family-wise
error of 5 % (:data:`FAMILY_COLUMNS`): every claim stands for one-sided tests ("holds": its
claimed side against the rest; "fails": the other), counted as many as can be wrong at once
(:func:`decision`); Holm's step-down over them (:func:`mcjax.analysis.statistics.holm`, Holm
1979) gives each claim a one-sided level ``a``, and the claim is judged as before on its
intervals of confidence ``1 − 2a`` — the interval and the verdict agree, and the runs that would
decide an undecided claim are those at that level. ``family = "bonferroni"``: every claim at the
first step's level (simultaneous intervals). A file of one claim: the 95 % verdict.

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
from typing import Mapping, NamedTuple

import numpy as np
import pandas as pd

from mcjax.analysis.statistics import CONFIDENCE, FAMILY_ERROR, holm
from mcjax.claims import verdicts
from mcjax.claims.spec import FAMILIES, Claim, ClaimsFile, Side
from mcjax.claims.verdicts import Estimate, Verdict

#: The columns of the family-wise verdict: the verdict and the runs that would decide it at the
#: claim's level, ours with the intervals of that level (``family_low``, ``family_high``: a claim of
#: one statistic), their ``family_confidence``, the Holm-adjusted p-value (``family_p``: the least
#: family-wise error at which the claim is decided), the method, the file's claims and tests.
FAMILY_COLUMNS = ("family_verdict", "family_runs_to_decide", "family_ours", "family_low", "family_high",
                  "family_confidence", "family_p", "family", "family_claims", "family_tests")
#: The columns of the verdict table, in order: each claim at its own 95 % (``verdict``,
#: ``runs_to_decide``, ``ours``, ``low``, ``high``), then at the family's level.
COLUMNS = ("id", "claim", "where", "paper", "ours", "verdict", "runs_to_decide", "statistic", "relation",
           "value", "low", "high", "runs", "sweeps", "estimates", *FAMILY_COLUMNS)
#: What a replication adds (:func:`replication`): each range's verdict at the family's level and
#: alone, and whether they are all the same.
REPLICATE_COLUMNS = ("range_verdicts", "replicates", "range_verdicts_per_claim", "replicates_per_claim")


class Runs:
    """A check's rows (sweep name → DataFrame) with each side's values read once."""

    def __init__(self, rows: Mapping[str, pd.DataFrame]):
        self.rows, self._seen = rows, {}

    def values(self, side: Side) -> tuple[np.ndarray, np.ndarray]:
        key = (side.sweep, side.point_id, side.filter, side.output, side.statistic == "rate", side.over, side.under)
        if key not in self._seen:
            self._seen[key] = side_values(side, self.rows[side.sweep])
        return self._seen[key]


def _runs(rows) -> Runs:
    return rows if isinstance(rows, Runs) else Runs(rows)


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


def side_estimate(side: Side, rows: Mapping[str, pd.DataFrame] | Runs, confidence: float = CONFIDENCE) -> Estimate:
    """The side's statistic with its interval; a difference paired by seed when it has ``minus``."""
    runs = _runs(rows)
    x, seeds = runs.values(side)
    if side.minus is not None:
        y, seeds_b = runs.values(side.minus)
        return verdicts.paired(x, y, seeds, seeds_b, confidence)
    return verdicts.estimate(x, side.statistic, q=side.q, confidence=confidence)


def side_tails(side: Side, runs: Runs, value: float) -> tuple[float, float]:
    """The side's one-sided p-values against ``value`` (:func:`mcjax.claims.verdicts.tails`)."""
    x, seeds = runs.values(side)
    if side.minus is not None:
        y, seeds_b = runs.values(side.minus)
        return verdicts.tails(verdicts.differences(x, y, seeds, seeds_b), "mean", value)
    return verdicts.tails(x, side.statistic, value, q=side.q)


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


def judge(claim: Claim, rows: Mapping[str, pd.DataFrame] | Runs,
          confidence: float = CONFIDENCE) -> tuple[Verdict, list[Estimate]]:
    """The claim's verdict and the estimates it was judged on (the claim's own side first), every
    interval of ``confidence``."""
    r, runs, c = claim.relation, _runs(rows), confidence
    if r in ("ordered", "monotone"):
        ests = [side_estimate(s, runs, c) for s in claim.others]
        return verdicts.ordered(ests, decreasing=claim.direction == "decreasing"), ests
    est = side_estimate(claim.side, runs, c)
    if r in ("below", "above") and claim.others:
        other = side_estimate(claim.others[0], runs, c)
        return verdicts.ordered([est, other], decreasing=r == "above"), [est, other]
    if r in ("below", "above"):
        return verdicts.compare(est, r, claim.value, confidence=c), [est]
    if r in ("within", "equal"):
        return verdicts.compare(est, "within", band=claim.band, confidence=c), [est]
    return verdicts.consistent(est, float(claim.paper), claim.paper_runs, c), [est]


class Decision(NamedTuple):
    """Where a claim stands in its family: ``level``, the smallest one-sided level at which its
    intervals decide it (1.0: at none); ``tests``, the one-sided tests the claim counts for in
    Holm's procedure (:func:`decision`); ``weight``, how many of them its decision takes off."""

    level: float
    weight: int
    tests: int


def _apart(runs: Runs, low_side: Side, high_side: Side) -> float:
    """The smallest one-sided level at which ``low_side``'s interval lies below ``high_side``'s."""
    a, b = side_estimate(low_side, runs), side_estimate(high_side, runs)
    if not a.value < b.value:  # the point estimates in the other order: apart at no level
        return 1.0

    def apart(level: float) -> bool:
        return side_estimate(low_side, runs, 1 - 2 * level).high < side_estimate(high_side, runs, 1 - 2 * level).low

    return verdicts.first_level(apart)


def decision(claim: Claim, rows: Mapping[str, pd.DataFrame] | Runs) -> Decision:
    """The claim's :class:`Decision`: its one-sided tests, counted as many as can be wrong at once
    (their true null hypotheses; Shaffer 1986's logical constraints on Holm's count), and how many
    of them a decision leaves. A claim on one statistic: ``below`` / ``above`` is two tests of
    weight 1 (holds: the claimed side; fails: the other), both wrong only on the boundary, one once
    decided; ``within`` / ``equal`` is three — holds (both ends inside the band: the intersection of
    two one-sided tests), fails above, fails below — of which two at most are wrong at once, and
    two may still be after a decision. Their p-values are those of the test the interval inverts
    (:func:`side_tails`). A claim on k statistics (``than``, ``ordered``, ``monotone``) rests on 2k
    interval ends: its holds (every neighbouring pair apart in order) and each pair's fails are
    tests of weight 2 (apart intervals are wrong only if one of two ends misses), all wrong at once
    when the k are equal. ``consistent`` is one two-sided test (weight 2); its holds is no test (the
    paper's number not shown to differ)."""
    r, runs = claim.relation, _runs(rows)
    if r in ("below", "above") and not claim.others:
        return Decision(min(side_tails(claim.side, runs, claim.value)), 1, 2)
    if r in ("within", "equal"):
        lo_below, lo_above = side_tails(claim.side, runs, claim.band[0])
        hi_below, hi_above = side_tails(claim.side, runs, claim.band[1])
        return Decision(min(max(lo_above, hi_below), hi_above, lo_below), 0, 2)
    if r == "consistent":
        def fails(level: float) -> bool:
            c = 1 - 2 * level
            est = side_estimate(claim.side, runs, c)
            return verdicts.consistent(est, float(claim.paper), claim.paper_runs, c).verdict == "fails"

        return Decision(verdicts.first_level(fails), 2, 2)
    sides = list(claim.others) if r in ("ordered", "monotone") else [claim.side, claim.others[0]]
    if (r == "above") if r in ("below", "above") else claim.direction == "decreasing":
        sides = sides[::-1]  # in increasing order
    pairs = list(zip(sides, sides[1:]))
    holds = max(_apart(runs, a, b) for a, b in pairs)
    fails = min(_apart(runs, b, a) for a, b in pairs)
    return Decision(min(holds, fails), 2, 2 * len(sides))


def _ours(claim: Claim, ests: list[Estimate]) -> str:
    if claim.relation in ("ordered", "monotone"):
        sign = "  <  " if claim.direction == "increasing" else "  >  "
        if claim.relation == "monotone":
            return sign.join(f"{claim.along} = {json.dumps(s.at[claim.along])}: {fmt_estimate(e)}"
                             for s, e in zip(claim.others, ests))
        return sign.join(fmt_estimate(e) for e in ests)
    return fmt_estimate(ests[0]) if len(ests) == 1 else f"{fmt_estimate(ests[0])} vs {fmt_estimate(ests[1])}"


def claim_row(claim: Claim, rows: Mapping[str, pd.DataFrame] | Runs) -> dict:
    """One row of the verdict table, the claim alone (:data:`COLUMNS` but the family's)."""
    verdict, ests = judge(claim, rows)
    own = ests[0]
    ours = _ours(claim, ests)
    statistic = describe_side(claim.others[0] if claim.relation in ("ordered", "monotone") else claim.side)
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


def family_rows(claims: tuple, rows: Mapping[str, pd.DataFrame] | Runs, method: str = "holm") -> list[dict]:
    """Each claim's family columns (:data:`FAMILY_COLUMNS`), the ``claims`` one family held to
    :data:`FAMILY_ERROR` by ``method`` (:data:`mcjax.claims.spec.FAMILIES`; module docstring)."""
    if method not in FAMILIES:
        raise ValueError(f"family must be one of {', '.join(FAMILIES)}; got {method!r}")
    runs = _runs(rows)
    found = [decision(c, runs) for c in claims]
    h = holm([d.level for d in found], [d.weight for d in found], [d.tests for d in found], FAMILY_ERROR,
             step_down=method == "holm")
    out = []
    for claim, level, adjusted in zip(claims, h.level, h.adjusted):
        confidence = 1 - 2 * float(level)
        verdict, ests = judge(claim, runs, confidence)
        single = len(ests) == 1
        out.append({"family_verdict": verdict.verdict,
                    "family_runs_to_decide": -1 if verdict.runs_to_decide is None else int(verdict.runs_to_decide),
                    "family_ours": _ours(claim, ests), "family_low": ests[0].low if single else math.nan,
                    "family_high": ests[0].high if single else math.nan, "family_confidence": confidence,
                    "family_p": float(adjusted), "family": method, "family_claims": len(claims),
                    "family_tests": int(h.tests)})
    return out


def verdict_table(claims: ClaimsFile, rows: Mapping[str, pd.DataFrame], family: str | None = None) -> pd.DataFrame:
    """Every claim's row (:data:`COLUMNS`), in the file's order; ``family``: the method (default:
    the file's ``family``, else Holm's)."""
    runs = Runs(rows)
    own = [claim_row(c, runs) for c in claims.claims]
    fam = family_rows(claims.claims, runs, family or claims.family or "holm")
    return pd.DataFrame([{**a, **b} for a, b in zip(own, fam)], columns=list(COLUMNS))


def replication(tables: list[pd.DataFrame]) -> pd.DataFrame:
    """The first range's verdict table with :data:`REPLICATE_COLUMNS`: each range's verdict (its
    family's, and alone), in range order, and whether they are all the same."""
    out = tables[0].copy()
    for column, suffix in (("family_verdict", ""), ("verdict", "_per_claim")):
        each = list(zip(*(t[column].tolist() for t in tables)))
        out[f"range_verdicts{suffix}"] = [", ".join(v) for v in each]
        out[f"replicates{suffix}"] = [len(set(v)) == 1 for v in each]
    return out[[*COLUMNS, *REPLICATE_COLUMNS]]


def needed_columns(claims: ClaimsFile) -> dict[str, list[str]]:
    """Per sweep, the columns its claims read (keys, axes and outputs)."""
    need: dict[str, set] = {}
    for c in claims.claims:
        sides = [c.side, *c.others] + ([c.side.minus] if c.side.minus else [])
        for s in sides:
            need.setdefault(s.sweep, set()).add(s.output)
    return {name: ["point_id", "seed_index", "filter", *study.axes, *sorted(need.get(name, ()))]
            for name, study in claims.sweeps.items()}
