"""``mcjax list SCENARIO``: a scenario's declarations as text — every Params field (unit,
default, allowed values, description), every Config field and every output; with a config
file, that file's values beside the defaults ("<-" marks the fields it changes, "the same" those
it sets to the default). No JAX."""

from __future__ import annotations

import math
import tomllib
from decimal import Decimal
from pathlib import Path

import numpy as np

from mcjax.analysis.tables import format_number
from mcjax.base.validation import ceiling
from mcjax.contract import Scenario


def _rounded(default: float, written: float) -> bool:
    """True when ``written`` is ``default`` rounded to the decimals a file writes it with
    (546.41 for 546.41016), agreeing to 1e-4 relative: a value shortened in a config file,
    not changed (3.0 for 3.04 is a change)."""
    if not (math.isfinite(default) and math.isfinite(written)) or written == 0.0:
        return False
    places = -Decimal(repr(written)).as_tuple().exponent  # decimals of the shortest repr: 546.41 -> 2
    return round(default, places) == written and abs(default - written) <= 1e-4 * abs(default)


def same_value(default, value) -> str | None:
    """``"exact"`` when a file's ``value`` is the ``default``, ``"rounded"`` when it is the
    default written with fewer decimals in every number that differs (:func:`_rounded`), else
    None (the file changes it)."""
    if isinstance(default, (str, tuple)) or isinstance(value, (str, tuple)) or isinstance(default, bool):
        return "exact" if default == value else None
    a, b = np.asarray(default), np.asarray(value)
    if a.shape != b.shape or a.dtype.kind not in "biuf" or b.dtype.kind not in "biuf":
        return None
    if np.array_equal(a, b):
        return "exact"
    pairs = zip(a.astype(float).ravel().tolist(), b.astype(float).ravel().tolist())
    return "rounded" if all(x == y or _rounded(x, y) for x, y in pairs) else None


def scenario_text(sc: Scenario, file=None, config_file: Path | None = None) -> str:
    """The listing of ``sc``; ``file``: a config file of it read by
    :func:`mcjax.study.read_config_file` (its values are shown beside the defaults)."""
    out: list[str] = []
    cfg = sc.Config()
    defaults = sc.default_params(cfg)
    mine = sc.default_params(file.config, **file.params) if file is not None else None
    tag = config_file.name if file is not None else ""

    def shown(value):  # numbers as in every table (mcjax.analysis.tables.format_number), arrays as lists
        value = np.asarray(value)
        if value.size > 48:
            return f"array{value.shape}"
        return format_number(value.tolist() if value.ndim else value.item(), 8).replace("(", "[").replace(")", "]")

    def beside(default, value, given: bool, show=shown) -> str:
        if file is None:
            return f"default {show(default)}"
        same = same_value(default, value)
        if same is not None:
            return f"default {show(default)}" + (f" ({tag}: the same{'' if same == 'exact' else ', rounded'})"
                                                 if given else "")
        return f"default {show(default)}  <- {tag}: {show(value)}"

    out.append(f"{sc.name}: {sc.title}")
    if file is not None:
        seeds = f"; seeds {file.seeds} (the paper's run count)" if file.seeds is not None else ""
        out.append(f"values of {config_file} beside the defaults (\"<-\": the file changes it){seeds}")
    out.append("\nParams (sweepable, no recompilation):")
    for name, p in sc.params_table.items():
        unit = f" [{p.unit}]" if p.unit else ""
        agent = ", scalar or per agent" if p.per_agent else ""
        if p.shape is not None:
            agent += ", shape " + "x".join("n_agents" if d == "n" else str(d) for d in p.shape)
        value = getattr(mine, name) if mine is not None else None
        text = beside(getattr(defaults, name), value, file is not None and name in file.params)
        out.append(f"  {name}{unit}: {p.description}\n      {text}; allowed {p.allowed()}{agent}")
    out.append("\nConfig (fixes shapes / the program; changing it recompiles):")
    given = _config_keys(file.path) if file is not None else set()
    for name, st in sc.settings.items():
        unit = f" [{st.unit}]" if st.unit else ""
        top = ceiling(name, st)
        most = f" (at most {top})" if top is not None else ""
        value = getattr(file.config, name) if file is not None else None
        text = beside(st.default, value, name in given, repr)
        out.append(f"  {name}{unit}: {st.description}\n      {text}; allowed {st.allowed()}{most}")
    out.append("\nOutputs (one row per run and filter in OUT/runs):")
    for name, o in sc.outputs(file.config if file is not None else cfg).items():
        unit = f" [{o.unit}]" if o.unit else ""
        role = f" (role: {o.role})" if o.role else ""
        out.append(f"  {name}{unit}{'' if o.per_filter else ' per run'}: {o.description}{role}")
    return "\n".join(out)


def _config_keys(path: Path) -> set[str]:
    """The Config fields a config file sets (its ``[config]`` table; the file was read and
    checked before, by :func:`mcjax.study.read_config_file`)."""
    data = tomllib.loads(Path(path).read_bytes().decode("utf-8").removeprefix("\ufeff"))
    table = data.get("config", {})
    return set(table) if isinstance(table, dict) else set()


def _takes(sc, name: str) -> str | None:
    """None when scenario ``sc`` runs the filter ``name`` with its own defaults (its Config's check, the rule
    that would refuse it), else that check's one-line refusal."""
    try:
        sc.Config(filters=(name,))
    except Exception as exc:  # noqa: BLE001 - the scenario's own words, whatever the check raised
        return " ".join(str(exc).split())
    return None


def filters_text() -> str:
    """``mcjax list filters``: every filter (built-in, then installed plugins) with its title, reference,
    traits and the scenarios that run it — each scenario asked by its own Config check, with its defaults,
    the rule that would refuse it (a built-in filter it lists among its ``filters`` choices, a plugin where its
    ``filters`` take plugins); a scenario that offers the filter but refuses it with its defaults is named
    with its refusal. A plugin that cannot be loaded, or that takes a built-in filter's name, is listed with
    its one-line reason, not hidden."""
    from mcjax import scenarios
    from mcjax.tracking.filters import registry

    takers = {}
    for name in scenarios.known():
        try:
            sc = scenarios.get(name)
        except Exception:  # a broken scenario plugin: `mcjax list` says why
            continue
        setting = sc.settings.get("filters")
        if setting is not None:
            takers[sc.name] = (sc, set(setting.choices or ()), bool(setting.plugins))
    lines = []
    for name in registry.known():
        try:
            f = registry.get(name)
        except Exception as exc:  # a broken plugin must not hide the others
            lines += [f"{name}", f"    cannot be loaded: {exc}"]
            continue
        builtin = name in registry.BUILTIN
        offered = [sc for sc, choices, plugins in takers.values() if (name in choices if builtin else plugins)]
        refusals = {sc.name: _takes(sc, name) for sc in offered}
        runs = [s for s, why in refusals.items() if why is None]
        where = "" if builtin else f"  [plugin: {registry.origin(name).removeprefix('plugin ')}]"
        shown = f.name if f.name == name else f"{name} (shown as {f.name})"
        lines += [f"{shown:14s} {f.title}{where}", f"    reference: {f.reference}",
                  f"    traits: {f.traits.words()}", f"    scenarios: {', '.join(runs) or 'none'}"]
        lines += [f"    not with {s}'s defaults: {why.split(': ')[0].split(' (')[0]} (`mcjax list {s}`)"
                  for s, why in refusals.items() if why is not None]
    for clash in registry.clashes():  # a plugin that takes a built-in's name: listed, never resolved
        lines += [clash.split(":")[0].removeprefix("filter ").strip("'"), f"    cannot be loaded: {clash}"]
    lines.append("a filter of your own: docs/library.md, 'Writing a filter' (entry-point group mcjax.filters, "
                 "or \"file.py:ATTRIBUTE\" in a config's filters)")
    return "\n".join(lines)
