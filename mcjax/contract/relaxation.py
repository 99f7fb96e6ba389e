"""A scenario's relaxation switch (:class:`Relaxation`) and which Params can be differentiated.

A scenario with a relaxation switch runs its exact simulation and a smooth one with one
``step``: ``step(cfg, params, state, key, temperatures)``, ``temperatures`` None for the exact one
(bit for bit the program without the switch), a NamedTuple of temperatures for the smooth one.
``mcjax tune`` trains on the smooth system and evaluates on the exact one; a sweep's
``[sensitivity]`` writes derivatives of outputs of the smooth system with respect to Params.

No JAX; of mcjax, only the validation layer's error.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import numpy as np

from mcjax.base.validation import SpecError


class Relaxation(NamedTuple):
    """A scenario's relaxation switch (``mcjax tune``, a sweep's ``[sensitivity]``): its ``step``
    takes a fifth argument ``temperatures`` — None (the default) runs the exact simulation, a
    ``Temperatures`` runs the same step with every discrete switch (a sensing gate, a comm link,
    a hysteresis, an indicator, an argmax) replaced by a smooth one at the given temperature,
    with the same random draws. One step, not a near-twin: the exact path with ``None`` is
    today's program bit for bit.

    ``Temperatures``: a NamedTuple of the temperatures, one per switch, with defaults (the keys of
    ``[tune.relaxation]`` and ``[sensitivity.relaxation]``, formerly ``smoothing``); ``errors(cfg, params, record) ->
    (F, n)``: the tracking errors the training loss reads from a step's record; ``weights(cfg,
    params) -> (n,)``: each agent's weight in that loss; ``rough``: continuous Params with no
    smooth path (their derivative on the smooth system is zero or undefined, e.g. a step count
    stored as a float) — tune and sensitivity refuse them by name."""

    Temperatures: type
    errors: Callable
    weights: Callable
    rough: tuple = ()


def smooth_params(scenario, cfg) -> list[str]:
    """The Params a tune or a sensitivity may name: those with a smooth path — continuous (not
    integer, no choices), one number (scalar, or per agent with a scalar default) and not
    declared rough by the scenario's :class:`Relaxation`; none without a relaxation switch."""
    if scenario.relaxation is None:
        return []
    return [k for k, p in scenario.params_table.items() if not p.integer and p.choices is None and p.shape is None
            and (p.per_agent or p.scalar(cfg)) and np.ndim(p.default_value(cfg)) == 0
            and k not in scenario.relaxation.rough]


def problem(scenario, cfg, name: str) -> str | None:
    """Why ``name`` cannot be differentiated (one line, naming it and the Params that can),
    or None: an unknown name, a Config field, an integer or choice, an array, or a Param
    with no smooth path (:class:`Relaxation` ``rough``)."""
    allowed = f"Params with a smooth path in {scenario.name}: {', '.join(smooth_params(scenario, cfg)) or 'none'}"
    if scenario.relaxation is None:
        return f"{scenario.name} has no relaxation switch (Scenario.relaxation), so no Param can be differentiated"
    if name not in scenario.params_table:
        if name in scenario.settings:
            return f"{name} is a Config field (fixed in the compiled program), not a Param; {allowed}"
        return f"unknown Param of {scenario.name}; {allowed}"
    p = scenario.params_table[name]
    if p.integer or p.choices is not None:
        return f"{name} is not continuous (it takes {p.allowed()}); {allowed}"
    if name in scenario.relaxation.rough:
        return f"{name} has no smooth path (its derivative is zero or undefined on the smooth system); {allowed}"
    if name not in smooth_params(scenario, cfg):
        return f"{name} is an array here; only Params with one number can be differentiated ({allowed})"
    return None


def column(output: str, param: str) -> str:
    """The name of the column holding d ``output`` / d ``param`` (a sweep's ``[sensitivity]``)."""
    return f"d_{output}_d_{param}"


#: The key of a spec's table of temperatures (``[tune.relaxation]``, ``[sensitivity.relaxation]``), and the
#: name it had before, still read (CHANGELOG.md).
KEY, FORMER_KEY = "relaxation", "smoothing"


def relaxation_key(where: str, table: dict) -> str:
    """Which key of ``table`` (the ``[tune]`` or ``[sensitivity]`` table at ``where``) holds the temperatures:
    ``relaxation``, or ``smoothing`` as written before (CHANGELOG.md); both at once is a :class:`SpecError`."""
    if KEY in table and FORMER_KEY in table:
        raise SpecError(f"{where}.{FORMER_KEY}: the former name of {where}.{KEY}; give one of them, not both")
    return FORMER_KEY if FORMER_KEY in table else KEY
