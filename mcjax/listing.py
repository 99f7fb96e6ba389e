"""``mcjax list SCENARIO``: a scenario's declarations as text — every Params field (unit,
default, allowed values, description), every Config field and every output; with a config
file, that file's values beside the defaults ("<-" marks the fields it changes). No JAX."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mcjax.contract import Scenario, ceiling
from mcjax.tables import format_number


def scenario_text(sc: Scenario, file=None, config_file: Path | None = None) -> str:
    """The listing of ``sc``; ``file``: a config file of it read by
    :func:`mcjax.study.read_config_file` (its values are shown beside the defaults)."""
    out: list[str] = []
    cfg = sc.Config()
    defaults = sc.default_params(cfg)
    mine = sc.default_params(file.config, **file.params) if file is not None else None
    tag = config_file.name if file is not None else ""

    def shown(value):  # numbers as in every table (mcjax.tables.format_number), arrays as lists
        value = np.asarray(value)
        if value.size > 48:
            return f"array{value.shape}"
        return format_number(value.tolist() if value.ndim else value.item(), 8).replace("(", "[").replace(")", "]")

    def beside(default, value, given: bool) -> str:
        if file is None:
            return f"default {shown(default)}"
        same = (np.shape(default) == np.shape(value) and bool(np.all(np.asarray(default) == np.asarray(value)))
                if not isinstance(default, (str, tuple)) else default == value)
        if same:
            return f"default {shown(default)}" + (f" ({tag}: the same)" if given else "")
        return f"default {shown(default)}  <- {tag}: {shown(value)}"

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
    for name, st in sc.settings.items():
        unit = f" [{st.unit}]" if st.unit else ""
        top = ceiling(name, st)
        most = f" (at most {top})" if top is not None else ""
        if file is None:
            text = f"default {st.default!r}"
        else:
            value = getattr(file.config, name)
            text = (f"default {st.default!r}" if value == st.default
                    else f"default {st.default!r}  <- {tag}: {value!r}")
        out.append(f"  {name}{unit}: {st.description}\n      {text}; allowed {st.allowed()}{most}")
    out.append("\nOutputs (one row per run and filter in OUT/runs):")
    for name, o in sc.outputs(file.config if file is not None else cfg).items():
        unit = f" [{o.unit}]" if o.unit else ""
        role = f" (role: {o.role})" if o.role else ""
        out.append(f"  {name}{unit}{'' if o.per_filter else ' per run'}: {o.description}{role}")
    return "\n".join(out)
