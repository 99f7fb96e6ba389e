"""Sensitivity maps: a sweep's ``[sensitivity]`` table, and the columns it adds.

::

    [sensitivity]
    params = ["comm_radius", "sigma_range"]   # Params with a smooth path (mcjax list SCENARIO)
    outputs = ["rmse"]                         # declared outputs (default: the error output)
    [sensitivity.relaxation]                   # the scenario's temperatures (default: its own; formerly smoothing)
    comm = 1000.0

For every run and point the sweep then also runs the scenario's smooth system
(:class:`mcjax.contract.relaxation.Relaxation`, the same keys) and writes, beside the outputs, the derivative of
each chosen output of that system with respect to each chosen Param, pushed forward with the run
(forward mode, one tangent per Param): the column ``d_<output>_d_<param>``
(:func:`mcjax.contract.relaxation.column`), per filter when the output is. A per-agent Param moves every
agent's value together. A flag's or a count's derivative is 0 (a step function of the Params:
differentiate a smooth output instead). The exact outputs are computed in a program of their
own, bit for bit as without the table.
"""

from __future__ import annotations

from typing import Any, NamedTuple

from mcjax.base.validation import SpecError, check_keys, is_number, show, suggest
from mcjax.contract import Output, Scenario
from mcjax.contract.relaxation import column
from mcjax.contract.relaxation import problem as smooth_problem
from mcjax.contract.relaxation import relaxation_key

SENSITIVITY_KEYS = ("params", "outputs", "relaxation", "smoothing")


class Sensitivity(NamedTuple):
    """What a sweep differentiates: Params, outputs and the smooth system's temperatures
    (hashable: it keys the compiled program)."""

    params: tuple
    outputs: tuple
    temperatures: Any


def _names(where: str, value) -> tuple:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise SpecError(f"{where}: must be a non-empty list of names; got {show(value)}")
    if len(set(value)) != len(value):
        raise SpecError(f"{where}: names a value twice; got {show(value)}")
    return tuple(value)


def read_sensitivity(scenario: Scenario, cfg, table) -> Sensitivity | None:
    """The validated ``[sensitivity]`` table (None: absent); a :class:`SpecError` names the key
    and what is allowed (a Param that is an integer, a Config field or has no smooth path is
    refused by name)."""
    if table is None:
        return None
    if not isinstance(table, dict):
        raise SpecError(f"sensitivity: must be a table ([sensitivity] params = [...]); got {show(table)}")
    check_keys("sensitivity.", table, SENSITIVITY_KEYS)
    if scenario.relaxation is None:
        raise SpecError(f"sensitivity: {smooth_problem(scenario, cfg, '')}")
    if "params" not in table:
        raise SpecError("sensitivity.params: missing; name the Params to differentiate by")
    params = _names("sensitivity.params", table["params"])
    for name in params:
        problem = smooth_problem(scenario, cfg, name)
        if problem is not None:
            raise SpecError(f"sensitivity.params: {problem}")
    declared = scenario.outputs(cfg)
    error = next(k for k, o in declared.items() if o.role == "error")
    outputs = _names("sensitivity.outputs", table.get("outputs", [error]))
    for name in outputs:
        if name not in declared:
            raise SpecError(f"sensitivity.outputs: {name!r} is not an output of {scenario.name}"
                            f"{suggest(name, list(declared))}; allowed: {', '.join(declared)}")
    Temperatures = scenario.relaxation.Temperatures
    key = relaxation_key("sensitivity", table)
    st = table.get(key, {})
    if not isinstance(st, dict):
        raise SpecError(f"sensitivity.{key}: must be a table ([sensitivity.{key}]); got {show(st)}")
    check_keys(f"sensitivity.{key}.", st, list(Temperatures._fields))
    for k, v in st.items():
        if not is_number(v) or not v > 0:
            raise SpecError(f"sensitivity.{key}.{k}: must be a number > 0; got {show(v)}")
    return Sensitivity(params, outputs, Temperatures(**{k: float(v) for k, v in st.items()}))


def declarations(scenario: Scenario, cfg, sens: Sensitivity | None) -> dict[str, Output]:
    """The columns a sensitivity adds, declared as outputs (unit: the output's per the Param's)."""
    if sens is None:
        return {}
    declared, table = scenario.outputs(cfg), scenario.params_table
    out = {}
    for o in sens.outputs:
        for p in sens.params:
            unit_o, unit_p = declared[o].unit, table[p].unit
            unit = f"{unit_o or '1'}/{unit_p}" if unit_p else unit_o
            out[column(o, p)] = Output(unit, f"d {o} / d {p} of the smooth system (forward mode)",
                                       declared[o].per_filter)
    return out
