"""A claims file (TOML) read and checked against the sweeps it names, before anything runs.

A claims file holds a paper's name, the sweeps its claims need and the claims::

    paper = "Sun, Zhou, Zou & Ding 2011"
    seeds = 1000                             # runs per point of every sweep (--seeds overrides)

    [sweeps.table1]                          # a sweep spec file (relative to this file) ...
    spec = "../../sweeps/sun2011_table1.toml"

    [sweeps.cem]                             # ... or a sweep written inline: a spec's keys
    base = "../../configs/sun2011.toml"
    config = { planner = "cem" }
    grid = { alpha_I = [0.0, 1000.0] }

    [[claim]]
    id = "case2-diverges-less"
    claim = "weighting the connectivity robustness makes my filter diverge less often"
    where = "Table 1"
    paper = "0 of 20 vs 16 of 20"
    sweep = "table1"                         # optional when the file has one sweep
    output = "diverged"
    filter = "my_filter"
    at = { alpha_I = 1000.0 }                # the design point (axes left out: free if one value)
    statistic = "rate"
    minus = { at = { alpha_I = 0.0 } }       # a difference paired by seed with another side
    relation = "below"
    value = 0.0

A *side* is one statistic of one output, filter and point: ``statistic`` is ``mean``,
``median``, ``quantile`` (with ``q``) or ``rate`` (of a flag output, or of ``output > over`` /
``output < under``); ``minus`` (a table of side keys over the claim's own) makes it the mean
difference of the two sides paired by seed. Relations (:data:`RELATIONS`):

* ``below`` / ``above`` a ``value``, or ``than`` another side (side keys over the claim's own;
  judged by the two intervals lying apart);
* ``within`` a ``band = [low, high]``; ``equal`` to a ``value`` within ``tolerance``;
* ``ordered``: the sides of ``order`` (each a table of side keys over the claim's own),
  ``direction = "increasing"`` (default) or ``"decreasing"``;
* ``monotone`` along a swept axis (``along``; ``direction``);
* ``consistent``: the paper's number (``paper``, from ``paper_runs`` runs) is one its runs could
  give if ours were the truth (:func:`mcjax.claims.verdicts.consistent`).

The file's claims are one family: ``family = "holm"`` (the default) or ``"bonferroni"`` fixes,
before the runs, how their verdicts are held to a family-wise error of 5 %
(:mod:`mcjax.claims.evaluate`). :func:`load_claims` can run every sweep from another base seed
(``base_seed``, as if each sweep's table said so; ``shift``: added to each sweep's base seed: a
replication's seed range, :mod:`mcjax.claims.runner`).

Every problem is a :class:`ClaimsError` of one line naming the claim and the field.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from mcjax.base.validation import SpecError, check_keys, got, key_text, read_toml, show, suggest
from mcjax.claims.verdicts import STATISTICS
from mcjax.study.plan import Study
from mcjax.study.rows import shown_filters
from mcjax.study.spec import MAX_BASE_SEED, MAX_SEEDS, build_spec, is_config_file
from mcjax.study.sweep_tables import load_checked, named_tables

RELATIONS = ("below", "above", "within", "equal", "ordered", "monotone", "consistent")
DIRECTIONS = ("increasing", "decreasing")
FILE_KEYS = ("paper", "title", "description", "seeds", "family", "sweeps", "claim")
#: How a file's claims are held to a family-wise error (``family``; :mod:`mcjax.claims.evaluate`).
FAMILIES = ("holm", "bonferroni")
SIDE_KEYS = ("sweep", "output", "filter", "at", "statistic", "q", "over", "under")
CLAIM_KEYS = ("id", "claim", "where", "paper", "paper_runs", *SIDE_KEYS, "minus", "relation", "value", "band",
              "tolerance", "than", "order", "along", "direction")
SPEC_TABLE_KEYS = ("spec", "description", "base", "scenario", "seeds", "base_seed", "chunk_size", "timeseries",
                   "config", "params", "grid", "zip", "sensitivity")
ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


class ClaimsError(SpecError):
    """A claims file is invalid; the message (one line) names the claim and the field."""


class Side(NamedTuple):
    """One statistic: ``statistic`` of ``output`` for ``filter`` at the sweep's point ``point_id``
    (``q`` the quantile's level; ``over`` / ``under`` make a rate of ``output > over`` /
    ``output < under``); ``minus``: the other side of a difference paired by seed."""

    sweep: str
    output: str
    filter: str
    point_id: int
    at: dict
    statistic: str
    q: float | None = None
    over: float | None = None
    under: float | None = None
    minus: "Side | None" = None


class Claim(NamedTuple):
    """One claim: its text, the paper's figure, its ``side`` and the ``relation`` with its
    operands (``others``: the sides of ``than`` / ``order`` / ``monotone``, in order)."""

    id: str
    text: str
    where: str
    paper: Any
    paper_runs: int | None
    side: Side
    relation: str
    value: float | None = None
    band: tuple[float, float] | None = None
    others: tuple[Side, ...] = ()
    direction: str = "increasing"
    along: str | None = None


class ClaimsFile(NamedTuple):
    """A checked claims file: its ``path``, ``paper``, ``title``, the ``sweeps`` (name → Study,
    with the spec file each came from in ``spec_files``, None when inline), the ``claims`` and the
    file's tables as read (``source``: what ``--resume`` compares); its ``family`` method (None
    when the file names none: ``"holm"`` then) and what :func:`load_claims` was given (``seeds``,
    ``base_seed``, ``shift``: to read it again for another seed range)."""

    path: Path
    paper: str
    title: str
    sweeps: dict
    spec_files: dict
    claims: tuple
    source: dict
    family: str | None = None
    seeds: int | None = None
    base_seed: int | None = None
    shift: int = 0


def _err(where: str, text: str) -> ClaimsError:
    return ClaimsError(f"{where}: {text}")


def _text(where: str, data: dict, key: str, required: bool = False) -> str:
    if key not in data:
        if required:
            raise _err(f"{where}{key}", "missing")
        return ""
    if not isinstance(data[key], str) or not data[key].strip():
        raise _err(f"{where}{key}", f"must be a non-empty string; got {show(data[key])}")
    return data[key]


def _number(where: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise _err(where, f"must be a finite number; got {got(value)}")
    return float(value)


def _reseeded(table: dict, base_seed: int | None, shift: int) -> dict:
    """A sweep's table with ``base_seed`` (the sweep's own when None) plus ``shift`` written in,
    as a hand-edited copy would hold it (left as it is when neither changes it)."""
    if base_seed is None and not shift:
        return table
    own = table.get("base_seed", 0) if base_seed is None else base_seed
    return {**table, "base_seed": own + shift if isinstance(own, int) and not isinstance(own, bool) else own}


def _sweeps(path: Path, data: dict, seeds: int | None, base_seed: int | None = None,
            shift: int = 0) -> tuple[dict, dict]:
    studies, files = {}, {}
    for name, where, table in named_tables(
            f"{path.name}: sweeps", data.get("sweeps"), SPEC_TABLE_KEYS, ClaimsError,
            missing="must name at least one sweep ([sweeps.NAME] with spec = FILE, or a sweep spec's keys)",
            bad_name="a sweep's name must be letters, digits, '_', '-' or '.' (it names its output folder)",
            table="a table (spec = FILE, or a sweep spec's keys)"):
        try:
            if "spec" in table:
                if set(table) - {"spec"}:
                    raise SpecError(f"must hold spec alone, or a sweep spec's keys inline; got {', '.join(table)}")
                if not isinstance(table["spec"], str):
                    raise SpecError(f"spec: must be the path of a sweep spec file; got {got(table['spec'])}")
                spec_file = (path.parent / table["spec"]).resolve()
                spec = read_toml(spec_file, "sweep spec")
                if is_config_file(spec):
                    raise SpecError(f"spec: {table['spec']} is a config file, not a sweep spec")
                studies[name] = build_spec(_reseeded(spec, base_seed, shift), spec_file.parent, seeds=seeds)
                files[name] = spec_file
            else:
                studies[name] = build_spec(_reseeded(table, base_seed, shift), path.parent, seeds=seeds)
                files[name] = None
        except ClaimsError:
            raise
        except SpecError as exc:
            raise _err(where, str(exc)) from None
    return studies, files


def _point(where: str, study: Study, at: Any, free: str | None = None) -> tuple[int | list[int], dict]:
    """The point ``at`` selects in ``study`` (every point along ``free``, in the axis's order)."""
    if not isinstance(at, dict):
        raise _err(f"{where}at", f"must be a table of swept axes and values; got {show(at)}")
    points = study.points
    keep = np.ones(len(points), bool)
    for axis, value in at.items():
        if axis not in study.axes:
            raise _err(f"{where}at.{key_text(axis)}", f"is not swept by the sweep{suggest(axis, study.axes)}; "
                       f"its axes: {', '.join(study.axes) or 'none (one point)'}")
        if axis == free:
            raise _err(f"{where}at.{key_text(axis)}", "must not pin the axis the claim is monotone along")
        col = points[axis].tolist()
        try:
            want = np.asarray(value, float)
        except (TypeError, ValueError):  # not a number (or a list of numbers): no point has it
            want = None
        hit = np.array([want is not None and np.shape(v) == want.shape and np.allclose(np.asarray(v, float), want)
                        for v in col])
        if not hit.any():
            values = list(dict.fromkeys(json.dumps(np.asarray(v).tolist()) for v in col))
            raise _err(f"{where}at.{key_text(axis)}", f"must be one of the sweep's values {', '.join(values)}; "
                       f"got {got(value)}")
        keep &= hit
    ids = points["point_id"].to_numpy()[keep]
    if free is not None:
        values = [json.dumps(np.asarray(v).tolist()) for v in points[free].to_numpy()[keep]]
        if len(ids) < 2 or len(set(values)) != len(values):
            raise _err(f"{where}at", f"must pin every axis but {free} (it selects {len(ids)} points, "
                       f"{len(set(values))} value(s) of {free})")
        free_values = [np.asarray(v).tolist() for v in points[free].to_numpy()[keep]]
        return [(int(i), v) for i, v in zip(ids, free_values)], dict(at)
    if len(ids) != 1:
        loose = [a for a in study.axes if a not in at and points.loc[keep, a].astype(str).nunique() > 1]
        raise _err(f"{where}at", f"must select one point of the sweep; it selects {len(ids)} (pin also "
                   f"{', '.join(loose)})")
    return int(ids[0]), dict(at)


def _sweep_name(where: str, table: dict, studies: dict) -> str:
    """The sweep a side names (the file's only one when it names none)."""
    sweep = table.get("sweep")
    if sweep is None:
        if len(studies) != 1:
            raise _err(f"{where}sweep", f"missing; the file has {len(studies)} sweeps: {', '.join(studies)}")
        return next(iter(studies))
    if not isinstance(sweep, str) or sweep not in studies:
        raise _err(f"{where}sweep", f"must be one of the file's sweeps {', '.join(studies)}; got {show(sweep)}"
                   f"{suggest(sweep, list(studies)) if isinstance(sweep, str) else ''}")
    return sweep


def _side(where: str, table: dict, studies: dict, *, free: str | None = None) -> Side | list[Side]:
    """A side from the claim's keys (``table``: the claim's own, with any override merged in)."""
    sweep = _sweep_name(where, table, studies)
    study = studies[sweep]
    outputs = study.scenario.outputs(study.config)
    output = table.get("output")
    if output is None:
        raise _err(f"{where}output", f"missing; scenario {study.scenario.name}'s outputs: {', '.join(outputs)}")
    if output not in outputs:
        raise _err(f"{where}output", f"must be an output of scenario {study.scenario.name}; got {show(output)}"
                   f"{suggest(output, list(outputs)) if isinstance(output, str) else ''}; allowed: "
                   f"{', '.join(outputs)}")
    filters = list(study.config.filters)
    filt = table.get("filter")
    if filt is None:
        if outputs[output].per_filter:
            raise _err(f"{where}filter", f"missing; output {output} is per filter, the sweep runs "
                       f"{', '.join(filters)}")
        filt = filters[0]  # a per-run output: every filter's row holds the same value
    elif filt not in filters and filt not in shown_filters(study.scenario, study.config):
        raise _err(f"{where}filter", f"must be one of the filters the sweep runs, {', '.join(filters)}; got "
                   f"{show(filt)}")
    if filt in filters:  # the rows' name for it: a filter of one's own by its record's name
        filt = shown_filters(study.scenario, study.config)[filters.index(filt)]
    statistic = table.get("statistic", "mean")
    if statistic not in STATISTICS:
        raise _err(f"{where}statistic", f"must be one of {', '.join(STATISTICS)}; got {show(statistic)}")
    q = table.get("q")
    if statistic == "quantile":
        if q is None or not (isinstance(q, (int, float)) and not isinstance(q, bool) and 0 < q < 1):
            raise _err(f"{where}q", f"must be a number in (0, 1) (the quantile's level); got {got(q)}")
    elif q is not None:
        raise _err(f"{where}q", f"applies to statistic = \"quantile\" only (this side's is {statistic!r})")
    over = _number(f"{where}over", table["over"]) if "over" in table else None
    under = _number(f"{where}under", table["under"]) if "under" in table else None
    if (over is not None or under is not None) and statistic != "rate":
        raise _err(f"{where}{'over' if over is not None else 'under'}", "applies to statistic = \"rate\" only")
    if over is not None and under is not None:
        raise _err(f"{where}under", "give over or under, not both")
    point, at = _point(where, study, table.get("at", {}), free)
    if isinstance(point, list):
        return [Side(sweep, output, filt, p, {**at, free: v}, statistic, q, over, under) for p, v in point]
    return Side(sweep, output, filt, point, at, statistic, q, over, under)


def _override(where: str, claim: dict, key: str, value: Any) -> dict:
    if not isinstance(value, dict):
        raise _err(f"{where}{key}", f"must be a table of side keys ({', '.join(SIDE_KEYS)}); got {show(value)}")
    check_keys(f"{where}{key}.", value, SIDE_KEYS)
    return {**{k: v for k, v in claim.items() if k in SIDE_KEYS}, **value}


def _claim(path: Path, i: int, raw: Any, studies: dict, seen: set) -> Claim:
    where = f"{path.name}: claim {i + 1}: "
    if not isinstance(raw, dict):
        raise _err(where.rstrip(": "), f"must be a table ([[claim]]); got {show(raw)}")
    if "id" in raw and isinstance(raw["id"], str) and ID.match(raw["id"]):
        where = f"{path.name}: claim {raw['id']!r}: "
    check_keys(where, raw, CLAIM_KEYS)
    cid = _text(where, raw, "id", required=True)
    if not ID.match(cid):
        raise _err(f"{where}id", f"must be letters, digits, '_', '-' or '.'; got {show(cid)}")
    if cid in seen:
        raise _err(f"{where}id", "is given to two claims; each claim needs its own id")
    seen.add(cid)
    text = _text(where, raw, "claim", required=True)
    place = _text(where, raw, "where")
    paper = raw.get("paper")
    if paper is not None and (isinstance(paper, bool) or not isinstance(paper, (str, int, float))):
        raise _err(f"{where}paper", f"must be the paper's figure, a number or a string; got {show(paper)}")
    paper_runs = raw.get("paper_runs")
    if paper_runs is not None and (isinstance(paper_runs, bool) or not isinstance(paper_runs, int) or paper_runs < 1):
        raise _err(f"{where}paper_runs", f"must be the paper's run count, an integer >= 1; got {got(paper_runs)}")
    relation = raw.get("relation")
    if relation not in RELATIONS:
        raise _err(f"{where}relation", f"{'missing' if relation is None else 'unknown'}; allowed: "
                   f"{', '.join(RELATIONS)}" + ("" if relation is None else f"; got {show(relation)}"))
    direction = raw.get("direction", "increasing")
    if direction not in DIRECTIONS:
        raise _err(f"{where}direction", f"must be one of {', '.join(DIRECTIONS)}; got {show(direction)}")
    operands = {"value": relation in ("equal",) or (relation in ("below", "above") and "than" not in raw),
                "than": relation in ("below", "above") and "than" in raw,
                "band": relation == "within", "tolerance": relation == "equal", "order": relation == "ordered",
                "along": relation == "monotone"}
    if relation in ("below", "above") and "than" in raw and "value" in raw:
        raise _err(f"{where}value", f"relation {relation!r} takes a value or than (another side), not both")
    for key, needed in operands.items():
        if needed and key not in raw:
            what = {"value": "a value (or than = {...}, another side)", "band": "band = [low, high]",
                    "tolerance": "tolerance (>= 0)", "order": "order = [{...}, {...}] (two or more sides)",
                    "along": "along = AXIS (a swept axis)", "than": ""}[key]
            raise _err(f"{where}{key}", f"missing; relation {relation!r} needs {what}")
        if not needed and key in raw:
            raise _err(f"{where}{key}", f"does not apply to relation {relation!r}")
    if relation != "monotone" and "direction" in raw and relation != "ordered":
        raise _err(f"{where}direction", f"does not apply to relation {relation!r}")
    if "minus" in raw and relation in ("ordered", "monotone"):
        raise _err(f"{where}minus", f"does not apply to relation {relation!r} (order sides, not differences)")
    side_keys = {k: v for k, v in raw.items() if k in SIDE_KEYS}
    free = raw.get("along") if relation == "monotone" else None
    if relation == "monotone":
        axes = studies[_sweep_name(where, side_keys, studies)].axes
        if free not in axes:
            raise _err(f"{where}along", f"must be an axis of the sweep ({', '.join(axes) or 'none'}); got {show(free)}")
    # an order's own keys are only the defaults of its sides
    side = None if relation == "ordered" else _side(where, side_keys, studies, free=free)
    others: tuple[Side, ...] = ()
    if relation == "monotone":
        side, others = side[0], tuple(side)
    if "minus" in raw:
        other = _side(f"{where}minus.", _override(where, raw, "minus", raw["minus"]), studies)
        if side.statistic not in ("mean", "rate") or other.statistic != side.statistic:
            raise _err(f"{where}statistic", "a paired difference (minus) takes statistic = \"mean\" or \"rate\" on "
                       "both sides")
        a, b = studies[side.sweep], studies[other.sweep]
        if (a.seeds, a.base_seed) != (b.seeds, b.base_seed):
            raise _err(f"{where}minus.sweep", f"a paired difference needs the same seeds on both sides; sweep "
                       f"{side.sweep} runs {a.seeds} seed(s) from base_seed {a.base_seed}, sweep {other.sweep} "
                       f"{b.seeds} from base_seed {b.base_seed}")
        side = side._replace(minus=other)
    if relation in ("below", "above") and "than" in raw:
        others = (_side(f"{where}than.", _override(where, raw, "than", raw["than"]), studies),)
    if relation == "ordered":
        order = raw["order"]
        if not isinstance(order, list) or len(order) < 2:
            raise _err(f"{where}order", f"must be a list of two or more sides; got {show(order)}")
        others = tuple(_side(f"{where}order[{k}].", _override(where, raw, f"order[{k}]", o), studies)
                       for k, o in enumerate(order))
        side = others[0]
    value = band = None
    if operands["value"]:
        value = _number(f"{where}value", raw["value"])
    if relation == "within":
        b = raw["band"]
        if not (isinstance(b, list) and len(b) == 2):
            raise _err(f"{where}band", f"must be [low, high]; got {got(b)}")
        band = (_number(f"{where}band", b[0]), _number(f"{where}band", b[1]))
        if band[0] > band[1]:
            raise _err(f"{where}band", f"must be [low, high] with low <= high; got {show(b)}")
    if relation == "equal":
        tol = _number(f"{where}tolerance", raw["tolerance"])
        if tol < 0:
            raise _err(f"{where}tolerance", f"must be >= 0; got {got(raw['tolerance'])}")
        band = (value - tol, value + tol)
    if relation == "consistent":
        if isinstance(paper, str) or paper is None:
            raise _err(f"{where}paper", "relation 'consistent' needs the paper's figure as a number")
        if paper_runs is None:
            raise _err(f"{where}paper_runs", "missing; relation 'consistent' needs the paper's run count")
        if side.statistic not in ("mean", "rate") or side.minus is not None:
            raise _err(f"{where}statistic", "relation 'consistent' takes statistic = \"mean\" or \"rate\" of one side")
    return Claim(cid, text, place, paper, paper_runs, side, relation, value, band, others, direction, free)


def load_claims(path: str | Path, *, seeds: int | None = None, base_seed: int | None = None,
                shift: int = 0) -> ClaimsFile:
    """Read and check the claims file ``path`` (module docstring) with every sweep it names
    (``seeds``: runs per point of each, over the file's ``seeds`` and the sweeps' own;
    ``base_seed``: every sweep's base seed, over their own; ``shift``: added to each sweep's base
    seed). Raises :class:`ClaimsError` (one line naming the claim and the field)."""
    if base_seed is not None and (isinstance(base_seed, bool) or not isinstance(base_seed, int)
                                  or not 0 <= base_seed <= MAX_BASE_SEED):
        raise ClaimsError(f"--base-seed: must be an integer in [0, {MAX_BASE_SEED}]; got {show(base_seed)}")
    given = seeds
    claims = load_checked(lambda p, n: _load(p, n, base_seed, shift), path, seeds, ClaimsError)
    return claims._replace(seeds=given, base_seed=base_seed, shift=shift)


def _load(path: Path, seeds: int | None, base_seed: int | None = None, shift: int = 0) -> ClaimsFile:
    data = read_toml(path, "claims file")
    check_keys(f"{path.name}: ", data, FILE_KEYS)
    paper = _text(f"{path.name}: ", data, "paper", required=True)
    title = _text(f"{path.name}: ", data, "title")
    family = data.get("family")
    if family is not None and family not in FAMILIES:
        raise _err(f"{path.name}: family", f"must be one of {', '.join(FAMILIES)} (how the file's claims are held "
                   f"to a family-wise error of 5 %); got {show(family)}")
    if seeds is None and "seeds" in data:
        s = data["seeds"]
        if isinstance(s, bool) or not isinstance(s, int) or not 1 <= s <= MAX_SEEDS:
            raise _err(f"{path.name}: seeds", f"must be an integer in [1, {MAX_SEEDS}]; got {got(s)}")
        seeds = s
    studies, files = _sweeps(path, data, seeds, base_seed, shift)
    raw = data.get("claim")
    if not isinstance(raw, list) or not raw:
        raise _err(f"{path.name}: claim", "must hold at least one claim ([[claim]] tables)"
                   + ("" if raw is None else f"; got {show(raw)}"))
    seen: set = set()
    claims = tuple(_claim(path, i, c, studies, seen) for i, c in enumerate(raw))
    return ClaimsFile(path, paper, title, studies, files, claims, data, family)
