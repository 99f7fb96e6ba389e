"""Display units: the unit a plot or a report shows a value in, and the factor to it from the
unit the value is declared in (metres shown in km, radians in degrees). No JAX."""

from __future__ import annotations

import math

#: Units a value may be shown in: (declared unit, shown unit) -> factor (shown = factor x declared).
DISPLAY_UNITS = {("m", "km"): 1e-3, ("rad", "deg"): 180.0 / math.pi, ("rad/s", "deg/s"): 180.0 / math.pi,
                 ("s", "min"): 1.0 / 60.0, ("s", "h"): 1.0 / 3600.0, ("m/s", "km/h"): 3.6}
#: The shown unit of a declared unit when a Param names none: angles in degrees.
DEFAULT_DISPLAY = {"rad": "deg", "rad/s": "deg/s"}


def display_unit(unit: str, display: str | None = None) -> tuple[str, float]:
    """``(shown unit, factor)`` for a value declared in ``unit``: ``display`` when given (it
    must be ``unit`` or a pair of :data:`DISPLAY_UNITS`, else ValueError), else
    :data:`DEFAULT_DISPLAY`, else ``unit`` unchanged (factor 1)."""
    unit = unit or ""
    if display is None:
        display = DEFAULT_DISPLAY.get(unit, unit)
    if display == unit:
        return unit, 1.0
    try:
        return display, DISPLAY_UNITS[(unit, display)]
    except KeyError:
        known = [b for a, b in DISPLAY_UNITS if a == unit]
        raise ValueError(f"display unit {display!r} for a value in {unit!r}: allowed "
                         f"{', '.join(repr(k) for k in [unit, *known])}") from None
